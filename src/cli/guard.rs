//! Checks every command runs before any work: an output must not be one of the inputs (by any spelling, a
//! symlink or a hard link), its directory must exist and its extension must be one that is written.
//!
//! Overwrite policy: an output that is an input is refused; any other existing output is replaced only by a
//! complete, successful result (atomically: a temporary file renamed into place), and for `register` only
//! by a trusted one.

use anyhow::{bail, Result};
use depthcal::cell::Cell;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// How a path is identified: its canonical form (of the parent directory plus the name when it does not
/// exist yet) and, when it exists, its (device, inode).
#[derive(Clone, Debug)]
struct FileId {
    canonical: Option<PathBuf>,
    inode: Option<(u64, u64)>,
}

fn inode(p: &Path) -> Option<(u64, u64)> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()))
    }
    #[cfg(not(unix))]
    {
        let _ = p;
        None
    }
}

fn file_id(p: &Path) -> FileId {
    if let Ok(c) = p.canonicalize() {
        return FileId {
            canonical: Some(c),
            inode: inode(p),
        };
    }
    let parent = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let canonical = match (parent.canonicalize(), p.file_name()) {
        (Ok(d), Some(n)) => Some(d.join(n)),
        _ => None,
    };
    FileId {
        canonical,
        inode: None,
    }
}

/// The input files of a command, with what each is (named in the refusal).
#[derive(Default)]
pub struct Inputs {
    by_path: HashMap<PathBuf, (String, PathBuf)>,
    by_inode: HashMap<(u64, u64), (String, PathBuf)>,
}

impl Inputs {
    /// Records an input file.
    pub fn add(&mut self, what: &str, path: &Path) {
        let id = file_id(path);
        let entry = (what.to_string(), path.to_path_buf());
        if let Some(c) = id.canonical {
            self.by_path.entry(c).or_insert_with(|| entry.clone());
        }
        if let Some(i) = id.inode {
            self.by_inode.entry(i).or_insert(entry);
        }
    }

    /// Records an optional input file.
    pub fn add_opt(&mut self, what: &str, path: Option<&PathBuf>) {
        if let Some(p) = path {
            self.add(what, p);
        }
    }

    /// Records every file a cell reads: cell.toml, ground_truth.json, and per robot its poses, intrinsics,
    /// hand-eye file, depth and colour frames.
    pub fn add_cell(&mut self, cell: &Cell) {
        self.add(
            "the cell manifest",
            &cell.dir.join(depthcal::cell::MANIFEST_FILE),
        );
        let gt = cell.dir.join(depthcal::cell::GROUND_TRUTH_FILE);
        if gt.exists() {
            self.add("the cell's ground truth", &gt);
        }
        for r in &cell.robots {
            let n = &r.name;
            self.add(&format!("robot {n:?}'s poses"), &r.poses_path);
            self.add(&format!("robot {n:?}'s intrinsics"), &r.intrinsics_path);
            if let Some(h) = &r.hand_eye_path {
                self.add(&format!("robot {n:?}'s hand-eye"), h);
            }
            for f in &r.frames {
                self.add(
                    &format!("robot {n:?}'s depth frame {}", f.id),
                    &f.depth_path,
                );
                if let Some(c) = &f.color_path {
                    self.add(&format!("robot {n:?}'s colour frame {}", f.id), c);
                }
            }
        }
    }

    /// The input `out` would overwrite, if any: (what, the input's path as given).
    fn clash(&self, out: &Path) -> Option<&(String, PathBuf)> {
        let id = file_id(out);
        id.inode
            .and_then(|i| self.by_inode.get(&i))
            .or_else(|| id.canonical.and_then(|c| self.by_path.get(&c)))
    }

    /// Refuses an output (`flag` names the option) that resolves to one of the inputs.
    pub fn check_output(&self, flag: &str, out: &Path) -> Result<()> {
        if let Some((what, input)) = self.clash(out) {
            bail!(
                "refusing to write {flag} {}: it is the same file as {what} {} (the input would be \
                 destroyed); choose another output path",
                out.display(),
                input.display()
            );
        }
        Ok(())
    }
}

