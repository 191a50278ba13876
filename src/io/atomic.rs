//! Atomic file output: write a temporary file beside the target, then rename it into place.
//!
//! The temporary file `.NAME.tmp-PID` is registered in [`crate::tempfiles`] while it exists, so that the
//! CLI's SIGINT / SIGTERM handler removes it; stale ones of dead processes in the same directory are
//! removed before writing.

use crate::error::{Error, Result};
use std::io::{BufWriter, Write};
use std::path::Path;

/// Writes `path` atomically: `fill` writes into a temporary file in the same directory, which is flushed,
/// synced and renamed over `path`. On any error the temporary file is removed and `path` is untouched.
pub fn write_atomically(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    if !dir.is_dir() {
        return Err(Error::io(
            path,
            std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("the directory {} does not exist", dir.display()),
            ),
        ));
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    crate::tempfiles::remove_stale_in(&dir);
    let tmp = dir.join(crate::tempfiles::temp_name(&name));
    let result = (|| -> std::io::Result<()> {
        let file = crate::tempfiles::create_registered(&tmp)?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    crate::tempfiles::unregister(&tmp);
    if let Err(e) = result {
        return Err(Error::io(path, e));
    }
    Ok(())
}
