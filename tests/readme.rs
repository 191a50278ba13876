//! The README and the docs stay true:
//! * every line of a ```sh / ```bash block of README.md that starts with `cargo run --release --` is run
//!   with the built binary from the repository root and must exit with the status written after it as
//!   `# exit N` (0 when nothing is written);
//! * every `depthcal SUB ...` line in a fenced block of README.md, BENCHMARK.md or docs/*.md names a real
//!   subcommand, and each `--flag` on it (continuation lines included) is one that `depthcal SUB --help`
//!   lists;
//! * every relative link in those files points at an existing file, and every `#anchor` at a heading.
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn markdown_files() -> Vec<PathBuf> {
    let mut v = vec![root().join("README.md"), root().join("BENCHMARK.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .expect("docs/ exists")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    v.extend(docs);
    v
}

/// The fenced code blocks of a markdown text: (language, lines).
fn fenced_blocks(text: &str) -> Vec<(String, Vec<String>)> {
    let mut out = Vec::new();
    let mut cur: Option<(String, Vec<String>)> = None;
    for line in text.lines() {
        let t = line.trim_start();
        if let Some(rest) = t.strip_prefix("```") {
            match cur.take() {
                Some(block) => out.push(block),
                None => cur = Some((rest.trim().to_string(), Vec::new())),
            }
        } else if let Some((_, lines)) = cur.as_mut() {
            lines.push(line.to_string());
        }
    }
    out
}

/// Splits a command line into words: whitespace separated, '...' and "..." quote, `#` starts a comment.
fn split_words(s: &str) -> (Vec<String>, String) {
    let (mut words, mut cur, mut quote, mut in_word) = (Vec::new(), String::new(), None, false);
    for (i, c) in s.char_indices() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => cur.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                in_word = true;
            }
            (None, '#') if !in_word => return (words, s[i + 1..].trim().to_string()),
            (None, c) if c.is_whitespace() => {
                if in_word {
                    words.push(std::mem::take(&mut cur));
                    in_word = false;
                }
            }
            (None, c) => {
                cur.push(c);
                in_word = true;
            }
        }
    }
    if in_word {
        words.push(cur);
    }
    (words, String::new())
}

#[test]
fn readme_commands_run() {
    let text = std::fs::read_to_string(root().join("README.md")).unwrap();
    let mut ran = 0;
    for (lang, lines) in fenced_blocks(&text) {
        if lang != "sh" && lang != "bash" {
            continue;
        }
        for line in lines {
            let Some(rest) = line.trim().strip_prefix("cargo run --release --") else {
                continue;
            };
            let (args, comment) = split_words(rest);
            let expected: i32 = comment
                .strip_prefix("exit ")
                .map_or(0, |n| n.trim().parse().expect("`# exit N`"));
            let out = Command::new(env!("CARGO_BIN_EXE_depthcal"))
                .args(&args)
                .current_dir(root())
                .output()
                .unwrap();
            assert_eq!(
                out.status.code(),
                Some(expected),
                "README command `{}` exited {:?}, README says {expected}\nstdout:\n{}\nstderr:\n{}",
                line.trim(),
                out.status.code(),
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            );
            ran += 1;
        }
    }
    assert!(ran >= 2, "the README's first commands were not found");
}

/// `depthcal SUB --help`, cached.
fn help(cache: &mut HashMap<String, String>, sub: &str) -> String {
    cache
        .entry(sub.to_string())
        .or_insert_with(|| {
            let mut c = Command::new(env!("CARGO_BIN_EXE_depthcal"));
            if !sub.is_empty() {
                c.arg(sub);
            }
            let out = c.arg("--help").output().unwrap();
            String::from_utf8_lossy(&out.stdout).into_owned()
        })
        .clone()
}

/// The long flags (`--name`) in a text.
fn flags(s: &str) -> Vec<String> {
    let b = s.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i + 2 < b.len() {
        let starts =
            b[i] == b'-' && b[i + 1] == b'-' && (i == 0 || !b[i - 1].is_ascii_alphanumeric());
        if starts && b[i + 2].is_ascii_lowercase() {
            let mut j = i + 2;
            while j < b.len() && (b[j].is_ascii_alphanumeric() || b[j] == b'-') {
                j += 1;
            }
            out.push(s[i..j].to_string());
            i = j;
        } else {
            i += 1;
        }
    }
    out
}

