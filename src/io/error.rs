//! Errors of the I/O layer. Every variant names the file and where in it the problem is.

use std::path::PathBuf;

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
    #[error("{}:{line}:{column}: {}{reason}", path.display(), if field.is_empty() { String::new() } else { format!("{field}: ") })]
    Json {
        /// The file.
        path: PathBuf,
        /// JSON path of the offending value (`cameras[1].fx`), empty when unknown.
        field: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What is wrong.
        reason: String,
    },
    /// Well-formed input whose values describe no valid rig.
    #[error("{}: {field}: {reason}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The offending field (`cameras[1]`, `interface`, …).
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// OpenCV FileStorage YAML that cannot be used.
    #[error("{}:{line}: {reason}", path.display())]
    OpenCv {
        /// The file.
        path: PathBuf,
        /// 1-based line (0 when the problem is the file as a whole, e.g. a missing key).
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// Malformed CSV.
    #[error("{}:{line}: column '{column}': {reason}", path.display())]
    Csv {
        /// The file (`-` for standard input).
        path: PathBuf,
        /// 1-based line of the file.
        line: usize,
        /// Column name (or number when the header itself is wrong).
        column: String,
        /// What is wrong.
        reason: String,
    },
}
