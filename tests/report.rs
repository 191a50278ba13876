//! `--report DIR` of calibrate, register and compare: the page opens offline in headless Chromium, its
//! viewer draws every point it shows when it opens, the numbers it embeds equal the command's `--json`, the
//! PNG snapshots decode at their size with both clouds' colours, an untrusted result is reported too (and
//! says so), and the report directory follows the rules of `--output`.
//!
//! Chromium (`chromium`, `chromium-browser` or `google-chrome` on PATH; CI installs Debian's `chromium`) is
//! required: without it the browser checks fail with a message, unless `DEPTHCAL_SKIP_BROWSER=1`.

mod common;

use common::{depthcal, listing, scratch};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn repo(p: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(p)
        .to_string_lossy()
        .into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The browser to test with, or `None` when `DEPTHCAL_SKIP_BROWSER=1`; panics naming what to install when
/// there is none.
fn browser() -> Option<PathBuf> {
    if std::env::var("DEPTHCAL_SKIP_BROWSER").as_deref() == Ok("1") {
        eprintln!("SKIP: the headless-browser checks (DEPTHCAL_SKIP_BROWSER=1)");
        return None;
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    for name in ["chromium", "chromium-browser", "google-chrome"] {
        for dir in std::env::split_paths(&path) {
            let p = dir.join(name);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    panic!(
        "no headless browser: the report tests need Chromium (`apt-get install -y chromium`, as .ci/run \
         does); set DEPTHCAL_SKIP_BROWSER=1 to skip these checks"
    );
}

/// The DOM of `page` after its scripts ran, from headless Chromium with every host name unresolvable (the
/// page must not need the network).
fn dump_dom(chrome: &Path, page: &Path) -> String {
    let profile = scratch(&format!(
        "chrome-profile-{}",
        page.parent()
            .unwrap()
            .file_name()
            .unwrap()
            .to_string_lossy()
    ));
    let mut child = std::process::Command::new(chrome)
        .args([
            "--headless",
            "--disable-gpu",
            "--no-sandbox",
            "--no-first-run",
            "--disable-extensions",
            "--host-resolver-rules=MAP * ~NOTFOUND",
            &format!("--user-data-dir={}", profile.display()),
            "--virtual-time-budget=20000",
            "--dump-dom",
        ])
        .arg(format!("file://{}", page.canonicalize().unwrap().display()))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("start chromium");
    let mut out = child.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut out, &mut s).unwrap();
        s
    });
    let t0 = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if t0.elapsed() > Duration::from_secs(180) {
            let _ = child.kill();
            panic!("chromium did not finish with {} in 180 s", page.display());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = std::fs::remove_dir_all(&profile);
    reader.join().unwrap()
}

/// The JSON of the page's `report-data` script element.
fn page_data(html: &str) -> Value {
    let start = r#"<script type="application/json" id="report-data">"#;
    let a = html.find(start).expect("report-data element") + start.len();
    let b = a + html[a..].find("</script>").unwrap();
    serde_json::from_str(&html[a..b]).unwrap()
}

/// The text of the element with `id` in a DOM dump.
fn element_text<'a>(dom: &'a str, id: &str) -> &'a str {
    let tag = format!("id=\"{id}\">");
    let a = dom.find(&tag).unwrap_or_else(|| panic!("no element {id}")) + tag.len();
    let b = a + dom[a..].find('<').unwrap();
    &dom[a..b]
}

/// Points the viewer shows when the page opens, from the embedded scene alone.
fn visible_points(data: &Value) -> u64 {
    let sc = &data["scene"];
    sc["items"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|i| i["visible"] == true && i["kind"] == "points")
        .map(|i| {
            sc["sets"][i["set"].as_u64().unwrap() as usize]["count"]
                .as_u64()
                .unwrap()
        })
        .sum()
}

