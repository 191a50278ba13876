//! The bad-input table of `docs/bad-inputs.md`, one test per row: each test writes the row's input into a
//! scratch directory, runs the row's command (paths relative to that directory), and checks the exit status
//! and that the message contains the row's excerpt; it also checks that no file in the directory changed
//! and none was added, and that nothing panicked. `every_row_has_a_test_and_every_test_a_row` keeps the
//! table and the tests one for one. `DEPTHCAL_BAD_INPUTS_PRINT=1` prints what each row's command does.

mod common;
use common::{depthcal, listing, scratch};
use std::path::{Path, PathBuf};

/// One row of the table: id, input description, command, message excerpt, exit status.
#[derive(Debug, Clone)]
struct Row {
    id: String,
    command: String,
    message: String,
    exit: i32,
}

fn table() -> Vec<Row> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/bad-inputs.md");
    let text = std::fs::read_to_string(&path).expect("docs/bad-inputs.md");
    let mut rows = Vec::new();
    for line in text.lines() {
        let cells: Vec<&str> = line.split(" | ").map(str::trim).collect();
        if !line.starts_with("| B") || cells.len() != 5 {
            continue;
        }
        let unquote = |s: &str| s.trim_matches('`').trim().replace("\\|", "|");
        rows.push(Row {
            id: cells[0].trim_start_matches("| ").to_string(),
            command: unquote(cells[2]),
            message: unquote(cells[3]),
            exit: cells[4]
                .trim_end_matches(" |")
                .trim()
                .parse()
                .expect("exit status"),
        });
    }
    rows
}

fn demo_cell() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("clouds/demo-cell")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let p = e.path();
        if p.is_dir() {
            copy_dir(&p, &to.join(e.file_name()));
        } else {
            std::fs::copy(&p, to.join(e.file_name())).unwrap();
        }
    }
}

/// A copy of the demo cell in `dir/cell` with `edit` applied to its cell.toml.
fn cell_with(dir: &Path, edit: impl Fn(String) -> String) {
    copy_dir(&demo_cell(), &dir.join("cell"));
    let m = dir.join("cell/cell.toml");
    let text = std::fs::read_to_string(&m).unwrap();
    std::fs::write(&m, edit(text)).unwrap();
}

/// Edits a JSON file of the cell copy.
fn edit_json(path: &Path, edit: impl Fn(&mut serde_json::Value)) {
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

/// A small valid ASCII PLY of `n` points on a curved patch.
fn ply(n: usize) -> String {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    );
    for i in 0..n {
        let (x, y) = ((i % 20) as f64 * 0.01, (i / 20) as f64 * 0.01);
        s.push_str(&format!("{x} {y} {}\n", 0.3 * (x * x - y * y)));
    }
    s
}

fn two_clouds(dir: &Path) {
    std::fs::write(dir.join("s.ply"), ply(400)).unwrap();
    std::fs::write(dir.join("t.ply"), ply(400)).unwrap();
}

