//! The wheel's `spsr` console script: the command line, run in the Python process.

use pyo3::prelude::*;

/// Runs the command line `spsr` with `argv` (program name first); returns the exit code.
#[pyfunction]
pub fn cli_main(py: Python<'_>, argv: Vec<String>) -> PyResult<u8> {
    let cli = match spsr_cli::try_parse_from(&argv) {
        Ok(cli) => cli,
        Err(e) => {
            // --help and --version print to stdout and succeed; errors print usage.
            let _ = e.print();
            return Ok(if e.use_stderr() {
                e.exit_code() as u8
            } else {
                0
            });
        }
    };
    let code = py.detach(move || match spsr_cli::run(&cli) {
        Ok(()) => 0,
        Err(failure) => {
            eprintln!("spsr: error: {}", failure.error);
            failure.code
        }
    });
    Ok(code)
}