#[test]
fn documented_command_lines_match_the_cli() {
    let mut cache = HashMap::new();
    let top = help(&mut cache, "");
    let globals = flags(&top);
    let mut problems = Vec::new();
    let mut checked = 0;
    for file in markdown_files() {
        let text = std::fs::read_to_string(&file).unwrap();
        for (_, lines) in fenced_blocks(&text) {
            // A command and its indented continuation lines.
            let mut commands: Vec<String> = Vec::new();
            for line in &lines {
                let cmd = line.trim_start();
                let cmd = cmd.strip_prefix("$ ").unwrap_or(cmd);
                if let Some(rest) = cmd.strip_prefix("depthcal ") {
                    commands.push(rest.to_string());
                } else if line.starts_with(' ') && !commands.is_empty() && cmd.starts_with('[') {
                    let last = commands.last_mut().unwrap();
                    last.push(' ');
                    last.push_str(cmd);
                } else if !line.starts_with(' ') {
                    // Another command ends the continuation.
                    commands.push(String::new());
                }
            }
            for cmd in commands.iter().filter(|c| !c.is_empty()) {
                let cmd = cmd.split(" #").next().unwrap();
                let sub = cmd.split_whitespace().next().unwrap_or("");
                let sub_help = help(&mut cache, sub);
                if !sub_help.contains("Usage:") {
                    problems.push(format!(
                        "{}: `depthcal {cmd}`: no subcommand {sub}",
                        file.display()
                    ));
                    continue;
                }
                for f in flags(cmd) {
                    if !sub_help.contains(&format!("{f} "))
                        && !sub_help.contains(&format!("{f}\n"))
                        && !sub_help.contains(&format!("{f}="))
                        && !sub_help.contains(&format!("{f},"))
                        && !globals.contains(&f)
                    {
                        problems.push(format!(
                            "{}: `depthcal {cmd}`: `depthcal {sub} --help` has no {f}",
                            file.display()
                        ));
                    }
                }
                checked += 1;
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    assert!(
        checked > 20,
        "only {checked} documented command lines found"
    );
}

/// GitHub's anchor of a heading: lower case, punctuation dropped (`-` and `_` kept), spaces to `-`.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

fn anchors(text: &str) -> HashSet<String> {
    let mut in_code = false;
    let mut out = HashSet::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
        } else if !in_code && line.starts_with('#') {
            out.insert(slug(line.trim_start_matches('#')));
        }
    }
    out
}

/// The `](target)` links of a markdown text outside code blocks.
fn links(text: &str) -> Vec<String> {
    let mut in_code = false;
    let mut out = Vec::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
            continue;
        }
        if in_code {
            continue;
        }
        let mut rest = line;
        while let Some(i) = rest.find("](") {
            let after = &rest[i + 2..];
            let Some(j) = after.find(')') else { break };
            out.push(after[..j].to_string());
            rest = &after[j..];
        }
    }
    out
}

#[test]
fn relative_links_point_at_files_and_headings() {
    let mut problems = Vec::new();
    let mut checked = 0;
    for file in markdown_files() {
        let text = std::fs::read_to_string(&file).unwrap();
        for link in links(&text) {
            if link.starts_with("http://")
                || link.starts_with("https://")
                || link.starts_with("mailto:")
            {
                continue;
            }
            let (path, anchor) = match link.split_once('#') {
                Some((p, a)) => (p, Some(a)),
                None => (link.as_str(), None),
            };
            let target = if path.is_empty() {
                file.clone()
            } else {
                file.parent().unwrap().join(path)
            };
            checked += 1;
            if !target.exists() {
                problems.push(format!(
                    "{}: link {link}: {} does not exist",
                    file.display(),
                    target.display()
                ));
                continue;
            }
            if let Some(a) = anchor {
                let md = std::fs::read_to_string(&target).unwrap_or_default();
                if !anchors(&md).contains(a) {
                    problems.push(format!(
                        "{}: link {link}: no heading #{a} in {}",
                        file.display(),
                        target.display()
                    ));
                }
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    assert!(checked > 10, "only {checked} relative links found");
}

#[test]
fn split_words_handles_quotes_and_comments() {
    let (w, c) = split_words(r#"calibrate "a b" 'c' d # exit 3"#);
    assert_eq!(w, ["calibrate", "a b", "c", "d"]);
    assert_eq!(c, "exit 3");
    assert_eq!(
        slug("`depthcal calibrate` (exit 0, 3)"),
        "depthcal-calibrate-exit-0-3"
    );
    assert!(Path::new(env!("CARGO_BIN_EXE_depthcal")).exists());
}
