//! Long calls: the GIL released while the library works, on a thread pool of the requested size.

use crate::errors::input_err;
use pyo3::prelude::*;

/// The most threads a call may ask for: 8 per core, as the command line allows.
fn max_threads() -> usize {
    8 * std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Checks a `threads=` value the way the command line checks `--threads`.
pub fn check_threads(threads: Option<usize>) -> PyResult<()> {
    match threads {
        Some(0) => Err(input_err(
            "threads must be at least 1 (or None for all cores)",
        )),
        Some(n) if n > max_threads() => {
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
            Err(input_err(format!(
                "threads {n} is more than {} (8 per core, {cores} cores available); more threads than \
                 that only slow the work down",
                max_threads()
            )))
        }
        _ => Ok(()),
    }
}

/// Runs `f` with the GIL released: on a pool of `threads` workers built for this call, or on the global
/// pool (all cores) with `None`. Results do not depend on the thread count.
pub fn run<T, F>(py: Python<'_>, threads: Option<usize>, f: F) -> PyResult<T>
where
    T: Send,
    F: FnOnce() -> T + Send,
{
    check_threads(threads)?;
    let pool = match threads {
        Some(n) => Some(
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| input_err(format!("cannot start {n} threads: {e}")))?,
        ),
        None => None,
    };
    Ok(py.detach(move || match pool {
        Some(p) => p.install(f),
        None => f(),
    }))
}
