//! The module graph of daemon, protocols and sim, read from their sources: every `use crate::…`,
//! `use super::…` and inline `crate::…` path names the file it reaches (the longest module
//! prefix that is a file). No file may reach itself again through others (a circle), and in
//! the daemon every arrow runs down the layers that docs/architecture.md lists ("Layers of the
//! daemon"): a face may use a service or the core, a service the core, never the other way.
//!
//! Unit-test modules (`#[cfg(test)] mod … { … }`) are left out: a test may reach anything in
//! its crate. Paths in comments are left out too.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// A file's module path, with the crate root it belongs to first (`lib` or `bin`).
type ModPath = Vec<String>;

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

fn module_path(src: &Path, file: &Path) -> ModPath {
    let rel = file.strip_prefix(src).unwrap().with_extension("");
    let mut segs: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    let bin = matches!(segs[0].as_str(), "main" | "cmd" | "bin");
    if matches!(
        segs.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        segs.pop();
    }
    let mut p = vec![if bin { "bin" } else { "lib" }.to_string()];
    p.extend(segs);
    p
}

/// The source without comments and without `#[cfg(test)] mod name { … }` blocks.
fn product_text(text: &str) -> String {
    let mut lines = Vec::new();
    let mut skip_depth: Option<i64> = None;
    let mut pending_cfg_test = false;
    for line in text.lines() {
        let t = line.trim_start();
        if let Some(depth) = skip_depth.as_mut() {
            *depth += line.matches('{').count() as i64 - line.matches('}').count() as i64;
            if *depth <= 0 {
                skip_depth = None;
            }
            continue;
        }
        if t.starts_with("//") {
            continue;
        }
        if t.starts_with("#[cfg(test)]") {
            pending_cfg_test = true;
            continue;
        }
        if pending_cfg_test && t.starts_with("mod ") && t.contains('{') {
            pending_cfg_test = false;
            let depth = line.matches('{').count() as i64 - line.matches('}').count() as i64;
            if depth > 0 {
                skip_depth = Some(depth);
            }
            continue;
        }
        pending_cfg_test = false;
        lines.push(line);
    }
    lines.join("\n")
}

/// Expands a `use` tree (`a::{b, c::{d, e}}`) into whole paths.
fn expand(tree: &str) -> Vec<String> {
    let tree: String = tree.chars().filter(|c| !c.is_whitespace()).collect();
    let Some(open) = tree.find('{') else {
        return vec![tree];
    };
    let head = &tree[..open];
    let body = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
    let (mut parts, mut depth, mut cur) = (Vec::new(), 0, String::new());
    for c in body.chars() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            _ => {}
        }
        if c == ',' && depth == 0 {
            parts.push(std::mem::take(&mut cur));
        } else {
            cur.push(c);
        }
    }
    parts.push(cur);
    parts
        .iter()
        .filter(|p| !p.is_empty())
        .flat_map(|p| expand(p))
        .map(|p| format!("{head}{p}"))
        .collect()
}

/// Every path of the text that starts at `crate` or `super`, with whether it was indented
/// (a `super` inside an inline module means that module's file, not its parent).
fn paths(text: &str) -> Vec<(bool, String)> {
    let mut out = Vec::new();
    // use declarations, which may span lines
    let mut rest = text;
    while let Some(i) = find_use(rest) {
        let after = &rest[i..];
        let line_start = rest[..i].rfind('\n').map_or(0, |n| n + 1);
        let indented = rest[line_start..].starts_with(char::is_whitespace);
        let body_start = after.find("use ").unwrap() + 4;
        let Some(end) = after.find(';') else { break };
        for p in expand(&after[body_start..end]) {
            out.push((indented, p));
        }
        rest = &after[end..];
    }
    // inline paths: crate::a::b
    let bytes = text.as_bytes();
    for (i, _) in text.match_indices("crate::") {
        if i > 0
            && (bytes[i - 1].is_ascii_alphanumeric()
                || bytes[i - 1] == b'_'
                || bytes[i - 1] == b':')
        {
            continue;
        }
        let tail: String = text[i..]
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_' || *c == ':')
            .collect();
        out.push((false, tail.trim_end_matches(':').to_string()));
    }
    out
}

