//! The README and the guides (docs/*.md) as a user meets them: the README stays a front door of at
//! most 200 lines, every code block says how it is checked (the shell and Python blocks are run by
//! `scripts/check-docs.sh`, the Rust blocks compiled by `cargo test --doc`), and every relative
//! link leads to a file that exists.

use std::path::{Path, PathBuf};

/// The README's length limit, in lines.
const README_MAX_LINES: usize = 200;

/// Info strings a fenced code block may carry: `sh` and `python` run in `scripts/check-docs.sh`,
/// `rust` in the doctests; the others are shown only. Anything else (```bash, a bare ```) would
/// silently escape both checks, or be compiled as Rust.
const INFO_STRINGS: [&str; 8] = [
    "sh",
    "sh skip",
    "python",
    "python skip",
    "rust",
    "text",
    "json",
    "yaml",
];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// README.md and every docs/*.md, sorted.
fn documents() -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .expect("docs/ exists")
        .map(|e| e.expect("readable entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    files.sort();
    files.insert(0, root().join("README.md"));
    files
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn name(path: &Path) -> String {
    path.strip_prefix(root())
        .unwrap_or(path)
        .display()
        .to_string()
}

#[test]
fn the_readme_is_at_most_200_lines() {
    let lines = read(&root().join("README.md")).lines().count();
    assert!(
        lines <= README_MAX_LINES,
        "README.md has {lines} lines; it is the front door, at most {README_MAX_LINES}: move detail into a guide in docs/"
    );
}

#[test]
fn every_code_block_says_how_it_is_checked() {
    let mut bad = Vec::new();
    for path in documents() {
        let mut open: Option<usize> = None;
        for (i, line) in read(&path).lines().enumerate() {
            let Some(info) = line.strip_prefix("```") else {
                continue;
            };
            let info = info.trim();
            match open {
                Some(_) if info.is_empty() => open = None,
                Some(start) => bad.push(format!(
                    "{}:{}: a fence inside the block opened at line {start}",
                    name(&path),
                    i + 1
                )),
                None => {
                    if !INFO_STRINGS.contains(&info) {
                        bad.push(format!(
                            "{}:{}: code block with info string {info:?}; use one of {INFO_STRINGS:?}",
                            name(&path),
                            i + 1
                        ));
                    }
                    open = Some(i + 1);
                }
            }
        }
        if let Some(start) = open {
            bad.push(format!("{}:{start}: code block never closed", name(&path)));
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

#[test]
fn every_relative_link_leads_to_a_file() {
    let mut bad = Vec::new();
    for path in documents() {
        let text = read(&path);
        let mut in_code = false;
        for (i, line) in text.lines().enumerate() {
            if line.starts_with("```") {
                in_code = !in_code;
                continue;
            }
            if in_code {
                continue;
            }
            // Markdown links and images: ](target) or ](target#anchor).
            for (at, _) in line.match_indices("](") {
                let rest = &line[at + 2..];
                let Some(end) = rest.find(')') else { continue };
                let target = &rest[..end];
                if target.contains("://")
                    || target.starts_with('#')
                    || target.starts_with("mailto:")
                {
                    continue;
                }
                let file = target.split('#').next().unwrap_or(target);
                let resolved = path.parent().expect("a document has a folder").join(file);
                if !resolved.exists() {
                    bad.push(format!(
                        "{}:{}: link to {target}: {} does not exist",
                        name(&path),
                        i + 1,
                        name(&resolved)
                    ));
                }
            }
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

#[test]
fn the_readme_links_every_guide() {
    let readme = read(&root().join("README.md"));
    let missing: Vec<String> = documents()
        .iter()
        .skip(1)
        .map(|p| name(p))
        .filter(|guide| !readme.contains(&format!("]({guide})")))
        .collect();
    assert!(missing.is_empty(), "README.md does not link {missing:?}");
}

#[test]
fn the_job_files_of_the_guides_are_well_formed() {
    // The YAML is parsed (it cannot be run here); the SLURM files run one task in check-docs.
    for file in ["docs/jobs/sweep-job.yaml", "docs/jobs/stereo-job.yaml"] {
        let yaml = read(&root().join(file));
        for event in saphyr_parser::Parser::new_from_str(&yaml) {
            if let Err(error) = event {
                panic!("{file}: {error}");
            }
        }
    }
    for file in [
        "docs/jobs/sweep.sbatch",
        "docs/jobs/merge.sbatch",
        "docs/jobs/stereo.sbatch",
        "docs/jobs/stereo-merge.sbatch",
    ] {
        let text = read(&root().join(file));
        // sbatch reads #SBATCH lines only before the first command.
        let first_command = text
            .lines()
            .position(|l| !l.trim().is_empty() && !l.starts_with('#'))
            .expect("a job runs something");
        let lines: Vec<&str> = text.lines().collect();
        let last_directive = lines
            .iter()
            .rposition(|l| l.starts_with("#SBATCH"))
            .expect("#SBATCH lines");
        assert!(
            last_directive < first_command,
            "{file}: an #SBATCH line after the first command is ignored by sbatch"
        );
    }
}
