//! Is `depthcal calibrate` right on any cell, and does it say so? Families of cells that differ from each
//! other (the independent generator of `tests/common/foreign.rs` with its layouts, grounds, tables,
//! objects, the other robot in view, aims, depth artefacts and pose noise; and depthcal's own simulator),
//! many seeds each, run as a new user would (no priors, no `--config`), counted as right/wrong ×
//! trusted/refused. Beside it, each robot's frames fused by `depthcal fuse` and the two clouds registered
//! by `depthcal register`, to tell "the cell cannot be calibrated" from "calibrate misses what a plain
//! registration finds".
//!
//! * `cargo test --release --test trust_sweep smoke`: three small cells of different families (CI).
//! * `DEPTHCAL_TRUST_SWEEP=N cargo test --release --test trust_sweep sweep -- --nocapture`: N seeds per
//!   family (`DEPTHCAL_TRUST_SWEEP_FIRST=S`, default 1000: seeds no one tuned on;
//!   `DEPTHCAL_TRUST_SWEEP_FAMILIES=a,b` a subset by name; `DEPTHCAL_TRUST_SWEEP_ARGS="..."` extra
//!   calibrate arguments; `DEPTHCAL_BIN=PATH` a pinned copy of the binary, see `tests/common/mod.rs`;
//!   `DEPTHCAL_TRUST_SWEEP_KEEP=DIR` keeps each cell there instead of deleting it).
//!   One line per cell as it goes, then after each seed a Markdown table per family.
//! * The other tests check the generator's new options on small cells.
//!
//! Right = rotation error < 0.1° and translation error < 2 mm. Trusted = exit 0 and `trusted: true`;
//! refused = exit 3; anything else = failed. `z = sqrt(δᵀ Σ⁻¹ δ / 6)` (about 1 when the covariance is
//! honest; see `tests/common/outcome.rs`).

mod common;
use common::depthcal;
use common::foreign::{
    depth_edge, generate, Aim, ForeignConfig, Ground, Layout, Objects, Rand, SceneKind, TableShape,
};
use common::outcome::{calibrate, f, matrix4, Outcome};
use nalgebra::{Isometry3, Point3, Vector3};
use std::path::{Path, PathBuf};

// ---------------------------------------------------------------------------------------------------------
// Families.

/// The per-seed nuisance parameters every family draws.
#[derive(Clone, Copy, Debug)]
struct Nuisance {
    views: usize,
    width: u32,
    height: u32,
    /// Pose noise (mm, 1-σ per axis; rotation this x 0.05°): KUKA-like repeatability, 0-0.1 mm, except in
    /// the pose-noise family.
    pose_noise_mm: f64,
}

fn name_key(name: &str) -> u64 {
    name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x1000_0000_01b3)
    })
}

impl Nuisance {
    /// Drawn from the family's name and the seed: views 8..=30, 640x480 or 424x240, pose noise 0-0.1 mm.
    fn draw(family: &str, seed: u64) -> Self {
        let mut r = Rand::keyed(&[seed, name_key(family), 0x4e55]);
        let views = 8 + (r.uniform() * 23.0) as usize;
        let (width, height) = if r.uniform() < 0.5 {
            (640, 480)
        } else {
            (424, 240)
        };
        Nuisance {
            views: views.min(30),
            width,
            height,
            pose_noise_mm: r.range(0.0, 0.1),
        }
    }
}

/// How a family's cell is made.
#[derive(Clone, Copy)]
enum Source {
    /// The independent generator: a recipe on top of the defaults with the nuisance parameters (and a
    /// generator for the family's own draws).
    Foreign(fn(ForeignConfig, &mut Rand) -> ForeignConfig),
    /// `depthcal simulate DIR --seed N --frames F --overlap O --no-color`, calibrated with `--no-priors`.
    Simulator,
}

#[derive(Clone, Copy)]
struct Family {
    name: &'static str,
    source: Source,
}

