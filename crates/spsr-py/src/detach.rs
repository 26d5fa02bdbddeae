//! Running library code with the GIL released, interruptibly.

use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;

use crate::errors::invalid;

/// How often the waiting thread looks for pending Python signals.
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// `threads=`: `None` (all cores) or a positive count.
pub fn threads_arg(threads: Option<i64>) -> PyResult<Option<usize>> {
    match threads {
        None => Ok(None),
        Some(n) if n >= 1 => Ok(Some(usize::try_from(n).unwrap_or(usize::MAX))),
        Some(n) => Err(invalid("threads", n, "an integer of at least 1")),
    }
}

/// A pool of `threads` workers, or `None` for rayon's global pool (all cores).
fn pool(threads: Option<usize>) -> PyResult<Option<rayon::ThreadPool>> {
    let Some(n) = threads else { return Ok(None) };
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map(Some)
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start {n} worker threads: {e}")))
}

/// The payload of the unwind that stops library code at a pending signal.
struct Interrupted;

/// Runs `work` on a worker thread with the GIL released; `work` gets a progress callback that
/// the library calls at each stage (and solver depth). Meanwhile this thread checks every
/// 50 ms for pending Python signals; when a handler raises (Ctrl-C: `KeyboardInterrupt`),
/// the next progress call unwinds the library's stack, every buffer is freed, and the
/// handler's exception is returned once the worker has stopped.
pub fn run_detached<T, F>(py: Python<'_>, threads: Option<usize>, work: F) -> PyResult<T>
where
    T: Send,
    F: FnOnce(&(dyn Fn(&str) + Sync)) -> T + Send,
{
    let pool = pool(threads)?;
    let cancel = AtomicBool::new(false);
    let (outcome, interrupt) = py.detach(|| {
        std::thread::scope(|scope| {
            let (done_tx, done_rx) = mpsc::channel::<()>();
            let cancel = &cancel;
            let pool = &pool;
            let worker = std::thread::Builder::new()
                .name("spsr".into())
                .stack_size(8 << 20)
                .spawn_scoped(scope, move || {
                    let check = move |_stage: &str| {
                        if cancel.load(Ordering::Relaxed) {
                            // resume_unwind skips the panic hook: nothing is printed.
                            resume_unwind(Box::new(Interrupted));
                        }
                    };
                    let result = catch_unwind(AssertUnwindSafe(|| match pool {
                        Some(pool) => pool.install(|| work(&check)),
                        None => work(&check),
                    }));
                    let _ = done_tx.send(());
                    result
                });
            let worker = match worker {
                Ok(w) => w,
                Err(e) => {
                    let err = PyRuntimeError::new_err(format!("cannot start a thread: {e}"));
                    return (None, Some(err));
                }
            };
            let mut interrupt: Option<PyErr> = None;
            loop {
                match done_rx.recv_timeout(SIGNAL_POLL) {
                    Ok(()) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
                    Err(mpsc::RecvTimeoutError::Timeout) => {
                        if interrupt.is_none() {
                            if let Err(e) = Python::attach(|py| py.check_signals()) {
                                cancel.store(true, Ordering::Relaxed);
                                interrupt = Some(e);
                            }
                        }
                    }
                }
            }
            (Some(worker.join()), interrupt)
        })
    });
    if let Some(err) = interrupt {
        // The exception raised by the signal handler wins, whether the work had finished or
        // was stopped.
        return Err(err);
    }
    match outcome {
        Some(Ok(Ok(value))) => Ok(value),
        Some(Ok(Err(payload))) | Some(Err(payload)) => {
            if payload.is::<Interrupted>() {
                Err(PyRuntimeError::new_err("interrupted"))
            } else {
                // A bug in the library: let PyO3 turn it into a PanicException.
                resume_unwind(payload)
            }
        }
        None => Err(PyRuntimeError::new_err("the worker thread did not start")),
    }
}
