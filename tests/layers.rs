//! The layers of docs/architecture.md hold: no module of `src/` uses a layer to its right.
//!
//! ```text
//! base → model → gpu → engine → calib, stereo, render, detect → io → runs, report → cli
//! ```
//!
//! The four algorithm layers stand side by side: none of them uses another. The check reads every
//! `crate::LAYER` path in the code (comments and doc links left out, and `#[cfg(test)]` items: a
//! unit test may build its inputs with any layer, as the integration tests do). The WGSL that the
//! calibration and stereo kernels include is text, not a module, and is not checked here.

use std::path::{Path, PathBuf};

/// Each layer's place from the left; the algorithm layers share one.
const LAYERS: &[(&str, usize)] = &[
    ("base", 0),
    ("model", 1),
    ("gpu", 2),
    ("engine", 3),
    ("calib", 4),
    ("stereo", 4),
    ("render", 4),
    ("detect", 4),
    ("io", 5),
    ("runs", 6),
    ("report", 6),
    ("cli", 7),
];

fn rank(layer: &str) -> Option<usize> {
    LAYERS.iter().find(|(l, _)| *l == layer).map(|&(_, r)| r)
}

/// The code of `text` without comments (line, doc and block comments) and without the items
/// marked `#[cfg(test)]`, line by line (lines kept, emptied, so that numbers stay true).
fn code_lines(text: &str) -> Vec<String> {
    // Comments out first (strings may hold `//`, as in "http://": a quote toggles string mode).
    let mut lines = Vec::new();
    let mut in_block = 0usize;
    for line in text.lines() {
        let mut out = String::new();
        let chars: Vec<char> = line.chars().collect();
        let mut in_string = false;
        let mut i = 0;
        while i < chars.len() {
            let c = chars[i];
            let next = chars.get(i + 1).copied();
            if in_block > 0 {
                if c == '*' && next == Some('/') {
                    in_block -= 1;
                    i += 2;
                } else if c == '/' && next == Some('*') {
                    in_block += 1;
                    i += 2;
                } else {
                    i += 1;
                }
                continue;
            }
            if in_string {
                if c == '\\' {
                    out.push(c);
                    if let Some(n) = next {
                        out.push(n);
                    }
                    i += 2;
                    continue;
                }
                if c == '"' {
                    in_string = false;
                }
                out.push(c);
                i += 1;
                continue;
            }
            match (c, next) {
                ('/', Some('/')) => break,
                ('/', Some('*')) => {
                    in_block += 1;
                    i += 2;
                }
                ('"', _) => {
                    in_string = true;
                    out.push(c);
                    i += 1;
                }
                // A char literal holding a quote or a brace: kept out of the counts below.
                ('\'', _) if chars.get(i + 2) == Some(&'\'') => {
                    out.push_str("' '");
                    i += 3;
                }
                _ => {
                    out.push(c);
                    i += 1;
                }
            }
        }
        lines.push(out);
    }
    // Then the #[cfg(test)] items: the next item after the attribute, to its `;` or its closing
    // brace.
    let mut i = 0;
    while i < lines.len() {
        if lines[i].trim() == "#[cfg(test)]" {
            lines[i].clear();
            let mut depth = 0i64;
            let mut opened = false;
            i += 1;
            while i < lines.len() {
                let line = std::mem::take(&mut lines[i]);
                let mut in_string = false;
                let mut escaped = false;
                for c in line.chars() {
                    if in_string {
                        match c {
                            _ if escaped => escaped = false,
                            '\\' => escaped = true,
                            '"' => in_string = false,
                            _ => {}
                        }
                        continue;
                    }
                    match c {
                        '"' => in_string = true,
                        '{' => {
                            depth += 1;
                            opened = true;
                        }
                        '}' => depth -= 1,
                        _ => {}
                    }
                }
                i += 1;
                let ends = if opened {
                    depth <= 0
                } else {
                    line.trim_end().ends_with(';') && !line.trim_start().starts_with("#[")
                };
                if ends {
                    break;
                }
            }
        } else {
            i += 1;
        }
    }
    lines
}