fn families() -> Vec<Family> {
    use Source::Foreign;
    vec![
        Family {
            // The original cell (table on legs, floor below, facing robots); its views 8-30 per seed.
            name: "plain",
            source: Foreign(|c, _| c),
        },
        Family {
            // No table: the objects stand on the floor at table height; the other robot in view.
            name: "floor-level-arm",
            source: Foreign(|c, _| ForeignConfig {
                ground: Ground::FloorOnly,
                other_robot_in_view: true,
                ..c
            }),
        },
        Family {
            // Table on legs, the floor 0.7-0.8 m below, the other robot in view on a pedestal.
            name: "legs-arm-pedestal",
            source: Foreign(|c, _| ForeignConfig {
                ground: Ground::TableOnLegs,
                other_robot_in_view: true,
                pedestal: true,
                ..c
            }),
        },
        Family {
            // Nothing in range behind a square table.
            name: "nothing-square",
            source: Foreign(|c, _| ForeignConfig {
                ground: Ground::Nothing,
                square_table: true,
                ..c
            }),
        },
        Family {
            name: "round-table",
            source: Foreign(|c, _| ForeignConfig {
                table_shape: TableShape::Round,
                ..c
            }),
        },
        Family {
            name: "irregular-table",
            source: Foreign(|c, _| ForeignConfig {
                table_shape: TableShape::Irregular,
                ..c
            }),
        },
        Family {
            name: "symmetric-objects",
            source: Foreign(|c, _| ForeignConfig {
                objects: Objects::SymmetricOnly,
                ..c
            }),
        },
        Family {
            name: "right-angle",
            source: Foreign(|c, _| ForeignConfig {
                layout: Layout::RightAngle,
                ..c
            }),
        },
        Family {
            name: "side-by-side",
            source: Foreign(|c, _| ForeignConfig {
                layout: Layout::SideBySide,
                ..c
            }),
        },
        Family {
            name: "own-side",
            source: Foreign(|c, _| ForeignConfig {
                aim: Aim::OwnSide,
                ..c
            }),
        },
        Family {
            name: "low-overlap",
            source: Foreign(|c, _| ForeignConfig {
                aim: Aim::LowOverlap,
                ..c
            }),
        },
        Family {
            name: "flying-holes",
            source: Foreign(|c, _| ForeignConfig {
                flying_pixels: true,
                holes: true,
                ..c
            }),
        },
        Family {
            // Pose noise 0.1-2 mm (and 0.005-0.1°) per axis.
            name: "pose-noise",
            source: Foreign(|c, r| ForeignConfig {
                pose_noise_mm: r.range(0.1, 2.0),
                ..c
            }),
        },
        Family {
            name: "shelf",
            source: Foreign(|c, _| ForeignConfig {
                scene: SceneKind::ClutteredShelf,
                ..c
            }),
        },
        Family {
            name: "simulator",
            source: Source::Simulator,
        },
    ]
}

// ---------------------------------------------------------------------------------------------------------
// One cell.

/// The four outcomes (and failure) of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Class {
    RightTrusted,
    RightRefused,
    WrongRefused,
    WrongTrusted,
    Failed,
}

fn classify(o: &Outcome) -> Class {
    let trusted = o.code == 0 && o.trusted == Some(true);
    let refused = o.code == 3;
    match (trusted, refused, o.right()) {
        (true, _, true) => Class::RightTrusted,
        (true, _, false) => Class::WrongTrusted,
        (false, true, true) => Class::RightRefused,
        (false, true, false) => Class::WrongRefused,
        _ => Class::Failed,
    }
}

struct Row {
    family: &'static str,
    seed: u64,
    class: Class,
    cal: Outcome,
    /// `depthcal register` of the fused clouds (None when fusing failed).
    reg: Option<Outcome>,
}

/// A cell of `family` for `seed` in `dir`: its truth and a description.
fn make_cell(
    family: &Family,
    seed: u64,
    nz: Nuisance,
    dir: &Path,
) -> (Isometry3<f64>, String, Vec<String>) {
    match family.source {
        Source::Foreign(recipe) => {
            let base = ForeignConfig {
                seed,
                views: nz.views,
                width: nz.width,
                height: nz.height,
                pose_noise_mm: nz.pose_noise_mm,
                ..ForeignConfig::default()
            };
            let mut r = Rand::keyed(&[seed, name_key(family.name), 0xfa41]);
            let cfg = recipe(base, &mut r);
            let cell = generate(dir, &cfg);
            let desc = format!(
                "{}x{} v{} pn{:.2} share {:.2}/{:.2} gen {:.1}s",
                cfg.width,
                cfg.height,
                cfg.views,
                cfg.pose_noise_mm,
                cell.shared_fraction[0],
                cell.shared_fraction[1],
                cell.total_s
            );
            (cell.truth, desc, Vec::new())
        }
        Source::Simulator => {
            let mut r = Rand::keyed(&[seed, name_key(family.name), 0x5111]);
            let overlap = r.range(0.5, 0.8);
            let frames = nz.views.to_string();
            let (seed_s, overlap_s) = (seed.to_string(), format!("{overlap:.2}"));
            let t0 = std::time::Instant::now();
            let (code, _, err) = depthcal(&[
                "simulate",
                dir.to_str().unwrap(),
                "--seed",
                &seed_s,
                "--frames",
                &frames,
                "--overlap",
                &overlap_s,
                "--no-color",
                "--force",
                "--threads",
                "2",
            ]);
            assert_eq!(code, 0, "simulate: {err}");
            let gt: serde_json::Value = serde_json::from_str(
                &std::fs::read_to_string(dir.join("ground_truth.json")).unwrap(),
            )
            .unwrap();
            let truth = matrix4(&gt["T_base1_base2"]).expect("T_base1_base2");
            let desc = format!(
                "640x480 v{} overlap {overlap:.2} gen {:.1}s",
                nz.views,
                t0.elapsed().as_secs_f64()
            );
            (truth, desc, vec!["--no-priors".to_string()])
        }
    }
}

