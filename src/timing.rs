//! Stage timing: wall and CPU time of consecutive stages, with the number of items each took in and gave
//! out. The one timer of the pipelines (`register`, `calibrate`) and of `depthcal profile`.

use serde::Serialize;
use std::time::Instant;

/// One finished stage.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StageRecord {
    /// The stage's name (`scale`, `fpfh`, `icp`, ...).
    pub name: String,
    /// Wall time, milliseconds.
    pub wall_ms: f64,
    /// CPU time of the whole process over the stage (all threads, user + system), milliseconds; `None`
    /// where the platform does not say.
    pub cpu_ms: Option<f64>,
    /// Items the stage took in (points, descriptors, correspondences...), when it counts them.
    pub items_in: Option<usize>,
    /// Items it gave out.
    pub items_out: Option<usize>,
}

/// Times consecutive stages: each [`StageTimer::lap`] closes the stage that ran since the previous one.
#[derive(Debug)]
pub struct StageTimer {
    wall: Instant,
    cpu: Option<f64>,
    records: Vec<StageRecord>,
}

impl Default for StageTimer {
    fn default() -> Self {
        Self::new()
    }
}

impl StageTimer {
    /// A timer whose first stage starts now.
    pub fn new() -> Self {
        StageTimer {
            wall: Instant::now(),
            cpu: process_cpu_ms(),
            records: Vec::new(),
        }
    }

    /// Closes the current stage under `name` and starts the next.
    pub fn lap(&mut self, name: &str) {
        self.lap_counted(name, None, None);
    }

    /// As [`StageTimer::lap`], with the items the stage took in and gave out.
    pub fn lap_counted(&mut self, name: &str, items_in: Option<usize>, items_out: Option<usize>) {
        let now = Instant::now();
        let cpu = process_cpu_ms();
        self.records.push(StageRecord {
            name: name.to_string(),
            wall_ms: (now - self.wall).as_secs_f64() * 1e3,
            cpu_ms: cpu.zip(self.cpu).map(|(b, a)| (b - a).max(0.0)),
            items_in,
            items_out,
        });
        self.wall = now;
        self.cpu = cpu;
    }

    /// The finished stages, in order.
    pub fn records(&self) -> &[StageRecord] {
        &self.records
    }

    /// The finished stages.
    pub fn into_records(self) -> Vec<StageRecord> {
        self.records
    }

    /// `(name, wall ms)` of each finished stage, the `timings_ms` of the reports.
    pub fn wall_ms(&self) -> Vec<(String, f64)> {
        self.records
            .iter()
            .map(|r| (r.name.clone(), r.wall_ms))
            .collect()
    }
}

/// CPU time used by the whole process so far (all threads, user + system), milliseconds.
#[cfg(unix)]
pub fn process_cpu_ms() -> Option<f64> {
    // SAFETY: getrusage only writes the struct it is given; a zeroed rusage is a valid value of it.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: a valid pointer to a rusage owned by this frame.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) } != 0 {
        return None;
    }
    let ms = |t: libc::timeval| t.tv_sec as f64 * 1e3 + t.tv_usec as f64 * 1e-3;
    Some(ms(u.ru_utime) + ms(u.ru_stime))
}

/// CPU time used by the whole process so far: not known on this platform.
#[cfg(not(unix))]
pub fn process_cpu_ms() -> Option<f64> {
    None
}

/// The process's peak resident memory so far (Linux `VmHWM`), bytes; `None` where unknown.
pub fn peak_memory_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Resets the peak resident memory to the current one (Linux ≥ 4.0: `5` into `/proc/self/clear_refs`), so
/// that [`peak_memory_bytes`] measures what follows. Returns whether it could.
pub fn reset_peak_memory() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laps_are_consecutive_and_counted() {
        let mut t = StageTimer::new();
        let mut x = 0u64;
        for i in 0..2_000_000u64 {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(i);
        }
        t.lap_counted("work", Some(10), Some(3));
        t.lap("nothing");
        let r = t.records();
        assert_eq!(r.len(), 2);
        assert_eq!((r[0].items_in, r[0].items_out), (Some(10), Some(3)));
        assert!(r[0].wall_ms >= 0.0 && r[1].wall_ms >= 0.0, "{x}");
        if cfg!(unix) {
            assert!(r[0].cpu_ms.is_some());
        }
        assert_eq!(t.wall_ms()[1].0, "nothing");
    }

    #[test]
    fn memory_is_read_on_linux() {
        if cfg!(target_os = "linux") {
            let before = peak_memory_bytes().expect("VmHWM");
            let v = std::hint::black_box(vec![1u8; 64 << 20]);
            let after = peak_memory_bytes().unwrap();
            std::hint::black_box(v.iter().map(|&b| b as u64).sum::<u64>());
            assert!(
                after >= before && after >= v.len() as u64 / 2,
                "{before} {after}"
            );
        }
    }
}