/// The layers that `text` (a file of layer `layer`) uses against the rules: `(line, used)`.
fn violations(layer: &str, text: &str) -> Vec<(usize, String)> {
    let Some(own) = rank(layer) else {
        return Vec::new();
    };
    let mut found = Vec::new();
    for (n, line) in code_lines(text).iter().enumerate() {
        let mut used = Vec::new();
        let mut rest = line.as_str();
        while let Some(at) = rest.find("crate::") {
            rest = &rest[at + "crate::".len()..];
            if let Some(group) = rest.strip_prefix('{') {
                // `use crate::{a, b::c}`: every first name in the group.
                let inner = group.split('}').next().unwrap_or("");
                used.extend(
                    inner
                        .split(',')
                        .map(|p| p.trim().split("::").next().unwrap_or("").trim().to_string()),
                );
            } else {
                let name: String = rest
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                used.push(name);
            }
        }
        for name in used {
            if name == layer {
                continue;
            }
            if let Some(other) = rank(&name)
                && other >= own
            {
                found.push((n + 1, name));
            }
        }
    }
    found
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("src/ can be read") {
        let path = entry.expect("a directory entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn no_module_uses_a_layer_to_its_right() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut wrong = Vec::new();
    let mut layers_seen = std::collections::BTreeSet::new();
    for file in &files {
        let relative = file.strip_prefix(&src).unwrap();
        let Some(layer) = relative
            .components()
            .next()
            .and_then(|c| c.as_os_str().to_str())
            .filter(|_| relative.components().count() > 1)
        else {
            continue; // lib.rs, main.rs: the crate's root
        };
        assert!(
            rank(layer).is_some(),
            "src/{layer}/ is not a layer of docs/architecture.md: add it to the layers (and to this test)"
        );
        layers_seen.insert(layer.to_string());
        let text = std::fs::read_to_string(file).unwrap();
        for (line, used) in violations(layer, &text) {
            wrong.push(format!(
                "src/{}:{line}: {layer} uses {used}",
                relative.display()
            ));
        }
    }
    assert!(
        layers_seen.len() >= 10,
        "only {layers_seen:?} found under src/"
    );
    assert!(
        wrong.is_empty(),
        "modules that use a layer to their right (docs/architecture.md, \"Layers\"):\n{}",
        wrong.join("\n")
    );
}

#[test]
fn a_planted_violation_is_found() {
    // A model file that reaches for io, an algorithm that uses another, grouped and plain paths.
    let planted = "use crate::model::Rig;\nuse crate::{io::read_rig, model::Layer};\n";
    assert_eq!(violations("model", planted), vec![(2, "io".to_string())]);
    assert_eq!(
        violations("render", "fn f() { crate::calib::simulate(); }"),
        vec![(1, "calib".to_string())]
    );
    assert_eq!(
        violations("io", "pub use crate::runs::sequence;"),
        vec![(1, "runs".to_string())]
    );
    // What the check leaves alone: comments, doc links, strings' slashes, test items.
    let allowed = r#"//! See [`crate::cli`].
/// Links to [`crate::io::read_rig`].
const URL: &str = "https://example.org"; use crate::base::Board; // crate::cli
/* crate::cli */
#[cfg(test)]
mod tests {
    use crate::io::read_rig;
    fn f() { let s = "}"; crate::cli::main(); }
}
#[cfg(test)]
use crate::render::noise;
use crate::model::Rig;
"#;
    assert_eq!(violations("calib", allowed), Vec::<(usize, String)>::new());
    // ... but a test item does not hide what follows it.
    let after = "#[cfg(test)]\nuse crate::io::x;\nuse crate::io::y;\n";
    assert_eq!(violations("calib", after), vec![(3, "io".to_string())]);
}