/// The cell's robots (reference first) from `cell.toml`, and per robot the first frame's depth file and
/// its intrinsics file (for the fusion settings).
fn cell_robots(dir: &Path) -> Vec<(String, Option<(PathBuf, PathBuf)>)> {
    let text = std::fs::read_to_string(dir.join("cell.toml")).unwrap();
    let v: toml::Value = toml::from_str(&text).unwrap();
    let reference = v["reference"].as_str().unwrap().to_string();
    let mut out: Vec<(String, Option<(PathBuf, PathBuf)>)> = v["robot"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let name = r["name"].as_str().unwrap().to_string();
            let files = (|| {
                let poses = std::fs::read_to_string(dir.join(r.get("poses")?.as_str()?)).ok()?;
                let first = poses
                    .lines()
                    .find(|l| !l.starts_with('#') && !l.starts_with("frame") && !l.is_empty())?
                    .split([',', ' ', '\t'])
                    .next()?
                    .to_string();
                let depth = r.get("depth")?.as_str()?.replace("{frame}", &first);
                Some((dir.join(depth), dir.join(r.get("intrinsics")?.as_str()?)))
            })();
            (name, files)
        })
        .collect();
    out.sort_by_key(|(n, _)| *n != reference);
    out
}

/// Reads a 16-bit greyscale PNG.
fn read_png16(path: &Path) -> Option<(usize, usize, Vec<u16>)> {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).ok()?));
    let mut rd = dec.read_info().ok()?;
    let mut buf = vec![0; rd.output_buffer_size()?];
    let info = rd.next_frame(&mut buf).ok()?;
    if info.bit_depth != png::BitDepth::Sixteen || info.color_type != png::ColorType::Grayscale {
        return None;
    }
    let data = buf[..info.buffer_size()]
        .chunks_exact(2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .collect();
    Some((info.width as usize, info.height as usize, data))
}

/// `depthcal fuse` settings as close to calibrate's as the CLI allows: calibrate's voxel is 4 x the median
/// pixel footprint of the first frame (fuse's default is 3 x), no outlier removal; calibrate's range cut
/// (2.5 x the median range) is approximated by `--max-depth` 2.5 x the first frame's median depth.
/// Normals on (the default).
fn fuse_args(depth: &Path, intrinsics: &Path) -> Option<Vec<String>> {
    let (_, _, d) = read_png16(depth)?;
    let intr: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(intrinsics).ok()?).ok()?;
    let fx = intr.get("fx")?.as_f64()?;
    let scale = intr
        .get("depth_scale")
        .and_then(|s| s.as_f64())
        .unwrap_or(0.001);
    let mut z: Vec<u16> = d.into_iter().filter(|&v| v > 0).collect();
    if z.is_empty() {
        return None;
    }
    let mid = z.len() / 2;
    let median = *z.select_nth_unstable(mid).1 as f64 * scale;
    Some(vec![
        "--voxel".into(),
        format!("{:.5}", 4.0 * median / fx),
        "--max-depth".into(),
        format!("{:.3}", 2.5 * median),
    ])
}

/// Fuses both robots and registers the other robot's cloud (base2) onto the reference's (base1).
fn register_fused(dir: &Path, truth: &Isometry3<f64>) -> Result<Outcome, String> {
    let robots = cell_robots(dir);
    let mut clouds = Vec::new();
    for (name, files) in &robots {
        let out = dir.join(format!("fused-{name}.ply"));
        let mut args: Vec<String> = vec![
            "fuse".into(),
            dir.to_str().unwrap().into(),
            "--robot".into(),
            name.clone(),
            "--output".into(),
            out.to_str().unwrap().into(),
            "--threads".into(),
            "2".into(),
            "--no-outlier-removal".into(),
        ];
        if let Some(extra) = files.as_ref().and_then(|(d, i)| fuse_args(d, i)) {
            args.extend(extra);
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, _, err) = depthcal(&args);
        if code != 0 {
            return Err(format!("fuse {name}: exit {code}: {}", last_line(&err)));
        }
        clouds.push(out);
    }
    let t0 = std::time::Instant::now();
    let (code, out, err) = depthcal(&[
        "register",
        clouds[1].to_str().unwrap(),
        clouds[0].to_str().unwrap(),
        "--json",
        "--threads",
        "2",
    ]);
    Ok(Outcome::parse(
        code,
        &out,
        err,
        truth,
        t0.elapsed().as_secs_f64(),
    ))
}

fn last_line(s: &str) -> String {
    s.lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("")
        .to_string()
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(n).collect::<String>())
    }
}

/// The hold test's figures (calibrate's JSON `degeneracy`): per tested direction its kind, the gap between
/// the two ICP ends as a fraction of the step, and `free` when it was not held; empty when none was tested.
fn hold_gaps(cal: &Outcome) -> String {
    let Some(d) = cal.json.as_ref().and_then(|j| j.get("degeneracy")) else {
        return String::new();
    };
    let mut items = Vec::new();
    for (list, free) in [("held", false), ("weak", true)] {
        for w in d.get(list).and_then(|l| l.as_array()).into_iter().flatten() {
            let Some(h) = w.get("hold") else { continue };
            let frac = match (
                h.get("gap").and_then(|g| g.as_f64()),
                h.get("step").and_then(|g| g.as_f64()),
            ) {
                (Some(g), Some(s)) if s > 0.0 => g / s,
                _ => f64::INFINITY,
            };
            let kind = w.get("kind").and_then(|k| k.as_str()).unwrap_or("?");
            items.push(format!(
                "{} {frac:.3}{}",
                &kind[..kind.len().min(3)],
                if free { " free" } else { "" }
            ));
        }
    }
    if items.is_empty() {
        String::new()
    } else {
        format!(" | hold gaps: {}", items.join(", "))
    }
}