fn npy(shape: &str, data: &[f32]) -> Vec<u8> {
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

fn pcd_ascii(fields: &str, size: &str, ty: &str, count: &str, points: &str, body: &str) -> String {
    format!(
        "# .PCD v0.7\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\nTYPE {ty}\nCOUNT {count}\nWIDTH {points}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA ascii\n{body}"
    )
}

const KUKA_HEADER: &str = "frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n";

/// Runs row `id`: `setup` writes the input into the scratch directory and returns the arguments (paths
/// relative to the directory, which is the working directory of the command).
fn run_row(id: &str, setup: impl Fn(&Path) -> Vec<String>) {
    let rows = table();
    let row = rows.iter().find(|r| r.id == id).cloned();
    let dir = scratch(&format!("bad-{id}"));
    let args = setup(&dir);
    let command = format!("depthcal {}", args.join(" "));
    let before = listing(&dir);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_depthcal"))
        .args(&args)
        .current_dir(&dir)
        .output()
        .expect("run depthcal");
    let code = out.status.code().unwrap_or(-1);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    if std::env::var("DEPTHCAL_BAD_INPUTS_PRINT").is_ok() {
        println!("{id} | `{command}` | exit {code}\n  stderr: {stderr}");
    }
    assert!(!stderr.contains("panicked"), "{id}: panic: {stderr}");
    let row = row.unwrap_or_else(|| panic!("{id} has no row in docs/bad-inputs.md"));
    assert_eq!(row.command, command, "{id}: the table's command");
    assert_eq!(code, row.exit, "{id}: exit status; stderr: {stderr}");
    let all = format!("{stderr}{stdout}");
    assert!(
        all.contains(&row.message),
        "{id}: message {:?} not in: {all}",
        row.message
    );
    let after = listing(&dir);
    assert!(
        before == after,
        "{id}: the command changed or added files in its directory"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

fn s(v: &[&str]) -> Vec<String> {
    v.iter().map(|x| x.to_string()).collect()
}

macro_rules! rows {
    ($($id:ident => $setup:expr;)*) => {
        $(
            #[test]
            #[allow(non_snake_case)]
            fn $id() {
                run_row(stringify!($id), $setup);
            }
        )*
        const TESTED: &[&str] = &[$(stringify!($id)),*];
    };
}

#[test]
fn every_row_has_a_test_and_every_test_a_row() {
    let rows = table();
    let mut ids: Vec<&str> = rows.iter().map(|r| r.id.as_str()).collect();
    ids.sort_unstable();
    let mut tested = TESTED.to_vec();
    tested.sort_unstable();
    assert_eq!(ids, tested, "docs/bad-inputs.md rows vs tests");
    assert!(rows.len() >= 40, "{} rows", rows.len());
}

#[allow(dead_code)]
fn _unused() {
    let _ = depthcal;
}

rows! {
    B01 => |_d: &Path| s(&["register", "missing.ply", "t.ply"]);
    B02 => |d: &Path| { two_clouds(d); std::fs::write(d.join("s.foo"), "1 2 3\n").unwrap(); s(&["register", "s.foo", "t.ply"]) };
    B03 => |d: &Path| { two_clouds(d); std::fs::write(d.join("e.ply"), ply(0)).unwrap(); s(&["register", "e.ply", "t.ply"]) };
    B04 => |d: &Path| { two_clouds(d); let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec(); b.extend_from_slice(&[0u8; 100]); std::fs::write(d.join("b.ply"), b).unwrap(); s(&["register", "b.ply", "t.ply"]) };
    B05 => |d: &Path| { two_clouds(d); let p = ply(400).replacen("element vertex 400", "element vertex 300", 1); std::fs::write(d.join("u.ply"), p).unwrap(); s(&["register", "u.ply", "t.ply"]) };
    B06 => |d: &Path| { two_clouds(d); std::fs::write(d.join("c.pcd"), pcd_ascii("x y z", "4 4 4", "F F F", "0 0 0", "2", "1 2 3\n4 5 6\n")).unwrap(); s(&["register", "c.pcd", "t.ply"]) };
    B07 => |d: &Path| { two_clouds(d); std::fs::write(d.join("h.pcd"), pcd_ascii("x y z", "4 4 4", "F F F", "1 1 1", "10000000000", "1 2 3\n")).unwrap(); s(&["register", "h.pcd", "t.ply"]) };
    B08 => |d: &Path| { two_clouds(d); std::fs::write(d.join("w.pcd"), pcd_ascii("x y z", "4 4 4", "F F F", "1 1 1", "4611686018427387904", "1 2 3\n")).unwrap(); s(&["register", "w.pcd", "t.ply"]) };
    B09 => |d: &Path| { two_clouds(d); std::fs::write(d.join("r.pcd"), pcd_ascii("x y z rgb", "4 4 4 1", "F F F U", "1 1 1 1", "1", "1 2 3 4\n")).unwrap(); s(&["register", "r.pcd", "t.ply"]) };
    B10 => |d: &Path| { two_clouds(d); std::fs::write(d.join("big.npy"), npy("(4611686018427387904, 3)", &[1.0; 6])).unwrap(); s(&["register", "big.npy", "t.ply"]) };
    B11 => |d: &Path| { two_clouds(d); std::fs::write(d.join("tr.npy"), npy("(3, 100)", &[0.5; 300])).unwrap(); s(&["register", "tr.npy", "t.ply"]) };
    B12 => |d: &Path| { two_clouds(d); std::fs::write(d.join("x.xyz"), "0.1 0.2 zz\n0.1 0.2 0.3\n").unwrap(); s(&["register", "x.xyz", "t.ply"]) };
    B13 => |d: &Path| { two_clouds(d); std::fs::write(d.join("y.xyz"), "0.1 0.2 0.3\n0.4 0.5 0.6\n0.7 oops 0.9\n").unwrap(); s(&["register", "y.xyz", "t.ply"]) };
    B14 => |d: &Path| { two_clouds(d); s(&["register", "s.ply", "t.ply", "--output", "s.ply"]) };
    B15 => |d: &Path| { two_clouds(d); std::os::unix::fs::symlink("t.ply", d.join("link.ply")).unwrap(); s(&["register", "s.ply", "t.ply", "--output", "link.ply"]) };
    B16 => |d: &Path| { two_clouds(d); std::fs::hard_link(d.join("s.ply"), d.join("hard.ply")).unwrap(); s(&["register", "s.ply", "t.ply", "--output", "hard.ply"]) };
    B17 => |d: &Path| { two_clouds(d); s(&["register", "s.ply", "t.ply", "--output", "no/dir/o.ply"]) };
    B18 => |d: &Path| { two_clouds(d); s(&["register", "s.ply", "t.ply", "--output", "o.pcd"]) };
    B19 => |d: &Path| { two_clouds(d); s(&["register", "s.ply", "t.ply", "--threads", "100000"]) };
    B20 => |d: &Path| { two_clouds(d); s(&["register", "s.ply", "t.ply", "--threads", "0"]) };
    B21 => |d: &Path| { two_clouds(d); s(&["register", "s.ply", "t.ply", "--voxel", "100"]) };
    B22 => |d: &Path| { two_clouds(d); s(&["register", "s.ply", "t.ply", "--voxel=-1"]) };
    B23 => |d: &Path| { two_clouds(d); std::fs::write(d.join("cfg.json"), r#"{"voxle": 0.01}"#).unwrap(); s(&["register", "s.ply", "t.ply", "--config", "cfg.json"]) };
    B24 => |d: &Path| { two_clouds(d); std::fs::write(d.join("init.txt"), "1 0 0 0\n0 1 0 0\n0 0 1\n").unwrap(); s(&["register", "s.ply", "t.ply", "--init", "init.txt"]) };
    B25 => |d: &Path| { two_clouds(d); std::fs::write(d.join("init.txt"), "2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap(); s(&["register", "s.ply", "t.ply", "--init", "init.txt"]) };
    B26 => |_d: &Path| s(&["calibrate", "nocell"]);
    B27 => |d: &Path| { std::fs::create_dir_all(d.join("empty")).unwrap(); s(&["calibrate", "empty"]) };
    B28 => |d: &Path| { cell_with(d, |t| t.replacen("[priors]", "[prior]", 1)); s(&["calibrate", "cell"]) };
    B29 => |d: &Path| { cell_with(d, |t| t.replacen("pose_format = \"kuka\"", "pose_format = \"kuka\"\nhandeye_sigma_mm = 0.2", 1)); s(&["calibrate", "cell"]) };
    B30 => |d: &Path| { cell_with(d, |t| t.replacen("\"left/poses.csv\"", "\"../../../../etc/passwd\"", 1)); s(&["calibrate", "cell"]) };
    B31 => |d: &Path| { cell_with(d, |t| t.replacen("\"left/poses.csv\"", "\"/etc/hostname\"", 1)); s(&["calibrate", "cell"]) };
    B32 => |d: &Path| { cell_with(d, |t| t); std::fs::remove_file(d.join("cell/right/depth/003.png")).unwrap(); s(&["calibrate", "cell"]) };
    B33 => |d: &Path| { cell_with(d, |t| t); edit_json(&d.join("cell/left/intrinsics.json"), |v| { v["width"] = 60000.into(); v["height"] = 60000.into(); }); s(&["calibrate", "cell"]) };
    B34 => |d: &Path| { cell_with(d, |t| t); edit_json(&d.join("cell/left/intrinsics.json"), |v| { v["fx"] = (-500.0).into(); }); s(&["calibrate", "cell"]) };
    B35 => |d: &Path| { cell_with(d, |t| t); edit_json(&d.join("cell/left/intrinsics.json"), |v| { v["width"] = 320.into(); }); s(&["calibrate", "cell"]) };
    B36 => |d: &Path| { cell_with(d, |t| t); let p = d.join("cell/right/poses.csv"); let t = std::fs::read_to_string(&p).unwrap(); let mut lines: Vec<String> = t.lines().map(String::from).collect(); lines[3] = format!("{},abc,0,0,0,0,0", lines[3].split(',').next().unwrap()); std::fs::write(&p, lines.join("\n") + "\n").unwrap(); s(&["calibrate", "cell"]) };
    B37 => |d: &Path| { cell_with(d, |t| t); std::fs::write(d.join("cell/ground_truth.json"), "{ not json").unwrap(); s(&["calibrate", "cell"]) };
    B38 => |d: &Path| { cell_with(d, |t| t); std::fs::write(d.join("cfg.json"), r#"{"register": {"icp_level": 2}}"#).unwrap(); s(&["calibrate", "cell", "--config", "cfg.json"]) };
    B39 => |d: &Path| { cell_with(d, |t| t); std::fs::write(d.join("cfg.json"), r#"{"max_range_factor": -1.0}"#).unwrap(); s(&["calibrate", "cell", "--config", "cfg.json"]) };
    B40 => |d: &Path| { cell_with(d, |t| t); edit_json(&d.join("cell/right/intrinsics.json"), |v| { let f = v["fy"].as_f64().unwrap(); v["fy"] = (f * 10.0).into(); }); s(&["calibrate", "cell"]) };
    B41 => |d: &Path| { cell_with(d, |t| t.replacen("reference = \"left\"", "reference = \"lefty\"", 1)); s(&["calibrate", "cell"]) };
    B42 => |d: &Path| { cell_with(d, |t| t.replacen("format = \"depthcal-cell/1\"", "format = \"depthcal-cell/9\"", 1)); s(&["calibrate", "cell"]) };
    B43 => |d: &Path| { std::fs::write(d.join("p.csv"), format!("{KUKA_HEADER}0,1,2,3,4,5,6\n")).unwrap(); s(&["convert", "p.csv", "--to", "matrix", "--output", "p.csv"]) };
    B44 => |d: &Path| { std::fs::write(d.join("p.csv"), format!("{KUKA_HEADER}0,1,2,3,4,5\n")).unwrap(); s(&["convert", "p.csv", "--to", "matrix"]) };
    B45 => |d: &Path| { std::fs::write(d.join("p.csv"), "frame,m00,m01,m02,m03,m10,m11,m12,m13,m20,m21,m22,m23,m30,m31,m32,m33\n0,2,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1\n").unwrap(); s(&["convert", "p.csv", "--to", "kuka"]) };
    B46 => |d: &Path| { std::fs::write(d.join("p.csv"), format!("{KUKA_HEADER}0,1,2,3,4,5,6\n0,1,2,3,4,5,6\n")).unwrap(); s(&["convert", "p.csv", "--to", "matrix"]) };
    B47 => |d: &Path| { cell_with(d, |t| t); s(&["fuse", "cell", "--output", "f.ply", "--voxel", "1e9"]) };
    B48 => |d: &Path| { cell_with(d, |t| t); s(&["fuse", "cell", "--output", "f.ply", "--crop", "1,2,3"]) };
    B49 => |d: &Path| { cell_with(d, |t| t); s(&["fuse", "cell", "--robot", "middle", "--output", "f.ply"]) };
    B50 => |d: &Path| { std::fs::write(d.join("r.csv"), format!("{KUKA_HEADER}0,1,2,3,4,5,6\n1,1,2,3,4,5,6\n")).unwrap(); std::fs::write(d.join("b.csv"), "frame,x,y,z,qx,qy,qz,qw\n0,0,0,1,0,0,0,1\n2,0,0,1,0,0,0,1\n").unwrap(); s(&["handeye", "--robot-poses", "r.csv", "--target-poses", "b.csv", "--target-format", "xyzquat"]) };
    B51 => |d: &Path| { std::fs::write(d.join("r.csv"), format!("{KUKA_HEADER}0,1,2,3,4,5,6\n1,1,2,3,4,5,6\n")).unwrap(); std::fs::write(d.join("b.csv"), "frame,x,y,z,qx,qy,qz,qw\n0,0,0,1,0,0,0,1\n1,0,0,1,0,0,0,1\n").unwrap(); s(&["handeye", "--robot-poses", "r.csv", "--target-poses", "b.csv", "--target-format", "xyzquat"]) };
    B52 => |d: &Path| { cell_with(d, |t| t.replacen("hand_eye = [0.640536833922", "hand_eye = [1.640536833922", 1)); s(&["calibrate", "cell"]) };
    B53 => |d: &Path| { cell_with(d, |t| format!("{t}\n[board]\ntype = \"charuco\"\nsquares_x = 5\nsquares_y = 7\nsquare_m = 0.04\nmarker_m = 0.04\ndictionary = \"DICT_6X6_250\"\n")); s(&["calibrate", "cell", "--method", "checkerboard"]) };
    B54 => |d: &Path| { cell_with(d, |t| format!("{t}\n[board]\ntype = \"charucoo\"\ncols = 9\nrows = 6\nsquare_m = 0.03\n")); s(&["calibrate", "cell", "--method", "checkerboard"]) };
}
