//! The `spsr` binary: parse the command line, run it, report one error line and an exit code.
use std::process::ExitCode;

fn main() -> ExitCode {
    // Before any worker thread allocates (see the function's documentation).
    spsr::share_one_allocator_arena();
    let cli = match spsr_cli::try_parse_from(std::env::args_os()) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    spsr_cli::install_interrupt_handler();
    match spsr_cli::run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => {
            eprintln!("spsr: error: {}", failure.error);
            ExitCode::from(failure.code)
        }
    }
}
