//! CSV tables with a header row (DESIGN.md §1): points `x,y,z`, pixels `u,v`, matches
//! `ul,vl,ur,vr`, rays `ox,oy,oz,dx,dy,dz`, and the outputs of every command.
//!
//! Input: the header must be exactly the expected names (spaces around names and values are
//! ignored); every data line must have one finite number per column. Output keeps input order, one
//! row per input row, `NaN` in every column of a row without an answer.

use std::io::Write;
use std::path::Path;

use super::{IoError, write_atomic};

/// Reads a CSV file (`-` = standard input) whose header must be exactly `header`. Returns one row
/// of N numbers per data line, in file order. Blank lines are skipped.
pub fn read_table<const N: usize>(path: &Path, header: [&str; N]) -> Result<Vec<[f64; N]>, IoError> {
    if path.as_os_str() == "-" {
        return read_table_from(std::io::stdin().lock(), path, header);
    }
    let file = std::fs::File::open(path).map_err(|source| IoError::Read { path: path.to_path_buf(), source })?;
    read_table_from(std::io::BufReader::new(file), path, header)
}

/// [`read_table`] from any reader; `path` labels errors.
pub fn read_table_from<R: std::io::Read, const N: usize>(
    reader: R,
    path: &Path,
    header: [&str; N],
) -> Result<Vec<[f64; N]>, IoError> {
    let csv_error = |line: usize, column: String, reason: String| IoError::Csv {
        path: path.to_path_buf(),
        line,
        column,
        reason,
    };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(reader);
    let mut records = reader.records();
    let expected = header.join(",");
    let first = match records.next() {
        None => return Err(csv_error(1, "1".into(), format!("file is empty; expected the header '{expected}'"))),
        Some(record) => record.map_err(|e| read_failure(path, e))?,
    };
    let found: Vec<&str> = first.iter().collect();
    if found != header {
        let line = first.position().map_or(1, |p| p.line() as usize);
        let column = (0..N.max(found.len()))
            .find(|&i| found.get(i) != header.get(i))
            .map_or_else(|| "1".to_string(), |i| (i + 1).to_string());
        return Err(csv_error(line, column, format!("header is '{}', expected '{expected}'", found.join(","))));
    }
    let mut rows = Vec::new();
    for record in records {
        let record = record.map_err(|e| read_failure(path, e))?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        if record.len() != N {
            return Err(csv_error(
                line,
                header[N.min(record.len()).saturating_sub(1).min(N - 1)].to_string(),
                format!("has {} values, expected {N} ({expected})", record.len()),
            ));
        }
        let mut row = [0.0; N];
        for (i, (value, name)) in record.iter().zip(header).enumerate() {
            let number: f64 = value
                .parse()
                .map_err(|_| csv_error(line, name.to_string(), format!("not a number: \"{value}\"")))?;
            if !number.is_finite() {
                return Err(csv_error(line, name.to_string(), format!("must be finite, got \"{value}\"")));
            }
            row[i] = number;
        }
        rows.push(row);
    }
    Ok(rows)
}

fn read_failure(path: &Path, error: csv::Error) -> IoError {
    let line = error.position().map_or(0, |p| p.line() as usize);
    match error.into_kind() {
        csv::ErrorKind::Io(source) => IoError::Read { path: path.to_path_buf(), source },
        kind => IoError::Csv { path: path.to_path_buf(), line, column: "?".into(), reason: format!("{kind:?}") },
    }
}

/// What [`write_table`] wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TableWriteSummary {
    /// Data rows written.
    pub rows: usize,
    /// Rows written as NaN (no answer).
    pub nan_rows: usize,
}

/// Writes the header and one line per row, `None` as `NaN` in every column, to `path` atomically
/// or to standard output when `path` is `None`. Numbers use the shortest text that reads back to
/// the same f64.
pub fn write_table<const M: usize>(
    path: Option<&Path>,
    header: [&str; M],
    rows: impl IntoIterator<Item = Option<[f64; M]>>,
) -> Result<TableWriteSummary, IoError> {
    let mut text = String::with_capacity(64);
    text.push_str(&header.join(","));
    text.push('\n');
    let mut summary = TableWriteSummary { rows: 0, nan_rows: 0 };
    for row in rows {
        summary.rows += 1;
        match row {
            Some(values) => {
                for (i, v) in values.iter().enumerate() {
                    if i > 0 {
                        text.push(',');
                    }
                    // Display for f64 is the shortest round-trip representation.
                    std::fmt::Write::write_fmt(&mut text, format_args!("{v}")).expect("writing to a String");
                }
            }
            None => {
                summary.nan_rows += 1;
                text.push_str(&vec!["NaN"; M].join(","));
            }
        }
        text.push('\n');
    }
    match path {
        Some(path) => write_atomic(path, text.as_bytes())?,
        None => {
            let mut out = std::io::stdout().lock();
            out.write_all(text.as_bytes())
                .and_then(|()| out.flush())
                .map_err(|source| IoError::Write { path: "-".into(), source })?;
        }
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<Vec<[f64; 3]>, IoError> {
        read_table_from(text.as_bytes(), Path::new("p.csv"), ["x", "y", "z"])
    }

    fn message(text: &str) -> String {
        read(text).expect_err("should be rejected").to_string()
    }

    #[test]
    fn reads_rows_in_order_with_spaces() {
        let rows = read("x, y, z\n1,2,3\n 4.5 , -6e-3 ,7\n\n").unwrap();
        assert_eq!(rows, vec![[1.0, 2.0, 3.0], [4.5, -6e-3, 7.0]]);
        assert!(read("x,y,z\n").unwrap().is_empty());
    }

    #[test]
    fn errors_name_line_and_column() {
        assert_eq!(message("x,y,w\n1,2,3\n"), "p.csv:1: column '3': header is 'x,y,w', expected 'x,y,z'");
        let m = message("x,y,z\n1,2,3\n1,2\n");
        assert!(m.starts_with("p.csv:3:") && m.contains("2 values"), "{m}");
        assert_eq!(message("x,y,z\n1,2,3\n1,abc,3\n"), "p.csv:3: column 'y': not a number: \"abc\"");
        assert!(message("x,y,z\n1,2,NaN\n").starts_with("p.csv:2: column 'z': must be finite"));
        assert!(message("x,y,z\n1,2,inf\n").contains("column 'z'"));
        assert!(message("").contains("empty"));
        assert!(message("x,y\n1,2\n").contains("header"));
    }

    #[test]
    fn writes_nan_rows_and_counts_them() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.csv");
        let summary = write_table(Some(&path), ["u", "v"], [Some([1.5, -0.1]), None, Some([0.1 + 0.2, 3.0])]).unwrap();
        assert_eq!(summary, TableWriteSummary { rows: 3, nan_rows: 1 });
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text, "u,v\n1.5,-0.1\nNaN,NaN\n0.30000000000000004,3\n");
        // Round trip exactness of the text.
        let back = read_table_from(text.as_bytes(), &path, ["u", "v"]);
        assert!(back.is_err(), "NaN rows are not valid input");
    }
}