/// The hypotheses calibrate judged at full resolution (its JSON's `hypotheses`), when there were several:
/// per hypothesis its error against the truth, surface agreement and free-space violation, `*` on the
/// chosen one; empty otherwise.
fn judged_hypotheses(cal: &Outcome, truth: &Isometry3<f64>) -> String {
    let Some(list) = cal
        .json
        .as_ref()
        .and_then(|j| j.get("hypotheses"))
        .and_then(|h| h.as_array())
        .filter(|h| h.len() > 1)
    else {
        return String::new();
    };
    let items: Vec<String> = list
        .iter()
        .map(|h| {
            let err = h.get("transform").and_then(matrix4).map(|t| {
                let d = t * truth.inverse();
                (
                    d.rotation.angle().to_degrees(),
                    d.translation.vector.norm() * 1e3,
                )
            });
            let num = |k: &str| h.get(k).and_then(|v| v.as_f64());
            format!(
                "{}{}°/{}mm agr {} fs {}%",
                if h.get("chosen").and_then(|c| c.as_bool()) == Some(true) {
                    "*"
                } else {
                    ""
                },
                f(err.map(|e| e.0), 2),
                f(err.map(|e| e.1), 1),
                f(num("agreement"), 3),
                f(num("free_space_violation").map(|v| v * 1e2), 1)
            )
        })
        .collect();
    format!(" | hypotheses: {}", items.join("; "))
}