impl Inputs {
    /// Refuses an output directory (`flag` names the option) that is one of the inputs or holds one.
    pub fn check_output_dir(&self, flag: &str, dir: &Path) -> Result<()> {
        self.check_output(flag, dir)?;
        let Ok(d) = dir.canonicalize() else {
            return Ok(());
        };
        let held = self
            .by_path
            .iter()
            .filter(|(c, _)| c.starts_with(&d))
            .min_by(|a, b| a.0.cmp(b.0));
        if let Some((_, (what, input))) = held {
            bail!(
                "refusing to write {flag} {}: the directory holds {what} {} (an input could be \
                 overwritten); choose another output directory",
                dir.display(),
                input.display()
            );
        }
        Ok(())
    }
}

/// Checks an output directory before any work (`flag` names the option, `command` the command): not a
/// file, not a reserved temporary name, its parent exists, it is not and holds no input, and when it exists
/// it holds only files named in `names` (an earlier run's) and temporary files.
pub fn check_owned_dir(
    inputs: &Inputs,
    flag: &str,
    dir: &Path,
    names: &[&str],
    command: &str,
) -> Result<()> {
    if depthcal::tempfiles::is_temp_path(dir) {
        bail!(
            "{flag} {}: names like .NAME.tmp-PID are reserved for temporary files",
            dir.display()
        );
    }
    if dir.exists() && !dir.is_dir() {
        bail!("{flag} {}: exists and is not a directory", dir.display());
    }
    if !dir.exists() {
        let parent = match dir.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        if !parent.is_dir() {
            bail!(
                "{flag} {}: the directory {} does not exist",
                dir.display(),
                parent.display()
            );
        }
    }
    inputs.check_output_dir(flag, dir)?;
    for n in names {
        inputs.check_output(flag, &dir.join(n))?;
    }
    if dir.is_dir() {
        let rd = std::fs::read_dir(dir)
            .map_err(|e| anyhow::anyhow!("reading {}: {e}", dir.display()))?;
        let mut foreign = Vec::new();
        for e in rd {
            let e = e.map_err(|e| anyhow::anyhow!("reading {}: {e}", dir.display()))?;
            let name = e.file_name().to_string_lossy().into_owned();
            let ours = names.contains(&name.as_str()) && e.path().is_file();
            if !ours && !depthcal::tempfiles::is_temp_path(&e.path()) {
                foreign.push(name);
            }
        }
        foreign.sort();
        if !foreign.is_empty() {
            bail!(
                "{flag} {}: the directory holds files {command} does not write ({}); give a new or \
                 empty directory, or one from an earlier {flag}",
                dir.display(),
                foreign.join(", ")
            );
        }
    }
    Ok(())
}

/// Checks an output file before any work: not a directory, its directory exists, and its extension is one
/// of `exts` (lower case, without the dot; empty: any).
pub fn check_output_file(flag: &str, out: &Path, exts: &[&str]) -> Result<()> {
    if out.is_dir() {
        bail!("{flag} {}: is a directory; give a file name", out.display());
    }
    if depthcal::tempfiles::is_temp_path(out) {
        bail!(
            "{flag} {}: names like .NAME.tmp-PID are reserved for temporary files",
            out.display()
        );
    }
    if !exts.is_empty() {
        let ext = out
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .unwrap_or_default();
        if !exts.contains(&ext.as_str()) {
            let list: Vec<String> = exts.iter().map(|e| format!(".{e}")).collect();
            bail!(
                "{flag} {}: unsupported output extension {}; written formats: {}",
                out.display(),
                if ext.is_empty() {
                    "(none)".to_string()
                } else {
                    format!(".{ext}")
                },
                list.join(", ")
            );
        }
    }
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        bail!(
            "{flag} {}: the directory {} does not exist",
            out.display(),
            dir.display()
        );
    }
    Ok(())
}

/// The most worker threads `--threads` (or RAYON_NUM_THREADS) may ask for: 8 per available core.
pub fn max_threads() -> usize {
    8 * std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Checks a thread count against [`max_threads`]; `what` names where it came from.
pub fn check_threads(what: &str, n: usize) -> std::result::Result<(), String> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if n == 0 {
        return Err(format!("{what} must be at least 1"));
    }
    if n > max_threads() {
        return Err(format!(
            "{what} {n} is more than {} (8 per core, {cores} cores available); more threads than that \
             only slow the work down",
            max_threads()
        ));
    }
    Ok(())
}