/// The next `use` declaration at the start of a line (after `pub`, `pub(crate)`).
fn find_use(text: &str) -> Option<usize> {
    let mut at = 0;
    for line in text.split_inclusive('\n') {
        let t = line.trim_start();
        let t2 = t
            .strip_prefix("pub(crate) ")
            .or_else(|| t.strip_prefix("pub(super) "))
            .or_else(|| t.strip_prefix("pub "))
            .unwrap_or(t);
        if t2.starts_with("use ") {
            return Some(at + (line.len() - t2.len()) - (t.len() - t2.len()));
        }
        at += line.len();
    }
    None
}

/// file → the files it reaches, with the names it takes.
type Graph = BTreeMap<String, BTreeMap<String, BTreeSet<String>>>;

fn graph_of(crate_dir: &str) -> Graph {
    let root = workspace();
    let src = root.join(crate_dir).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let modules: BTreeMap<ModPath, PathBuf> = files
        .iter()
        .map(|f| (module_path(&src, f), f.clone()))
        .collect();
    let name = |f: &Path| f.strip_prefix(&root).unwrap().display().to_string();
    let mut g = Graph::new();
    for f in &files {
        let me = module_path(&src, f);
        let text = product_text(&std::fs::read_to_string(f).unwrap());
        for (indented, p) in paths(&text) {
            let segs: Vec<&str> = p.split("::").collect();
            let (mut full, rest): (ModPath, &[&str]) = match segs[0] {
                "crate" => (vec![me[0].clone()], &segs[1..]),
                "super" if !indented => {
                    let ups = segs.iter().take_while(|s| **s == "super").count();
                    let keep = me.len().saturating_sub(ups).max(1);
                    (me[..keep].to_vec(), &segs[ups..])
                }
                _ => continue,
            };
            full.extend(
                rest.iter()
                    .filter(|s| !matches!(**s, "self" | "*"))
                    .map(|s| s.to_string()),
            );
            let taken = rest.last().copied().unwrap_or("").to_string();
            for k in (1..=full.len()).rev() {
                if let Some(target) = modules.get(&full[..k]) {
                    if target != f {
                        g.entry(name(f))
                            .or_default()
                            .entry(name(target))
                            .or_default()
                            .insert(taken.clone());
                    }
                    break;
                }
            }
        }
    }
    g
}

/// The circles of `g`: its strongly connected parts of more than one file (Tarjan).
fn circles(g: &Graph) -> Vec<Vec<String>> {
    struct T<'a> {
        g: &'a Graph,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on: BTreeSet<&'a str>,
        out: Vec<Vec<String>>,
    }
    fn visit<'a>(t: &mut T<'a>, v: &'a str) {
        let n = t.index.len();
        t.index.insert(v, n);
        t.low.insert(v, n);
        t.stack.push(v);
        t.on.insert(v);
        if let Some(next) = t.g.get(v) {
            for w in next.keys() {
                let w = w.as_str();
                if !t.index.contains_key(w) {
                    visit(t, w);
                    let lw = t.low[w];
                    let lv = t.low.get_mut(v).unwrap();
                    *lv = (*lv).min(lw);
                } else if t.on.contains(w) {
                    let iw = t.index[w];
                    let lv = t.low.get_mut(v).unwrap();
                    *lv = (*lv).min(iw);
                }
            }
        }
        if t.low[v] == t.index[v] {
            let mut part = Vec::new();
            loop {
                let w = t.stack.pop().unwrap();
                t.on.remove(w);
                part.push(w.to_string());
                if w == v {
                    break;
                }
            }
            if part.len() > 1 {
                part.sort();
                t.out.push(part);
            }
        }
    }
    let mut t = T {
        g,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        out: Vec::new(),
    };
    let all: BTreeSet<&str> = g
        .iter()
        .flat_map(|(a, next)| std::iter::once(a.as_str()).chain(next.keys().map(String::as_str)))
        .collect();
    for v in all {
        if !t.index.contains_key(v) {
            visit(&mut t, v);
        }
    }
    t.out
}

fn describe(g: &Graph, part: &[String]) -> String {
    let mut s = format!("a circle of {} files:\n", part.len());
    for a in part {
        for (b, names) in g.get(a).into_iter().flatten() {
            if part.contains(b) {
                let names: Vec<&str> = names.iter().map(String::as_str).collect();
                s += &format!("  {a} -> {b} ({})\n", names.join(", "));
            }
        }
    }
    s
}

fn assert_no_circles(crate_dir: &str) {
    let g = graph_of(crate_dir);
    assert!(
        g.len() > 5,
        "{crate_dir}: only {} files import others: the reader found no paths",
        g.len()
    );
    let found = circles(&g);
    let text: Vec<String> = found.iter().map(|p| describe(&g, p)).collect();
    assert!(
        found.is_empty(),
        "{crate_dir}/src has circles:\n{}",
        text.join("\n")
    );
}