/// Generates, calibrates, fuses and registers one cell, prints its line and deletes it (or moves it into
/// `DEPTHCAL_TRUST_SWEEP_KEEP`, a directory, when that is set).
fn run_cell(
    family: &Family,
    seed: u64,
    nz: Nuisance,
    extra: &[String],
    with_register: bool,
) -> Row {
    let t0 = std::time::Instant::now();
    let dir = common::scratch(&format!("trust-{}-{seed}", family.name));
    let (truth, desc, mut args) = make_cell(family, seed, nz, &dir);
    args.extend(extra.iter().cloned());
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let cal = calibrate(&dir, &truth, &args);
    let class = classify(&cal);
    let reg = if with_register {
        match register_fused(&dir, &truth) {
            Ok(o) => Some(o),
            Err(e) => {
                println!("    register: {e}");
                None
            }
        }
    } else {
        None
    };
    let reason = if class == Class::Failed {
        format!(
            "FAILED exit {}: {}",
            cal.code,
            truncate(&last_line(&cal.stderr), 200)
        )
    } else {
        cal.reasons
            .first()
            .map_or(String::new(), |r| truncate(r, 100))
    };
    let hypotheses = judged_hypotheses(&cal, &truth);
    let holds = hold_gaps(&cal);
    println!(
        "{:<18} {:>5} {:<13} err {:>8}° {:>7} mm  σ {:>7}° {:>6} mm  z {:>6}  exit {} trusted {:<5} {:>5.1}s | \
         register {:>8}° {:>7} mm exit {} | cell {:.0}s, {desc} | {reason}{holds}{hypotheses}",
        family.name,
        seed,
        format!("{class:?}"),
        f(cal.rot_deg, 4),
        f(cal.trans_mm, 2),
        f(cal.sigma_rot_deg, 4),
        f(cal.sigma_trans_mm, 2),
        f(cal.z(), 2),
        cal.code,
        cal.trusted.map_or("-".into(), |t| t.to_string()),
        cal.secs,
        f(reg.as_ref().and_then(|r| r.rot_deg), 4),
        f(reg.as_ref().and_then(|r| r.trans_mm), 2),
        reg.as_ref().map_or("-".into(), |r| r.code.to_string()),
        t0.elapsed().as_secs_f64(),
    );
    match std::env::var_os("DEPTHCAL_TRUST_SWEEP_KEEP") {
        Some(keep) => {
            let to = PathBuf::from(keep).join(format!("{}-{seed}", family.name));
            let _ = std::fs::remove_dir_all(&to);
            std::fs::create_dir_all(to.parent().unwrap()).unwrap();
            if std::fs::rename(&dir, &to).is_err() {
                println!("    could not keep the cell at {}", to.display());
                let _ = std::fs::remove_dir_all(&dir);
            }
        }
        None => {
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
    Row {
        family: family.name,
        seed,
        class,
        cal,
        reg,
    }
}

// ---------------------------------------------------------------------------------------------------------
// The table.

#[derive(Default, Clone, Copy, Debug, PartialEq, Eq)]
struct Tally {
    cells: usize,
    right_trusted: usize,
    right_refused: usize,
    wrong_refused: usize,
    wrong_trusted: usize,
    failed: usize,
    trusted: usize,
    trusted_z_below_3: usize,
    register_right: usize,
    cal_wrong_register_right: usize,
}

impl Tally {
    fn add(&mut self, r: &Row) {
        self.cells += 1;
        match r.class {
            Class::RightTrusted => self.right_trusted += 1,
            Class::RightRefused => self.right_refused += 1,
            Class::WrongRefused => self.wrong_refused += 1,
            Class::WrongTrusted => self.wrong_trusted += 1,
            Class::Failed => self.failed += 1,
        }
        if matches!(r.class, Class::RightTrusted | Class::WrongTrusted) {
            self.trusted += 1;
            if r.cal.z().is_some_and(|z| z < 3.0) {
                self.trusted_z_below_3 += 1;
            }
        }
        let reg_right = r.reg.as_ref().is_some_and(|o| o.right());
        if reg_right {
            self.register_right += 1;
            if !r.cal.right() {
                self.cal_wrong_register_right += 1;
            }
        }
    }

    fn sum(&self) -> usize {
        self.right_trusted
            + self.right_refused
            + self.wrong_refused
            + self.wrong_trusted
            + self.failed
    }

    fn line(&self, name: &str) -> String {
        format!(
            "| {name} | {} | {} | {} | {} | {} | {} | {}/{} | {} | {} |",
            self.cells,
            self.right_trusted,
            self.right_refused,
            self.wrong_refused,
            self.wrong_trusted,
            self.failed,
            self.trusted_z_below_3,
            self.trusted,
            self.register_right,
            self.cal_wrong_register_right
        )
    }
}

/// The Markdown table of `rows`, one line per family (in `order`) and a total.
fn table(rows: &[Row], order: &[&str]) -> (String, Tally) {
    let mut out = String::from(
        "| family | cells | right & trusted | right but refused | wrong & refused | wrong & trusted | failed \
         | trusted z<3 / trusted | register right | calibrate wrong, register right |\n\
         |---|---|---|---|---|---|---|---|---|---|\n",
    );
    let mut total = Tally::default();
    for name in order {
        let mut t = Tally::default();
        for r in rows.iter().filter(|r| r.family == *name) {
            t.add(r);
            total.add(r);
        }
        if t.cells > 0 {
            out.push_str(&t.line(name));
            out.push('\n');
        }
    }
    out.push_str(&total.line("**total**"));
    out.push('\n');
    (out, total)
}

fn env_list(name: &str) -> Option<Vec<String>> {
    std::env::var(name).ok().map(|s| {
        s.split([',', ' '])
            .filter(|x| !x.is_empty())
            .map(String::from)
            .collect()
    })
}

/// The full sweep: `DEPTHCAL_TRUST_SWEEP=N` seeds per family (see the file's doc).
#[test]
fn sweep() {
    let Some(n) = std::env::var("DEPTHCAL_TRUST_SWEEP")
        .ok()
        .and_then(|s| s.parse::<u64>().ok())
    else {
        println!(
            "set DEPTHCAL_TRUST_SWEEP=N to run the sweep: DEPTHCAL_TRUST_SWEEP=6 cargo test --release --test \
             trust_sweep sweep -- --nocapture (DEPTHCAL_TRUST_SWEEP_FIRST=S, DEPTHCAL_TRUST_SWEEP_FAMILIES=a,b, \
             DEPTHCAL_TRUST_SWEEP_ARGS=\"...\")"
        );
        return;
    };
    let first = std::env::var("DEPTHCAL_TRUST_SWEEP_FIRST")
        .ok()
        .and_then(|s| s.parse::<u64>().ok())
        .unwrap_or(1000);
    let extra = env_list("DEPTHCAL_TRUST_SWEEP_ARGS").unwrap_or_default();
    let all = families();
    let chosen: Vec<Family> = match env_list("DEPTHCAL_TRUST_SWEEP_FAMILIES") {
        Some(names) => {
            for n in &names {
                assert!(
                    all.iter().any(|f| f.name == n),
                    "unknown family {n:?}; the families: {:?}",
                    all.iter().map(|f| f.name).collect::<Vec<_>>()
                );
            }
            all.into_iter()
                .filter(|f| names.iter().any(|n| n == f.name))
                .collect()
        }
        None => all,
    };
    println!(
        "trust sweep: {n} seeds ({first}..) x {} families, calibrate args {extra:?}",
        chosen.len()
    );
    let t0 = std::time::Instant::now();
    let mut rows = Vec::new();
    // Seed-major so that a run stopped early still covers every family.
    for seed in first..first + n {
        for fam in &chosen {
            rows.push(run_cell(
                fam,
                seed,
                Nuisance::draw(fam.name, seed),
                &extra,
                true,
            ));
        }
        let order: Vec<&str> = chosen.iter().map(|f| f.name).collect();
        println!(
            "\nafter seed {seed} ({:.0} s, {:.1} s per cell):\n{}",
            t0.elapsed().as_secs_f64(),
            t0.elapsed().as_secs_f64() / rows.len() as f64,
            table(&rows, &order).0
        );
    }
    let wrong_trusted: Vec<String> = rows
        .iter()
        .filter(|r| r.class == Class::WrongTrusted)
        .map(|r| format!("{} seed {}", r.family, r.seed))
        .collect();
    println!("wrong and trusted: {wrong_trusted:?}");
}

/// CI: three small cells from different families run end to end; the counts add up and no cell is wrong
/// and trusted (or failed).
#[test]
fn smoke() {
    let all = families();
    let pick = |name: &str| *all.iter().find(|f| f.name == name).unwrap();
    let cells = [
        (pick("floor-level-arm"), 1000, 10),
        (pick("round-table"), 1001, 8),
        (pick("own-side"), 1002, 10),
    ];
    let mut rows = Vec::new();
    for (fam, seed, views) in cells {
        let nz = Nuisance {
            views,
            width: 424,
            height: 240,
            ..Nuisance::draw(fam.name, seed)
        };
        rows.push(run_cell(&fam, seed, nz, &[], true));
    }
    let order: Vec<&str> = cells.iter().map(|c| c.0.name).collect();
    let (text, total) = table(&rows, &order);
    println!("{text}");
    assert_eq!(total.cells, cells.len());
    assert_eq!(total.sum(), total.cells, "{total:?}");
    assert!(total.trusted_z_below_3 <= total.trusted);
    assert_eq!(
        total.wrong_trusted, 0,
        "a cell is wrong and trusted:\n{text}"
    );
    assert_eq!(total.failed, 0, "a run failed:\n{text}");
}

/// A held-out cell whose answer is a loose basin's: own-side seed 2002 (views at each robot's own side),
/// fused as before the fusion voxel's bound (`fuse.max_auto_voxel_m` null: 13-15 mm voxels), came out
/// 0.25° / 3.0 mm off and trusted, its yaw held only loosely (the hold test's two ICP runs ended 0.16 of a
/// voxel apart, right answers at most 0.046). It must not be trusted while that wrong, and the reason must
/// say what the hold test measured. (With the bound, at 11 mm, the same cell comes out 0.243° off in a
/// basin the hold test holds, and is trusted: docs/accuracy.md, "The fusion voxel's largest edge".)
#[test]
fn a_loosely_held_answer_is_not_trusted() {
    let all = families();
    let fam = *all.iter().find(|f| f.name == "own-side").unwrap();
    let cfg = common::scratch("trust-unbounded-voxel").join("config.json");
    std::fs::write(&cfg, r#"{"fuse": {"max_auto_voxel_m": null}}"#).unwrap();
    let extra = ["--config".to_string(), cfg.display().to_string()];
    let row = run_cell(&fam, 2002, Nuisance::draw(fam.name, 2002), &extra, false);
    println!("{:?} {:?}", row.class, row.cal.reasons);
    assert_ne!(row.class, Class::Failed, "{:?}", row.cal.stderr);
    assert_ne!(row.class, Class::WrongTrusted, "{:?}", row.cal.reasons);
    if row.class == Class::WrongRefused {
        let said = row.cal.reasons.join(" ");
        assert!(
            said.contains("only loosely")
                || said.contains("only weakly")
                || said.contains("unconstrained"),
            "{said}"
        );
    }
}

/// Held-out cells whose automatic fusion voxel is coarse (424-pixel cameras, a far floor in the first
/// frame: 19 and 23 mm) and whose answers were wrong and trusted at it, just past the bar (irregular-table
/// 2002 0.163° / 1.3 mm, round-table 7000 0.122° / 1.9 mm): fused at no coarser than 11 mm they are right
/// (0.004° and 0.016°).
#[test]
fn coarsely_fused_cells_are_right_with_the_voxel_bounded() {
    let all = families();
    for (name, seed) in [("irregular-table", 2002), ("round-table", 7000)] {
        let fam = *all.iter().find(|f| f.name == name).unwrap();
        let row = run_cell(&fam, seed, Nuisance::draw(fam.name, seed), &[], false);
        println!("{name} {seed}: {:?} {:?}", row.class, row.cal.reasons);
        assert_eq!(
            row.class,
            Class::RightTrusted,
            "{name} {seed}: {:?}",
            row.cal.reasons
        );
    }
}

// ---------------------------------------------------------------------------------------------------------
// The generator's new options.

fn scratch_cell(name: &str, cfg: &ForeignConfig) -> common::foreign::ForeignCell {
    generate(&common::scratch(&format!("trust-gen-{name}")), cfg)
}

fn small(seed: u64) -> ForeignConfig {
    ForeignConfig {
        seed,
        views: 6,
        width: 320,
        height: 240,
        ..ForeignConfig::default()
    }
}

/// The points of robot `k`'s depth frames in base1, read back from the files (intrinsics, the true flange
/// poses and hand-eye the generator returned).
fn world_points(cell: &common::foreign::ForeignCell, k: usize) -> Vec<Point3<f64>> {
    let name = &cell.config.names[k];
    let intr: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(cell.dir.join(name).join("intrinsics.json")).unwrap(),
    )
    .unwrap();
    let g = |s: &str| intr[s].as_f64().unwrap();
    let (fx, fy, ppx, ppy, scale) = (g("fx"), g("fy"), g("ppx"), g("ppy"), g("depth_scale"));
    let to_base1 = if k == 0 {
        Isometry3::identity()
    } else {
        cell.truth
    };
    let mut out = Vec::new();
    for (i, t_base_ee) in cell.t_base_ee[k].iter().enumerate() {
        let (w, _, d) = read_png16(
            &cell
                .dir
                .join(name)
                .join("depth")
                .join(format!("{i:04}.png")),
        )
        .unwrap();
        let t = to_base1 * t_base_ee * cell.t_ee_cam[k];
        for (j, &v) in d.iter().enumerate() {
            if v == 0 {
                continue;
            }
            let z = v as f64 * scale;
            let (u, vv) = ((j % w) as f64, (j / w) as f64);
            out.push(t * Point3::new((u - ppx) / fx * z, (vv - ppy) / fy * z, z));
        }
    }
    out
}

/// The idle robot's arm shows in the other robot's depth, never in its own, and not without the option.
#[test]
fn the_other_robot_shows_in_the_other_robots_depth_only() {
    let with = ForeignConfig {
        other_robot_in_view: true,
        width: 424,
        ..small(11)
    };
    let a = scratch_cell("arm", &with);
    let b = scratch_cell(
        "no-arm",
        &ForeignConfig {
            other_robot_in_view: false,
            ..with.clone()
        },
    );
    let bases = [Vector3::zeros(), a.truth.translation.vector];
    // Points on a base's vertical axis (within 0.12 m) well above the table: only an arm can be there.
    let on_arm = |pts: &[Point3<f64>], base: &Vector3<f64>| {
        pts.iter()
            .filter(|p| {
                (p.coords - base).xy().norm() < 0.12
                    && p.z > a.table_top + 0.05
                    && p.z < base.z + 1.4
            })
            .count()
    };
    for k in 0..2 {
        let (pa, pb) = (world_points(&a, k), world_points(&b, k));
        let (other_a, own_a, other_b) = (
            on_arm(&pa, &bases[1 - k]),
            on_arm(&pa, &bases[k]),
            on_arm(&pb, &bases[1 - k]),
        );
        println!(
            "robot {k}: other arm {other_a} points (without the option {other_b}), own {own_a}"
        );
        assert!(
            other_a > 100,
            "robot {k} sees {other_a} points of the other arm"
        );
        assert_eq!(own_a, 0, "robot {k} sees itself");
        assert_eq!(other_b, 0, "robot {k} sees an arm that is not there");
    }
    let _ = std::fs::remove_dir_all(&a.dir);
    let _ = std::fs::remove_dir_all(&b.dir);
}

/// Aiming toward the own side shares less: own-side about 50-70 %, low overlap about 15-30 % (measured by
/// the generator's own shared fraction on small cells, a few seeds).
#[test]
fn own_side_and_low_overlap_share_what_they_should() {
    for seed in [21, 22] {
        let mut shares = Vec::new();
        for aim in [Aim::Shared, Aim::OwnSide, Aim::LowOverlap] {
            let c = scratch_cell(
                &format!("aim-{}-{seed}", aim.name()),
                &ForeignConfig {
                    aim,
                    views: 10,
                    ..small(seed)
                },
            );
            let s = (c.shared_fraction[0] + c.shared_fraction[1]) / 2.0;
            println!(
                "seed {seed} {}: shared {:.3?}",
                aim.name(),
                c.shared_fraction
            );
            shares.push(s);
            let _ = std::fs::remove_dir_all(&c.dir);
        }
        assert!(shares[0] > 0.7, "shared {shares:?}");
        assert!((0.45..=0.75).contains(&shares[1]), "own side {shares:?}");
        assert!((0.12..=0.33).contains(&shares[2]), "low overlap {shares:?}");
    }
}

/// Flying pixels differ from the plain cell's depth only next to its depth edges; holes only remove data,
/// in blobs.
#[test]
fn flying_pixels_sit_on_depth_edges_and_holes_are_blobs() {
    let plain = small(31);
    let a = scratch_cell("fly-plain", &plain);
    let b = scratch_cell(
        "fly",
        &ForeignConfig {
            flying_pixels: true,
            ..plain.clone()
        },
    );
    let c = scratch_cell(
        "holes",
        &ForeignConfig {
            holes: true,
            ..plain.clone()
        },
    );
    let (mut changed, mut off_edge, mut holes, mut holes_in_blobs) = (0, 0, 0, 0);
    for name in &plain.names {
        for i in 0..plain.views {
            let file = |cell: &common::foreign::ForeignCell| {
                read_png16(
                    &cell
                        .dir
                        .join(name)
                        .join("depth")
                        .join(format!("{i:04}.png")),
                )
                .unwrap()
            };
            let ((w, h, da), (_, _, db), (_, _, dc)) = (file(&a), file(&b), file(&c));
            // The plain depth in metres, as the "clean" image of the edge test (5x5: its own dropout
            // may hide one side).
            let za: Vec<f32> = da.iter().map(|&d| d as f32 * 1e-3).collect();
            for j in 0..w * h {
                let (u, v) = (j % w, j / w);
                if da[j] != db[j] {
                    changed += 1;
                    let near_edge = (v.saturating_sub(1)..(v + 2).min(h)).any(|y| {
                        (u.saturating_sub(1)..(u + 2).min(w))
                            .any(|x| depth_edge(&za, w, h, x, y).is_some())
                    });
                    if !near_edge {
                        off_edge += 1;
                    }
                }
                if da[j] != dc[j] {
                    assert_eq!(dc[j], 0, "holes only remove data");
                    holes += 1;
                    let zero_neighbours = [(0i64, 1i64), (1, 0), (0, -1), (-1, 0)]
                        .iter()
                        .filter(|(dx, dy)| {
                            let (x, y) = (u as i64 + dx, v as i64 + dy);
                            x >= 0
                                && y >= 0
                                && (x as usize) < w
                                && (y as usize) < h
                                && dc[y as usize * w + x as usize] == 0
                        })
                        .count();
                    if zero_neighbours >= 2 {
                        holes_in_blobs += 1;
                    }
                }
            }
        }
    }
    println!(
        "flying pixels: {changed} changed, {off_edge} away from an edge; holes: {holes} pixels, \
         {holes_in_blobs} with 2+ empty neighbours"
    );
    assert!(changed > 100, "{changed} flying pixels");
    // The plain depth has its own dropout and range / incidence cuts, which hide a few of the edges the
    // generator saw in the noise-free depth.
    assert!(
        off_edge * 20 <= changed,
        "{off_edge} of {changed} away from an edge"
    );
    assert!(holes > 200, "{holes} hole pixels");
    assert!(
        holes_in_blobs * 10 >= holes * 8,
        "{holes_in_blobs} of {holes} in blobs"
    );
    for cell in [a, b, c] {
        let _ = std::fs::remove_dir_all(&cell.dir);
    }
}

/// Pose noise changes `poses.csv` by about the stated σ but not the depth.
#[test]
fn pose_noise_changes_the_poses_not_the_depth() {
    let plain = ForeignConfig {
        views: 8,
        ..small(41)
    };
    let a = scratch_cell("pn-plain", &plain);
    let b = scratch_cell(
        "pn",
        &ForeignConfig {
            pose_noise_mm: 1.0,
            ..plain.clone()
        },
    );
    let rows = |cell: &common::foreign::ForeignCell, name: &str| -> Vec<Vec<f64>> {
        std::fs::read_to_string(cell.dir.join(name).join("poses.csv"))
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| l.split(',').skip(1).map(|s| s.parse().unwrap()).collect())
            .collect()
    };
    let mut sq = Vec::new();
    for name in &plain.names {
        for (ra, rb) in rows(&a, name).iter().zip(rows(&b, name).iter()) {
            for k in 0..3 {
                sq.push((ra[k] - rb[k]).powi(2));
            }
        }
        for i in 0..plain.views {
            let p = |c: &common::foreign::ForeignCell| {
                std::fs::read(c.dir.join(name).join("depth").join(format!("{i:04}.png"))).unwrap()
            };
            assert_eq!(p(&a), p(&b), "{name} frame {i}: the depth changed");
        }
    }
    let rms = (sq.iter().sum::<f64>() / sq.len() as f64).sqrt();
    println!(
        "pose noise 1 mm: RMS change per axis {rms:.3} mm over {} values",
        sq.len()
    );
    assert!((0.6..1.5).contains(&rms), "RMS {rms} mm");
    let _ = std::fs::remove_dir_all(&a.dir);
    let _ = std::fs::remove_dir_all(&b.dir);
}

/// Every layout, ground and table shape makes a cell both robots see a good part of.
#[test]
fn new_layouts_grounds_and_tables_give_overlapping_cells() {
    let cases = [
        (
            "right-angle",
            ForeignConfig {
                layout: Layout::RightAngle,
                ..small(51)
            },
        ),
        (
            "side-by-side",
            ForeignConfig {
                layout: Layout::SideBySide,
                ..small(52)
            },
        ),
        (
            "floor-only",
            ForeignConfig {
                ground: Ground::FloorOnly,
                pedestal: true,
                ..small(53)
            },
        ),
        (
            "round",
            ForeignConfig {
                table_shape: TableShape::Round,
                ..small(54)
            },
        ),
        (
            "irregular",
            ForeignConfig {
                table_shape: TableShape::Irregular,
                objects: Objects::SymmetricOnly,
                ..small(55)
            },
        ),
    ];
    for (name, cfg) in cases {
        let c = scratch_cell(name, &cfg);
        let gt: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(c.dir.join("ground_truth.json")).unwrap(),
        )
        .unwrap();
        println!(
            "{name}: shared {:.3?}, valid {:.3?}, ground_truth {} / {} / {} / {}",
            c.shared_fraction,
            c.valid_fraction,
            gt["layout"],
            gt["ground"],
            gt["table_shape"],
            gt["objects"]
        );
        assert_eq!(gt["layout"], cfg.layout.name());
        assert_eq!(gt["ground"], cfg.effective_ground().name());
        assert!(
            c.shared_fraction.iter().all(|&s| s > 0.4),
            "{name}: {:?}",
            c.shared_fraction
        );
        assert!(
            c.valid_fraction.iter().all(|&s| s > 0.5),
            "{name}: {:?}",
            c.valid_fraction
        );
        let _ = std::fs::remove_dir_all(&c.dir);
    }
}
