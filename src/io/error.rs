//! Errors of the I/O layer. Every variant names the file and where in it the problem is.

use std::path::{Path, PathBuf};

/// A file that could not be read, parsed or written.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The file could not be opened or read.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        /// The file (`-` for standard input).
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// The file could not be written.
    #[error("{}: cannot write: {source}", path.display())]
    Write {
        /// The file (`-` for standard output).
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// JSON syntax or schema error (unknown key, missing field, wrong type).
    #[error("{}{}{reason}", located(path, &[*line, *column]), prefix(field))]
    Json {
        /// The file.
        path: PathBuf,
        /// JSON path of the offending value (`cameras[1].fx`), empty when unknown.
        field: String,
        /// 1-based line (0 when unknown).
        line: usize,
        /// 1-based column (0 when unknown).
        column: usize,
        /// What is wrong.
        reason: String,
    },
    /// Well-formed input whose values describe no valid rig.
    #[error("{}: {}{reason}", path.display(), prefix(field))]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The offending field (`cameras[1]`, `interface`, …).
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// OpenCV FileStorage YAML that cannot be used.
    #[error("{}{reason}", located(path, &[*line]))]
    OpenCv {
        /// The file.
        path: PathBuf,
        /// 1-based line (0 when the problem is the file as a whole, e.g. a missing key).
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// Malformed CSV.
    #[error("{}column '{column}': {reason}", located(path, &[*line]))]
    Csv {
        /// The file (`-` for standard input).
        path: PathBuf,
        /// 1-based line of the file (0 when unknown).
        line: usize,
        /// Column name (or number when the header itself is wrong).
        column: String,
        /// What is wrong.
        reason: String,
    },
    /// An external program that reading the file needs (`ffmpeg` for videos) is not installed or
    /// cannot be started.
    #[error("{}: reading it needs the `{program}` command, which cannot be started ({source}): {install}", path.display())]
    MissingProgram {
        /// The file that needed it.
        path: PathBuf,
        /// The program's name as run (`ffmpeg`, `ffprobe`).
        program: String,
        /// How to install it.
        install: String,
        /// The operating-system error of starting it.
        source: std::io::Error,
    },
}

pub(crate) use crate::base::text::{EXCERPT_CHARS, excerpt, head, quoted, shorten_quoted};

/// `path:line:column: `, leaving out positions that are unknown (0).
fn located(path: &Path, position: &[usize]) -> String {
    let mut text = path.display().to_string();
    for p in position.iter().take_while(|&&p| p > 0) {
        text.push_str(&format!(":{p}"));
    }
    text.push_str(": ");
    text
}

/// `field: `, or nothing for an empty field.
fn prefix(field: &str) -> String {
    if field.is_empty() {
        String::new()
    } else {
        format!("{field}: ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_quoted_pieces_of_messages_are_cut() {
        // Short messages pass unchanged, also with an unclosed quote.
        for m in [
            "unknown field `colour`, expected one of `cameras`, `interface`",
            "invalid type: string \"a\\\"b\", expected f64",
            "expected `",
        ] {
            assert_eq!(shorten_quoted(m, 12), m);
        }
        let key = "k".repeat(1000);
        assert_eq!(
            shorten_quoted(&format!("unknown field `{key}`, expected `a` or `b`"), 8),
            "unknown field `kkkkkkkk…` (1000 bytes), expected `a` or `b`"
        );
        // An escaped quote does not end a double-quoted piece.
        let value = format!("{}\\\"{}", "v".repeat(10), "w".repeat(1000));
        assert_eq!(
            shorten_quoted(
                &format!("invalid type: string \"{value}\", expected f64"),
                8
            ),
            format!(
                "invalid type: string \"vvvvvvvv…\" ({} bytes), expected f64",
                value.len()
            )
        );
        assert_eq!(
            shorten_quoted(&format!("expected `{key}"), 8),
            "expected `kkkkkkkk… (1000 bytes)"
        );
        // A long message without quotes keeps its start.
        let m = shorten_quoted(&"z".repeat(1000), 8);
        assert_eq!(m, format!("{}… (1000 bytes)", "z".repeat(128)));
        assert_eq!(excerpt("abc", 3), "abc");
        assert_eq!(excerpt("abcd", 3), "abc… (4 bytes)");
        assert_eq!(excerpt("ééé", 2), "éé… (6 bytes)");
    }

    #[test]
    fn messages_leave_out_unknown_positions() {
        let path = PathBuf::from("rig.json");
        let json = |line, column, field: &str| IoError::Json {
            path: path.clone(),
            field: field.into(),
            line,
            column,
            reason: "missing field `fx`".into(),
        };
        assert_eq!(
            json(3, 7, "cameras[1]").to_string(),
            "rig.json:3:7: cameras[1]: missing field `fx`"
        );
        assert_eq!(json(0, 0, "").to_string(), "rig.json: missing field `fx`");
        let opencv = |line| IoError::OpenCv {
            path: "s.yml".into(),
            line,
            reason: "missing key T".into(),
        };
        assert_eq!(opencv(0).to_string(), "s.yml: missing key T");
        assert_eq!(opencv(4).to_string(), "s.yml:4: missing key T");
        let csv = IoError::Csv {
            path: "-".into(),
            line: 7,
            column: "y".into(),
            reason: "not a number: \"abc\"".into(),
        };
        assert_eq!(csv.to_string(), "-:7: column 'y': not a number: \"abc\"");
        let invalid = IoError::Invalid {
            path: path.clone(),
            field: "cameras[1].fx".into(),
            reason: "must be > 0".into(),
        };
        assert_eq!(invalid.to_string(), "rig.json: cameras[1].fx: must be > 0");
    }
}