fn close(a: &Value, b: &Value, what: &str) {
    match (a, b) {
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{what}");
            for (u, v) in x.iter().zip(y) {
                close(u, v, what);
            }
        }
        (Value::Number(_), Value::Number(_)) => {
            let (u, v) = (a.as_f64().unwrap(), b.as_f64().unwrap());
            assert!(
                (u - v).abs() <= 1e-12 * u.abs().max(v.abs()).max(1.0),
                "{what}: page {u} vs JSON {v}"
            );
        }
        _ => assert_eq!(a, b, "{what}"),
    }
}

/// Decodes a PNG into (width, height, RGB bytes).
fn read_png(p: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(p).unwrap()));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", p.display());
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

/// Pixels of `rgb` that are orange-ish (the reference / target) and blue-ish (the other cloud / source).
fn colour_counts(rgb: &[u8]) -> (usize, usize) {
    let mut o = 0;
    let mut b = 0;
    for p in rgb.chunks_exact(3) {
        let (r, g, bl) = (p[0] as i32, p[1] as i32, p[2] as i32);
        if r > 110 && r > bl + 60 && r > g + 20 {
            o += 1;
        }
        if bl > 110 && bl > r + 60 {
            b += 1;
        }
    }
    (o, b)
}

/// Checks the files of a report directory and the page's self-containment; returns the page and its data.
fn check_files(dir: &Path) -> (String, Value) {
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>"));
    assert!(html.contains("Content-Security-Policy") && html.contains("default-src 'none'"));
    for bad in [
        "src=\"http",
        "href=\"http",
        "src='http",
        "url(http",
        "@import",
        "fetch(",
        "XMLHttpRequest",
    ] {
        assert!(
            !html.contains(bad),
            "the page references the network: {bad}"
        );
    }
    assert!(html.len() < 8_000_000, "page of {} bytes", html.len());
    for f in ["overview.png", "initial.png", "residual.png"] {
        let (w, h, rgb) = read_png(&dir.join(f));
        assert_eq!((w, h), (1024, 768), "{f}");
        let distinct: std::collections::HashSet<&[u8]> = rgb.chunks_exact(3).collect();
        assert!(
            distinct.len() > 50,
            "{f} is blank ({} colours)",
            distinct.len()
        );
    }
    let data = page_data(&html);
    (html, data)
}

/// The page in the browser: it loaded, the viewer drew, and every point it shows lies in the canvas.
fn check_in_browser(dir: &Path, data: &Value) -> String {
    let Some(chrome) = browser() else {
        return String::new();
    };
    let dom = dump_dom(&chrome, &dir.join("report.html"));
    assert!(
        dom.contains("data-viewer=\"drawn\""),
        "the viewer did not draw: {}",
        element_text(&dom, "viewer-status")
    );
    let want = visible_points(data);
    assert!(want > 1000, "{want}");
    assert_eq!(element_text(&dom, "points-drawn"), want.to_string());
    assert_eq!(element_text(&dom, "points-embedded"), want.to_string());
    assert_eq!(data["scene"]["visible_points"].as_u64(), Some(want));
    dom
}