#[test]
fn daemon_files_import_no_circle() {
    assert_no_circles("daemon");
}

#[test]
fn protocols_files_import_no_circle() {
    assert_no_circles("protocols");
}

#[test]
fn sim_files_import_no_circle() {
    assert_no_circles("sim");
}

/// The layers of docs/architecture.md's "Layers of the daemon": numbered lines, each naming
/// its folders or files in backticks, lowest first.
fn documented_layers() -> Vec<Vec<String>> {
    let doc = std::fs::read_to_string(workspace().join("docs/architecture.md")).unwrap();
    let section = doc
        .split("## Layers of the daemon")
        .nth(1)
        .expect("docs/architecture.md has a section \"## Layers of the daemon\"");
    let section = section.split("\n## ").next().unwrap();
    let mut layers = Vec::new();
    for line in section.lines() {
        let t = line.trim_start();
        let numbered = t
            .split_once(". ")
            .is_some_and(|(n, _)| n.parse::<u32>().is_ok());
        if !numbered {
            continue;
        }
        let names: Vec<String> = t
            .split('`')
            .skip(1)
            .step_by(2)
            .filter(|s| s.starts_with("daemon/src/"))
            .map(String::from)
            .collect();
        if !names.is_empty() {
            layers.push(names);
        }
    }
    layers
}

#[test]
fn daemon_arrows_run_down_the_documented_layers() {
    let layers = documented_layers();
    assert!(
        layers.len() >= 3,
        "docs/architecture.md lists {} layers of the daemon",
        layers.len()
    );
    let layer_of = |file: &str| {
        layers.iter().position(|l| {
            l.iter()
                .any(|p| file == p || (p.ends_with('/') && file.starts_with(p.as_str())))
        })
    };
    let g = graph_of("daemon");
    let mut unplaced = BTreeSet::new();
    let mut upward = Vec::new();
    for (a, next) in &g {
        for (b, names) in next {
            match (layer_of(a), layer_of(b)) {
                (Some(la), Some(lb)) if la < lb => {
                    let names: Vec<&str> = names.iter().map(String::as_str).collect();
                    upward.push(format!(
                        "  {a} (layer {}) -> {b} (layer {}): {}",
                        la + 1,
                        lb + 1,
                        names.join(", ")
                    ));
                }
                (Some(_), Some(_)) => {}
                (la, lb) => {
                    if la.is_none() {
                        unplaced.insert(a.clone());
                    }
                    if lb.is_none() {
                        unplaced.insert(b.clone());
                    }
                }
            }
        }
    }
    assert!(
        unplaced.is_empty(),
        "files in no layer of docs/architecture.md (\"Layers of the daemon\"): {unplaced:?}"
    );
    assert!(
        upward.is_empty(),
        "arrows that run up the daemon's layers (docs/architecture.md):\n{}",
        upward.join("\n")
    );
}

#[test]
fn the_reader_sees_every_kind_of_path() {
    let text = "use crate::a::{b, c::{D, e}};\npub(crate) use super::f::G;\nfn x() {\n    use super::*;\n    crate::h::i();\n}\n// crate::not::this\n#[cfg(test)]\nmod tests {\n    use crate::z::Z;\n}\n";
    let got = paths(&product_text(text));
    let want = [
        (false, "crate::a::b"),
        (false, "crate::a::c::D"),
        (false, "crate::a::c::e"),
        (false, "super::f::G"),
        (true, "super::*"),
        (false, "crate::a"),
        (false, "crate::h::i"),
    ]
    .map(|(i, p)| (i, p.to_string()));
    assert_eq!(got, want);
}

#[test]
fn a_circle_through_three_files_is_found_and_a_chain_is_not() {
    let mut g = Graph::new();
    let mut arrow = |a: &str, b: &str| {
        g.entry(a.into())
            .or_default()
            .entry(b.into())
            .or_default()
            .insert("X".into());
    };
    arrow("a.rs", "b.rs");
    arrow("b.rs", "c.rs");
    arrow("c.rs", "a.rs");
    arrow("d.rs", "a.rs");
    arrow("d.rs", "e.rs");
    assert_eq!(
        circles(&g),
        vec![vec!["a.rs".to_string(), "b.rs".into(), "c.rs".into()]]
    );
}
