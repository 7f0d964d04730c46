//! The layer order of `src/` holds: a module imports only modules below it in the order
//! written once, in the doc comment of `src/lib.rs` (its "Layers" paragraph). Reads every
//! `crate::` path and every `super::` that leaves its top-level module, outside
//! `#[cfg(test)]` modules (a test may build its fixtures with a higher layer). The binary's
//! `app/` is the top layer and is not checked.
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The layers named in `lib.rs`'s "Layers" paragraph, lowest first.
fn documented_order(lib: &str) -> Vec<String> {
    let doc: Vec<&str> = lib
        .lines()
        .take_while(|l| l.starts_with("//!"))
        .map(|l| l.trim_start_matches("//!").trim())
        .collect();
    let start = doc
        .iter()
        .position(|l| l.starts_with("Layers"))
        .expect("lib.rs's doc comment has a paragraph starting with \"Layers\"");
    let paragraph = doc[start..].iter().take_while(|l| !l.is_empty());
    paragraph
        .flat_map(|l| l.split('`').skip(1).step_by(2))
        .filter(|name| name.chars().all(|c| c.is_ascii_lowercase() || c == '_'))
        .map(str::to_string)
        .collect()
}

/// The `pub mod` declarations of `lib.rs`.
fn declared_modules(lib: &str) -> BTreeSet<String> {
    lib.lines()
        .filter_map(|l| l.trim().strip_prefix("pub mod "))
        .map(|l| l.trim_end_matches(';').to_string())
        .collect()
}

/// `src` with comments, string and char literals blanked (newlines kept, so line numbers
/// stay true).
fn code_only(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    let blank = |out: &mut String, s: &[u8]| {
        for &c in s {
            out.push(if c == b'\n' { '\n' } else { ' ' });
        }
    };
    while i < b.len() {
        let rest = &b[i..];
        let end = if rest.starts_with(b"//") {
            rest.iter().position(|&c| c == b'\n').unwrap_or(rest.len())
        } else if rest.starts_with(b"/*") {
            find(rest, b"*/").map_or(rest.len(), |e| e + 2)
        } else if rest.starts_with(b"r#\"") {
            find(&rest[3..], b"\"#").map_or(rest.len(), |e| e + 5)
        } else if rest[0] == b'"' {
            let mut k = 1;
            while k < rest.len() && rest[k] != b'"' {
                k += if rest[k] == b'\\' { 2 } else { 1 };
            }
            k + 1
        } else if rest[0] == b'\''
            && (rest.get(2) == Some(&b'\'')
                || (rest.get(1) == Some(&b'\\') && rest.get(3) == Some(&b'\'')))
        {
            if rest[1] == b'\\' {
                4
            } else {
                3
            }
        } else {
            0
        };
        if end == 0 {
            out.push(b[i] as char);
            i += 1;
        } else {
            let end = end.min(rest.len());
            blank(&mut out, &rest[..end]);
            i += end;
        }
    }
    out
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// `code` with the bodies of `#[cfg(test)]` modules blanked.
fn without_test_modules(code: &str) -> String {
    let mut out = code.to_string();
    let mut from = 0;
    while let Some(at) = out[from..].find("#[cfg(test)]") {
        let at = from + at;
        let after = &out[at + 12..];
        let head = after.trim_start();
        let head = head.strip_prefix("pub(crate) ").unwrap_or(head);
        from = at + 12;
        if !head.starts_with("mod ") {
            continue;
        }
        let Some(open) = out[from..].find('{').map(|o| from + o) else {
            break;
        };
        let mut depth = 0;
        let mut close = out.len();
        for (k, c) in out[open..].char_indices() {
            match c {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        close = open + k;
                        break;
                    }
                }
                _ => {}
            }
        }
        let blanked: String = out[at..close]
            .chars()
            .map(|c| if c == '\n' { '\n' } else { ' ' })
            .collect();
        out.replace_range(at..close, &blanked);
    }
    out
}

/// The top-level modules one file imports, with the line of each: `crate::name`
/// anywhere (in `use` trees too, where `crate::{a::X, b::Y}` names both), and `super::`
/// chains that climb out of the file's own top-level module.
fn imports(rel: &Path, src: &str) -> Vec<(String, usize)> {
    let code = without_test_modules(&code_only(src));
    let parts: Vec<String> = rel
        .with_extension("")
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    // The module path of this file, as `super::` sees it.
    let mut module = parts.clone();
    if module.last().is_some_and(|l| l == "mod") {
        module.pop();
    }
    let line_of = |at: usize| code[..at].matches('\n').count() + 1;
    let b = code.as_bytes();
    let mut found = Vec::new();
    for (at, _) in code.match_indices("crate::") {
        if at > 0 && is_ident(b[at - 1]) {
            continue;
        }
        for name in first_segments(&code[at + 7..]) {
            found.push((name, line_of(at)));
        }
    }
    for (at, _) in code.match_indices("super::") {
        if at > 0 && (is_ident(b[at - 1]) || b[at - 1] == b':') {
            continue;
        }
        let mut rest = &code[at..];
        let mut up = 0;
        while let Some(r) = rest.strip_prefix("super::") {
            up += 1;
            rest = r;
        }
        if up >= module.len() {
            for name in first_segments(rest) {
                found.push((name, line_of(at)));
            }
        }
    }
    found
}

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

