//! The `spsr` binary: parse the command line, run it, report one error line and an exit code.
use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = spsr_cli::Cli::parse();
    spsr_cli::install_interrupt_handler();
    match spsr_cli::run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => {
            eprintln!("spsr: error: {}", failure.error);
            ExitCode::from(failure.code)
        }
    }
}
