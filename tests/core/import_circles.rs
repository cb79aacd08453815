//! No import circles inside a crate (between crates the compiler forbids them): every module
//! file's `crate::…`, `super::…` and `self::…` paths (in `use` lines and inline) name the
//! module files it depends on, and the graph of each crate must have no cycle. A module's
//! use of its own ancestors (`super::Error` from a child) is the usual parent–child link and
//! does not count.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

type Module = Vec<String>;

/// Every `.rs` file below `src` as its module path (`geometry/rig.rs` is `[geometry, rig]`).
fn modules(src: &Path) -> BTreeMap<Module, PathBuf> {
    let mut out = BTreeMap::new();
    let mut stack = vec![src.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("source folder").flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") {
                continue;
            }
            let rel = path
                .strip_prefix(src)
                .expect("below src")
                .with_extension("");
            let mut module: Module = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            if module.last().is_some_and(|m| m == "mod") {
                module.pop();
            }
            if module == ["lib"] || module == ["main"] {
                module.clear();
            }
            out.insert(module, path);
        }
    }
    out
}

/// The module files a path like `super::rig::Rig` (seen from `from`) lands in.
fn resolve(from: &Module, segments: &[&str], files: &BTreeMap<Module, PathBuf>) -> Option<Module> {
    let mut base: Module = Vec::new();
    let mut rest = segments;
    match rest.first()? {
        &"crate" => rest = &rest[1..],
        &"super" | &"self" => {
            base = from.clone();
            while let Some(first) = rest.first() {
                match *first {
                    "super" => {
                        base.pop();
                    }
                    "self" => {}
                    _ => break,
                }
                rest = &rest[1..];
            }
        }
        _ => return None,
    }
    let full: Module = base
        .into_iter()
        .chain(rest.iter().map(|s| s.to_string()))
        .collect();
    (0..=full.len())
        .rev()
        .map(|n| full[..n].to_vec())
        .find(|m| files.contains_key(m))
}

/// Paths starting with `crate`, `super` or `self` in `code` (comments removed), with the
/// names inside one level of `{…}` expanded.
fn paths(code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let bytes: Vec<char> = code.chars().collect();
    let mut i = 0;
    while i < bytes.len() {
        let starts = ["crate::", "super::", "self::"]
            .iter()
            .any(|p| code_at(&bytes, i, p))
            && (i == 0 || !(bytes[i - 1].is_alphanumeric() || bytes[i - 1] == '_'));
        if !starts {
            i += 1;
            continue;
        }
        let mut j = i;
        while j < bytes.len() && (bytes[j].is_alphanumeric() || bytes[j] == '_' || bytes[j] == ':')
        {
            j += 1;
        }
        let head: String = bytes[i..j].iter().collect();
        let head = head.trim_end_matches(':').to_string();
        let prefix: Vec<String> = head.split("::").map(String::from).collect();
        if j < bytes.len() && bytes[j] == '{' {
            let end = bytes[j..]
                .iter()
                .position(|&c| c == '}')
                .map_or(bytes.len(), |k| j + k);
            let inner: String = bytes[j + 1..end].iter().collect();
            for item in inner.split(',') {
                let name = item.trim().split("::").next().unwrap_or("").trim();
                let name = name.split_whitespace().next().unwrap_or("");
                if !name.is_empty() && name != "self" {
                    let mut p = prefix.clone();
                    p.push(name.to_string());
                    out.push(p);
                }
            }
            i = end;
        } else {
            out.push(prefix);
            i = j;
        }
    }
    out
}

fn code_at(chars: &[char], i: usize, pattern: &str) -> bool {
    pattern
        .chars()
        .enumerate()
        .all(|(k, c)| chars.get(i + k) == Some(&c))
}

/// The crate's modules in a cycle, if any (one cycle, as module paths).
fn find_cycle(src: &Path) -> Option<Vec<String>> {
    let files = modules(src);
    let mut edges: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
    for (module, path) in &files {
        let text = std::fs::read_to_string(path).expect("source");
        let code: String = text
            .lines()
            .map(|l| l.split("//").next().unwrap_or(""))
            .collect::<Vec<_>>()
            .join("\n");
        let deps = edges.entry(module.clone()).or_default();
        for p in paths(&code) {
            let segments: Vec<&str> = p.iter().map(String::as_str).collect();
            if let Some(target) = resolve(module, &segments, &files) {
                let ancestor = target.len() < module.len() && module.starts_with(&target);
                if &target != module && !ancestor {
                    deps.insert(target);
                }
            }
        }
    }
    // Depth-first search with colours.
    fn visit(
        m: &Module,
        edges: &BTreeMap<Module, BTreeSet<Module>>,
        state: &mut BTreeMap<Module, u8>,
        stack: &mut Vec<Module>,
    ) -> Option<Vec<String>> {
        state.insert(m.clone(), 1);
        stack.push(m.clone());
        for next in edges.get(m).into_iter().flatten() {
            match state.get(next).copied().unwrap_or(0) {
                1 => {
                    let start = stack.iter().position(|s| s == next).unwrap_or(0);
                    return Some(stack[start..].iter().map(|s| s.join("::")).collect());
                }
                0 => {
                    if let Some(c) = visit(next, edges, state, stack) {
                        return Some(c);
                    }
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(m.clone(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for m in edges.keys() {
        if state.get(m).copied().unwrap_or(0) == 0 {
            if let Some(c) = visit(m, &edges, &mut state, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

#[test]
fn no_crate_has_an_import_circle() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut sources = vec![root.join("src")];
    for entry in std::fs::read_dir(root.join("crates"))
        .expect("crates")
        .flatten()
    {
        sources.push(entry.path().join("src"));
    }
    assert!(sources.len() >= 7, "{sources:?}");
    for src in sources {
        assert_eq!(find_cycle(&src), None, "import circle in {}", src.display());
    }
}

#[test]
fn a_circle_is_found() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path();
    std::fs::write(src.join("lib.rs"), "mod a;\nmod b;\n").expect("lib");
    std::fs::write(src.join("a.rs"), "use crate::b::B;\npub struct A;\n").expect("a");
    std::fs::write(src.join("b.rs"), "use super::{a::A, c};\npub struct B;\n").expect("b");
    std::fs::write(src.join("c.rs"), "pub fn c() {}\n").expect("c");
    let cycle = find_cycle(src).expect("a and b use each other");
    assert_eq!(cycle.len(), 2, "{cycle:?}");
    std::fs::write(src.join("b.rs"), "use super::c;\npub struct B;\n").expect("b");
    assert_eq!(find_cycle(src), None);
}