#[test]
fn calibrate_report_on_the_demo_cell() {
    let dir = scratch("calibrate-report").join("out");
    let t0 = Instant::now();
    // --output and --report may share a directory.
    let (code, out, err) = depthcal(&[
        "calibrate",
        &repo("clouds/demo-cell"),
        "--json",
        "--report",
        s(&dir),
        "--output",
        s(&dir),
    ]);
    eprintln!(
        "calibrate --report: {:.1} s; {}",
        t0.elapsed().as_secs_f64(),
        err.trim()
    );
    assert_eq!(code, 0, "{err}");
    let json: Value = serde_json::from_str(&out).unwrap();
    assert!(err.contains("report.html"), "{err}");
    let (html, data) = check_files(&dir);
    assert!(dir.join("calibration.json").is_file());
    assert_eq!(data["kind"], "calibrate");
    let sum = &data["summary"];
    for k in [
        "transform",
        "fitness",
        "inlier_rmse_m",
        "overlap",
        "sigma",
        "trusted",
        "reasons",
        "converged",
    ] {
        close(&sum[k], &json[k], k);
    }
    close(
        &sum["initial"]["transform"],
        &json["initial"]["transform"],
        "initial",
    );
    close(&sum["fused_points"], &json["fused_points"], "fused points");
    assert_eq!(data["frame_ids"], json["frame_ids"]);
    // The consistency and the ICP history are there, one frame per pose.
    assert_eq!(
        data["consistency"][0]["frames"].as_array().unwrap().len(),
        20
    );
    // Both hand-eye checks, as in the JSON.
    assert_eq!(data["hand_eye_check"], json["hand_eye_check"]);
    assert_eq!(data["hand_eye_check"].as_array().unwrap().len(), 2);
    let levels = data["icp_levels"].as_array().unwrap();
    assert!(!levels.is_empty());
    let iters: usize = levels
        .iter()
        .map(|l| l["iterations"].as_array().unwrap().len() - 1)
        .sum();
    assert!(iters > 0);
    // The reference cloud embedded whole (the demo cell is below the budget), the other cloud once.
    assert_eq!(
        data["scene"]["sets"][0]["count"],
        json["fused_points"]["reference"]
    );
    assert_eq!(
        data["scene"]["sets"][1]["count"],
        json["fused_points"]["other"]
    );
    // Every transform file of --output shows on the page as written.
    let launch = std::fs::read_to_string(dir.join("static_tf.launch.py")).unwrap();
    let escaped = launch
        .trim_end()
        .replace('&', "&amp;")
        .replace('"', "&quot;")
        .replace('\'', "&#39;");
    assert!(
        html.contains(&escaped),
        "the launch file is not on the page"
    );
    // Both robots' colours on the overview, the residual scale on the residual snapshot.
    let (_, _, rgb) = read_png(&dir.join("overview.png"));
    let (o, b) = colour_counts(&rgb);
    assert!(o > 2000 && b > 2000, "orange {o}, blue {b}");
    let dom = check_in_browser(&dir, &data);
    if !dom.is_empty() {
        assert!(dom.contains("id=\"verdict\" data-trusted=\"true\""));
        let m = json["transform"]["matrix"][0][3].as_f64().unwrap();
        assert!(
            dom.contains(&format!("data-r=\"0\" data-c=\"3\">{m:.6}<")),
            "x of the matrix"
        );
        let sr = &json["sigma"]["rotation_deg"];
        let text = format!(
            "{:.4} {:.4} {:.4}",
            sr[0].as_f64().unwrap(),
            sr[1].as_f64().unwrap(),
            sr[2].as_f64().unwrap()
        );
        assert_eq!(element_text(&dom, "sigma-rotation"), text);
        // The browser's time is not asserted; the files are.
    }
    // A second run replaces the report in place.
    let before = listing(&dir).len();
    let (code, _, err) = depthcal(&["calibrate", &repo("clouds/demo-cell"), "--report", s(&dir)]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(listing(&dir).len(), before);
}

/// Pixels close to a colour of the report's palette (the shaded clouds keep their hue).
fn near(rgb: &[u8], want: [u8; 3]) -> usize {
    rgb.chunks_exact(3)
        .filter(|p| {
            let (r, g, b) = (p[0] as f64, p[1] as f64, p[2] as f64);
            let (wr, wg, wb) = (want[0] as f64, want[1] as f64, want[2] as f64);
            // Same hue under the depth shading: the pixel is the colour scaled by 0.4-1.1.
            let k = (r * wr + g * wg + b * wb) / (wr * wr + wg * wg + wb * wb);
            (0.4..1.1).contains(&k)
                && ((r - k * wr).powi(2) + (g - k * wg).powi(2) + (b - k * wb).powi(2)).sqrt()
                    < 25.0
        })
        .count()
}

#[test]
fn calibrate_report_of_three_robots() {
    let cell = scratch("report-three");
    let (code, _, err) = depthcal(&[
        "simulate",
        s(&cell),
        "--robots",
        "3",
        "--seed",
        "12",
        "--frames",
        "12",
        "--no-color",
        "--force",
    ]);
    assert_eq!(code, 0, "{err}");
    let dir = scratch("report-three-out");
    let _ = std::fs::remove_dir_all(&dir);
    let (code, out, err) = depthcal(&["calibrate", s(&cell), "--json", "--report", s(&dir)]);
    let json: Value = serde_json::from_str(&out).unwrap();
    assert!(err.contains("report.html"), "{err}");
    let (html, data) = check_files(&dir);
    assert_eq!(data["kind"], "calibrate_robots");
    // The page holds the JSON's robots and pairs, and its verdict.
    assert_eq!(data["robots"], json["robots"]);
    assert_eq!(data["pairs"], json["pairs"]);
    assert_eq!(data["trusted"], json["trusted"]);
    assert_eq!(code == 0, json["trusted"] == true, "{err}");
    // One cloud per robot, each robot's residual against the reference when it has a pose.
    assert_eq!(data["scene"]["sets"].as_array().unwrap().len(), 3);
    let posed = json["robots"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| !r["transform"].is_null())
        .count();
    assert_eq!(data["residuals"].as_array().unwrap().len(), posed);
    // Every robot and every pair is named on the page, with the graph's nodes and edges.
    for name in ["left", "right", "robot3"] {
        assert!(html.contains(&format!("T_left_{name}")) || name == "left");
        assert!(
            html.contains(&format!(">{name}</text>")),
            "graph node {name}"
        );
    }
    let graph = &html[html.find("<section id=\"graph\">").unwrap()..];
    let graph = &graph[..graph.find("</section>").unwrap()];
    assert_eq!(graph.matches("<circle").count(), 3);
    assert_eq!(graph.matches("<line ").count(), 3);
    // Each posed robot in its own colour on the overview: orange the reference, blue and purple the others.
    let (_, _, rgb) = read_png(&dir.join("overview.png"));
    for (k, want) in [[230, 120, 30], [40, 110, 230], [175, 80, 210]]
        .into_iter()
        .enumerate()
    {
        let px = near(&rgb, want);
        if k == 0 || !json["robots"][k - 1]["transform"].is_null() {
            assert!(px > 1500, "robot {k}: {px} pixels of its colour");
        }
    }
    check_in_browser(&dir, &data);
}

#[test]
fn register_report_on_the_sample_pair() {
    let dir = scratch("register-report").join("rep");
    let (code, out, err) = depthcal(&[
        "register",
        &repo("clouds/demo_source.ply"),
        &repo("clouds/demo_target.ply"),
        "--json",
        "--report",
        s(&dir),
    ]);
    assert_eq!(code, 0, "{err}");
    let json: Value = serde_json::from_str(&out).unwrap();
    let (_, data) = check_files(&dir);
    assert_eq!(data["kind"], "register");
    let sum = &data["summary"];
    for k in [
        "transform",
        "fitness",
        "inlier_rmse_m",
        "overlap",
        "trusted",
        "iterations",
        "converged",
    ] {
        close(&sum[k], &json[k], k);
    }
    close(
        &sum["initial"]["transform"],
        &json["global"]["transform"],
        "global estimate",
    );
    close(&sum["sigma"], &json["sigma"], "sigma");
    let icp: usize = data["icp_levels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["iterations"].as_array().unwrap().len() - 1)
        .sum();
    assert_eq!(icp as u64, json["iterations"].as_u64().unwrap());
    let (_, _, rgb) = read_png(&dir.join("overview.png"));
    let (o, b) = colour_counts(&rgb);
    assert!(o > 2000 && b > 2000, "orange {o}, blue {b}");
    check_in_browser(&dir, &data);
}

#[test]
fn compare_report_shows_every_method() {
    let dir = scratch("compare-report").join("rep");
    let (code, out, err) = depthcal(&[
        "compare",
        &repo("clouds/demo-cell"),
        "--json",
        "--report",
        s(&dir),
    ]);
    assert_eq!(code, 0, "{err}");
    let json: Value = serde_json::from_str(&out).unwrap();
    let (html, data) = check_files(&dir);
    let methods = data["summary"]["methods"].as_array().unwrap();
    let jm = json["methods"].as_array().unwrap();
    assert_eq!(methods.len(), jm.len());
    for (p, j) in methods.iter().zip(jm) {
        assert_eq!(p["method"], j["method"]);
        assert_eq!(p["status"], j["status"]);
        if j["status"] == "ok" {
            close(&p["transform"], &j["transform"], "transform");
            assert_eq!(p["trusted"], j["trusted"]);
        } else {
            assert!(html.contains(&format!("<td>{}</td>", j["method"].as_str().unwrap())));
        }
    }
    check_in_browser(&dir, &data);
}

/// A flat square: registering onto it leaves motions unconstrained, so the result is not trusted.
fn write_plane(path: &Path) {
    let mut s = String::new();
    for i in 0..60 {
        for j in 0..60 {
            s.push_str(&format!("{} {} 0\n", i as f64 * 0.01, j as f64 * 0.01));
        }
    }
    std::fs::write(path, s).unwrap();
}

#[test]
fn an_untrusted_result_is_reported_and_says_so() {
    let d = scratch("untrusted-report");
    let (src, tgt) = (d.join("a.xyz"), d.join("b.xyz"));
    write_plane(&src);
    write_plane(&tgt);
    let dir = d.join("rep");
    let (code, _, err) = depthcal(&["register", s(&src), s(&tgt), "--report", s(&dir)]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("NOT trusted"), "{err}");
    let (html, data) = check_files(&dir);
    assert_eq!(data["summary"]["trusted"], false);
    assert!(html.contains("data-trusted=\"false\"><strong>NOT TRUSTED</strong>"));
    let reasons = data["summary"]["reasons"].as_array().unwrap();
    assert!(!reasons.is_empty());
    assert!(html.contains(
        &reasons[0]
            .as_str()
            .unwrap()
            .replace('\'', "&#39;")
            .replace('"', "&quot;")
    ));
    // The snapshots carry the verdict in red.
    let (_, _, rgb) = read_png(&dir.join("overview.png"));
    let red = rgb.chunks_exact(3).filter(|p| p == &[255, 70, 70]).count();
    assert!(red > 200, "{red}");
}

#[test]
fn the_report_directory_follows_the_output_rules() {
    let d = scratch("report-dir-rules");
    let (src, tgt) = (
        repo("clouds/demo_source.ply"),
        repo("clouds/demo_target.ply"),
    );
    // A directory holding someone else's files is refused before any work, and left as it was.
    let busy = d.join("busy");
    std::fs::create_dir(&busy).unwrap();
    std::fs::write(busy.join("notes.txt"), "mine").unwrap();
    let t0 = Instant::now();
    let (code, _, err) = depthcal(&["register", &src, &tgt, "--report", s(&busy)]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("notes.txt") && err.contains("--report"),
        "{err}"
    );
    assert!(t0.elapsed() < Duration::from_secs(20));
    assert_eq!(listing(&busy).len(), 1);
    // A file, a missing parent, the cell's own directory.
    let file = d.join("file");
    std::fs::write(&file, "x").unwrap();
    let (code, _, err) = depthcal(&["register", &src, &tgt, "--report", s(&file)]);
    assert_eq!(code, 1);
    assert!(err.contains("not a directory"), "{err}");
    let (code, _, err) = depthcal(&["register", &src, &tgt, "--report", s(&d.join("no/such"))]);
    assert_eq!(code, 1);
    assert!(err.contains("does not exist"), "{err}");
    let cell = repo("clouds/demo-cell");
    let before = listing(Path::new(&cell));
    let (code, _, err) = depthcal(&["calibrate", &cell, "--report", &cell]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("refusing") || err.contains("does not write"),
        "{err}"
    );
    let (code, _, err) = depthcal(&["compare", &cell, "--report", &format!("{cell}/left")]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("refusing"), "{err}");
    assert_eq!(listing(Path::new(&cell)), before);
}
