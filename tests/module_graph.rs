//! The library's module graph has no cycle: data flows one way (geometry/io → camera → preprocess/index/
//! features → registration → fusion → cell → calibration → vision/capture/sim → methods → report).
//!
//! The graph is read from the sources: module A depends on module B when a file of A (outside its unit
//! tests) names `crate::B`. A cycle fails the test, naming the modules and the files that close it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The code of a file without comments and without its unit tests (`#[cfg(test)] mod tests`, tests.rs).
fn code(p: &Path) -> String {
    if p.file_name().is_some_and(|n| n == "tests.rs") {
        return String::new();
    }
    let text = std::fs::read_to_string(p).unwrap();
    let text = match text.find("#[cfg(test)]\nmod tests") {
        Some(i) => &text[..i],
        None => &text[..],
    };
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Module → (module it names → files that name it), for the modules in `dir` (each file or directory
/// but `skip`): module A depends on module B when a file of A names `{prefix}B`, or, for a file directly in
/// `dir`, `super::B`.
fn graph_in(
    dir: &Path,
    prefix: &str,
    skip: &[&str],
) -> BTreeMap<String, BTreeMap<String, BTreeSet<String>>> {
    let mut modules = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        let name = p.file_stem().unwrap().to_string_lossy().to_string();
        if skip.contains(&name.as_str()) {
            continue;
        }
        let mut files = Vec::new();
        if p.is_dir() {
            rust_files(&p, &mut files);
        } else if p.extension().is_some_and(|x| x == "rs") {
            files.push(p.clone());
        } else {
            continue;
        }
        modules.insert(name, files);
    }
    let names: BTreeSet<String> = modules.keys().cloned().collect();
    let mut g: BTreeMap<String, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for (m, files) in &modules {
        let entry = g.entry(m.clone()).or_default();
        for f in files {
            let c = code(f);
            let mut named: Vec<&str> = c
                .match_indices(prefix)
                .map(|(i, _)| &c[i + prefix.len()..])
                .collect();
            if f.parent() == Some(dir) {
                named.extend(c.match_indices("super::").map(|(i, _)| &c[i + 7..]));
            }
            for rest in named {
                let other: String = rest
                    .chars()
                    .take_while(|ch| ch.is_ascii_alphanumeric() || *ch == '_')
                    .collect();
                if other != *m && names.contains(&other) {
                    let rel = f.strip_prefix(dir).unwrap().display().to_string();
                    entry.entry(other).or_default().insert(rel);
                }
            }
        }
    }
    g
}

/// The crate's top-level modules.
fn graph(src: &Path) -> BTreeMap<String, BTreeMap<String, BTreeSet<String>>> {
    graph_in(src, "crate::", &["lib", "main", "cli"])
}

/// Strongly connected components of more than one module (Tarjan's algorithm).
fn cycles(g: &BTreeMap<String, BTreeMap<String, BTreeSet<String>>>) -> Vec<Vec<String>> {
    struct S<'a> {
        g: &'a BTreeMap<String, BTreeMap<String, BTreeSet<String>>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on: BTreeSet<&'a str>,
        next: usize,
        out: Vec<Vec<String>>,
    }
    fn visit<'a>(s: &mut S<'a>, v: &'a str) {
        s.index.insert(v, s.next);
        s.low.insert(v, s.next);
        s.next += 1;
        s.stack.push(v);
        s.on.insert(v);
        if let Some(edges) = s.g.get(v) {
            for w in edges.keys() {
                let w = w.as_str();
                if !s.index.contains_key(w) {
                    visit(s, w);
                    let l = s.low[v].min(s.low[w]);
                    s.low.insert(v, l);
                } else if s.on.contains(w) {
                    let l = s.low[v].min(s.index[w]);
                    s.low.insert(v, l);
                }
            }
        }
        if s.low[v] == s.index[v] {
            let mut comp = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on.remove(w);
                comp.push(w.to_string());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                comp.sort();
                s.out.push(comp);
            }
        }
    }
    let mut s = S {
        g,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in g.keys() {
        if !s.index.contains_key(v.as_str()) {
            visit(&mut s, v);
        }
    }
    s.out
}

/// Fails naming every cycle of `g` and the files that close it.
fn assert_acyclic(g: &BTreeMap<String, BTreeMap<String, BTreeSet<String>>>) {
    let found = cycles(g);
    let explain: Vec<String> = found
        .iter()
        .map(|comp| {
            let mut lines = vec![format!("cycle among {comp:?}:")];
            for a in comp {
                for (b, files) in &g[a] {
                    if comp.contains(b) {
                        lines.push(format!("  {a} -> {b} in {files:?}"));
                    }
                }
            }
            lines.join("\n")
        })
        .collect();
    assert!(found.is_empty(), "{}", explain.join("\n"));
}

#[test]
fn the_module_graph_has_no_cycle() {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src");
    let g = graph(&src);
    assert!(g.len() > 10, "found only {} modules in src/", g.len());
    assert_acyclic(&g);
}

/// Inside `calibration`, too: the settings (`config`), the fused clouds (`fused`), the initialisers, the
/// pairwise engine (`robot_to_robot`, `hypotheses`) and the robot graph (`multi_robot`, `routes`,
/// `plan_robots`) import one way (docs/architecture.md, "Inside `calibration`").
#[test]
fn the_calibration_modules_import_one_way() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src/calibration");
    let g = graph_in(&dir, "crate::calibration::", &["mod"]);
    assert!(
        g.len() > 15,
        "found only {} modules in src/calibration/",
        g.len()
    );
    // The rooms: nothing below the pairwise engine names it, and the engine does not name the graph.
    let names = |m: &str| -> BTreeSet<String> { g[m].keys().cloned().collect() };
    for low in [
        "config",
        "fused",
        "initializer",
        "board_init",
        "marker_init",
        "feature_init",
        "hypotheses",
    ] {
        assert!(
            !names(low).contains("robot_to_robot"),
            "{low} names robot_to_robot: {:?}",
            g[low]
        );
    }
    for graph_module in ["multi_robot", "routes", "plan_robots"] {
        assert!(
            !names("robot_to_robot").contains(graph_module),
            "robot_to_robot names {graph_module}"
        );
    }
    assert_acyclic(&g);
}

#[test]
fn the_cycle_finder_finds_cycles() {
    let mut g: BTreeMap<String, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for (a, b) in [("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")] {
        g.entry(a.into()).or_default().entry(b.into()).or_default();
        g.entry(b.into()).or_default();
    }
    assert_eq!(
        cycles(&g),
        vec![vec!["a".to_string(), "b".into(), "c".into()]]
    );
    g.get_mut("c").unwrap().remove("a");
    assert!(cycles(&g).is_empty());
}
