//! The temporary files of atomic writes (`.NAME.tmp-PID` beside the output): a process-wide registry of the
//! live ones, so that a signal handler can remove them before the process ends ([`remove_live`]), the name
//! rule every reader uses to ignore them ([`is_temp_name`]), and the removal of stale ones left by a process
//! that no longer runs (killed with SIGKILL, a power cut) when writing next to them ([`remove_stale_in`]).

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
static SWEPT: Mutex<Option<HashSet<PathBuf>>> = Mutex::new(None);

/// The temporary file name of an atomic write of `name` by this process.
pub fn temp_name(name: &str) -> String {
    format!(".{name}.tmp-{}", std::process::id())
}

/// The writing process's id when `name` is a temporary file name (`.NAME.tmp-PID`), else `None`.
pub fn temp_pid(name: &str) -> Option<u32> {
    let rest = name.strip_prefix('.')?;
    let (stem, pid) = rest.rsplit_once(".tmp-")?;
    if stem.is_empty() || pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    pid.parse().ok()
}

/// Whether `name` is the temporary file of an atomic write (never a result: readers skip it).
pub fn is_temp_name(name: &str) -> bool {
    temp_pid(name).is_some()
}

/// Whether the file name of `path` is a temporary file of an atomic write.
pub fn is_temp_path(path: &Path) -> bool {
    path.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(is_temp_name)
}

/// Creates the temporary file `tmp` and records it as live, under the registry's lock (so that a signal
/// arriving meanwhile either sees it and removes it, or ends the process before it exists).
pub fn create_registered(tmp: &Path) -> std::io::Result<std::fs::File> {
    let mut live = LIVE.lock().unwrap_or_else(|e| e.into_inner());
    let f = std::fs::File::create(tmp)?;
    live.push(tmp.to_path_buf());
    Ok(f)
}

/// Forgets `tmp` (renamed into place or removed).
pub fn unregister(tmp: &Path) {
    let mut live = LIVE.lock().unwrap_or_else(|e| e.into_inner());
    live.retain(|p| p != tmp);
}

/// Removes every live temporary file. Called on SIGINT / SIGTERM just before the process exits; the lock
/// is kept (returned) so that no new temporary file appears until the process is gone.
pub fn remove_live() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    let mut live = LIVE.lock().unwrap_or_else(|e| e.into_inner());
    for p in live.drain(..) {
        let _ = std::fs::remove_file(p);
    }
    live
}

#[cfg(unix)]
fn alive(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // SAFETY: kill with signal 0 only checks whether the process exists.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

#[cfg(not(unix))]
fn alive(_pid: u32) -> bool {
    true
}

/// Removes the temporary files in `dir` whose writing process no longer runs (once per directory and
/// process). Errors are ignored: this is housekeeping.
pub fn remove_stale_in(dir: &Path) {
    {
        let mut swept = SWEPT.lock().unwrap_or_else(|e| e.into_inner());
        if !swept
            .get_or_insert_with(HashSet::new)
            .insert(dir.to_path_buf())
        {
            return;
        }
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let me = std::process::id();
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name.to_str().and_then(temp_pid) else {
            continue;
        };
        if pid != me && !alive(pid) && e.file_type().is_ok_and(|t| t.is_file()) {
            log::info!("removing a stale temporary file {}", e.path().display());
            let _ = std::fs::remove_file(e.path());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_names() {
        assert_eq!(temp_pid(".a.ply.tmp-123"), Some(123));
        assert!(is_temp_name(&temp_name("x.csv")));
        for n in [
            "a.ply",
            ".a.ply",
            ".tmp-1",
            ".a.tmp-",
            ".a.tmp-1x",
            "a.tmp-1",
        ] {
            assert!(!is_temp_name(n), "{n}");
        }
    }
}
