//! The `depthcal` command-line tool: a thin layer over the library (parsing, printing, progress).

mod cli;

fn main() {
    // Behave like a Unix tool when stdout is closed early (`depthcal ... | head`): end quietly instead of
    // panicking on a broken pipe.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of SIGPIPE before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    std::process::exit(cli::run());
}