/// The first path segment after `crate::`: one name, or each name of a `{...}` group.
fn first_segments(rest: &str) -> Vec<String> {
    let ident = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect()
    };
    if let Some(group) = rest.strip_prefix('{') {
        let mut depth = 0;
        let mut names = Vec::new();
        let mut start = true;
        for (k, c) in group.char_indices() {
            match c {
                '{' => depth += 1,
                '}' if depth == 0 => break,
                '}' => depth -= 1,
                ',' if depth == 0 => start = true,
                c if start && !c.is_whitespace() => {
                    start = false;
                    names.push(ident(&group[k..]));
                }
                _ => {}
            }
        }
        names.into_iter().filter(|n| !n.is_empty()).collect()
    } else {
        let name = ident(rest);
        if name.is_empty() {
            vec![]
        } else {
            vec![name]
        }
    }
}

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

/// Every import of `files` (path relative to `src/`, text) that points up `order`.
fn upward(order: &[String], files: &[(PathBuf, String)]) -> Vec<String> {
    let rank = |m: &str| order.iter().position(|o| o == m);
    let mut bad = Vec::new();
    for (rel, src) in files {
        let top = rel.iter().next().unwrap().to_string_lossy();
        let top = top.trim_end_matches(".rs");
        let Some(own) = rank(top) else {
            bad.push(format!(
                "{}: module `{top}` is not in lib.rs's layer order",
                rel.display()
            ));
            continue;
        };
        for (name, line) in imports(rel, src) {
            if name == top || name == "self" {
                continue;
            }
            match rank(&name) {
                Some(r) if r > own => bad.push(format!(
                    "{}:{line}: `{top}` imports `{name}`, a layer above it",
                    rel.display()
                )),
                None => bad.push(format!(
                    "{}:{line}: `{name}` is not in lib.rs's layer order",
                    rel.display()
                )),
                _ => {}
            }
        }
    }
    bad
}

#[test]
fn layering_points_every_import_down() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let lib = std::fs::read_to_string(src.join("lib.rs")).unwrap();
    let order = documented_order(&lib);
    let declared = declared_modules(&lib);
    let listed: BTreeSet<String> = order.iter().cloned().collect();
    assert_eq!(
        listed.len(),
        order.len(),
        "a layer is listed twice: {order:?}"
    );
    assert_eq!(
        declared, listed,
        "lib.rs's modules and its layer order differ"
    );
    let mut paths = Vec::new();
    rust_files(&src, &mut paths);
    let files: Vec<(PathBuf, String)> = paths
        .into_iter()
        .map(|p| {
            (
                p.strip_prefix(&src).unwrap().to_path_buf(),
                std::fs::read_to_string(&p).unwrap(),
            )
        })
        .filter(|(rel, _)| {
            let first = rel.iter().next().unwrap().to_string_lossy().into_owned();
            !matches!(first.as_str(), "lib.rs" | "main.rs" | "app" | "app.rs")
        })
        .collect();
    assert!(
        files.len() > 50,
        "found only {} files under src/",
        files.len()
    );
    let bad = upward(&order, &files);
    assert!(
        bad.is_empty(),
        "imports that point up the layers:\n{}",
        bad.join("\n")
    );
}

/// The checker itself finds upward imports in every form the crate writes them, and
/// leaves test modules, comments and strings alone.
#[test]
fn layering_check_finds_an_upward_import() {
    let order: Vec<String> = ["core", "media", "scene"].map(String::from).to_vec();
    let file = |path: &str, src: &str| (PathBuf::from(path), src.to_string());
    let clean = [
        file("media/grid.rs", "use crate::core::Ray;\nuse super::Phase;\n// crate::scene\nconst S: &str = \"crate::scene\";\n#[cfg(test)]\nmod tests {\n    use crate::scene::Scene;\n    fn f() { let _ = '{'; }\n}\n"),
        file("scene/mod.rs", "use crate::{core::Rgb, media::Media};\n"),
    ];
    assert_eq!(upward(&order, &clean), Vec::<String>::new());
    for (path, src) in [
        ("media/grid.rs", "use crate::scene::Scene;\n"),
        ("media/grid.rs", "fn f() { crate::scene::load(); }\n"),
        (
            "media/grid.rs",
            "use crate::{core::Ray, scene::{Scene, Rgb}};\n",
        ),
        ("media/grid.rs", "use super::super::scene::Scene;\n"),
        (
            "media/deep/x.rs",
            "use super::super::super::scene::Scene;\n",
        ),
        ("core/ray.rs", "use crate::media::Media;\n"),
        ("media/grid.rs", "use crate::nowhere::X;\n"),
    ] {
        let bad = upward(&order, &[file(path, src)]);
        assert_eq!(bad.len(), 1, "{path}: {src:?} gave {bad:?}");
    }
    // `super::` inside its own top-level module is no import of another.
    assert!(upward(
        &order,
        &[file("media/deep/x.rs", "use super::super::Phase;\n")]
    )
    .is_empty());
}
