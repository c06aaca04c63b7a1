//! CSV tables with a header row (DESIGN.md §1): points `x,y,z`, pixels `u,v`, matches
//! `ul,vl,ur,vr`, rays `ox,oy,oz,dx,dy,dz`, and the outputs of every command.
//!
//! Input: the header must be exactly the expected names (spaces around names and values are
//! ignored); every data line must have one finite number per column. Output keeps input order, one
//! row per input row, `NaN` in every column of a row without an answer.

use std::io::Write;
use std::path::Path;

use super::{IoError, write_atomic};

/// Reads a CSV file (`-` = standard input) whose header row must be exactly `header` (after
/// trimming spaces around names). Returns one row of N numbers per data line, in file order.
///
/// Spaces around values are allowed; blank lines are skipped. Errors name the file, the 1-based
/// line and the column: a missing or different header, a line with another number of values, a
/// value that is not a number or not finite (NaN and infinities are not valid input).
pub fn read_table<const N: usize>(
    path: &Path,
    header: [&str; N],
) -> Result<Vec<[f64; N]>, IoError> {
    if path.as_os_str() == "-" {
        return read_table_from(std::io::stdin().lock(), path, header);
    }
    let file = std::fs::File::open(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    read_table_from(std::io::BufReader::new(file), path, header)
}

/// [`read_table`] from any reader (standard input, a byte slice in tests); `path` labels errors.
pub fn read_table_from<R: std::io::Read, const N: usize>(
    reader: R,
    path: &Path,
    header: [&str; N],
) -> Result<Vec<[f64; N]>, IoError> {
    // The tables hold numbers only, so this reads lines itself rather than through the `csv` crate,
    // whose record positions are off after blank lines (BurntSushi/rust-csv#208).
    let csv_error = |line: usize, column: String, reason: String| IoError::Csv {
        path: path.to_path_buf(),
        line,
        column,
        reason,
    };
    let mut lines = Lines {
        reader: std::io::BufReader::new(reader),
        buffer: Vec::new(),
        number: 0,
        path,
        header: &header,
    };
    let expected = header.join(",");
    // The header: the first line that is not blank.
    let found = loop {
        match lines.next_line()? {
            None => {
                return Err(csv_error(
                    1,
                    "1".into(),
                    format!("file is empty; expected the header '{expected}'"),
                ));
            }
            Some((_, text)) if text.trim().is_empty() => {}
            Some((_, text)) => {
                break text
                    .trim_start_matches('\u{feff}')
                    .split(',')
                    .map(field)
                    .collect::<Vec<_>>()
                    .join(",");
            }
        }
    };
    if found != expected {
        let found: Vec<&str> = found.split(',').collect();
        let column = (0..N.max(found.len()))
            .find(|&i| found.get(i) != header.get(i))
            .unwrap_or(0)
            + 1;
        return Err(csv_error(
            lines.number,
            column.to_string(),
            format!("header is '{}', expected '{expected}'", found.join(",")),
        ));
    }
    let mut rows = Vec::new();
    while let Some((line, text)) = lines.next_line()? {
        if text.trim().is_empty() {
            continue;
        }
        let mut row = [0.0; N];
        let mut count = 0;
        for value in text.split(',').map(field) {
            if let (Some(slot), Some(name)) = (row.get_mut(count), header.get(count)) {
                let number: f64 = value.parse().map_err(|_| {
                    csv_error(line, name.to_string(), format!("not a number: \"{value}\""))
                })?;
                if !number.is_finite() {
                    return Err(csv_error(
                        line,
                        name.to_string(),
                        format!("must be a finite number, got \"{value}\""),
                    ));
                }
                *slot = number;
            }
            count += 1;
        }
        if count != N {
            // Name the first missing column, or the number of the first extra one.
            let column = header
                .get(count)
                .map_or_else(|| (N + 1).to_string(), |name| name.to_string());
            return Err(csv_error(
                line,
                column,
                format!("line has {count} values, expected {N} ({expected})"),
            ));
        }
        rows.push(row);
    }
    Ok(rows)
}

/// A value without the spaces around it and without enclosing double quotes.
fn field(text: &str) -> &str {
    let text = text.trim();
    text.strip_prefix('"')
        .and_then(|t| t.strip_suffix('"'))
        .unwrap_or(text)
}

/// Lines of a reader, counted from 1, with `\n` or `\r\n` ends removed.
struct Lines<'a, R> {
    reader: std::io::BufReader<R>,
    buffer: Vec<u8>,
    /// 1-based number of the line last returned.
    number: usize,
    path: &'a Path,
    header: &'a [&'a str],
}

impl<R: std::io::Read> Lines<'_, R> {
    /// The next line and its number, `None` at the end.
    fn next_line(&mut self) -> Result<Option<(usize, &str)>, IoError> {
        self.buffer.clear();
        let read = std::io::BufRead::read_until(&mut self.reader, b'\n', &mut self.buffer)
            .map_err(|source| IoError::Read {
                path: self.path.to_path_buf(),
                source,
            })?;
        if read == 0 {
            return Ok(None);
        }
        self.number += 1;
        let mut bytes = &self.buffer[..];
        bytes = bytes.strip_suffix(b"\n").unwrap_or(bytes);
        bytes = bytes.strip_suffix(b"\r").unwrap_or(bytes);
        std::str::from_utf8(bytes)
            .map(|text| Some((self.number, text)))
            .map_err(|e| {
                let index = bytes[..e.valid_up_to()]
                    .iter()
                    .filter(|&&b| b == b',')
                    .count();
                IoError::Csv {
                    path: self.path.to_path_buf(),
                    line: self.number,
                    column: self
                        .header
                        .get(index)
                        .map_or_else(|| (index + 1).to_string(), |n| n.to_string()),
                    reason: "not valid UTF-8 text".into(),
                }
            })
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
/// (see [`write_atomic`]), or to standard output when `path` is `None` or `-`. Numbers are written
/// with Rust's `{}` for f64: the shortest text that reads back to the same f64.
pub fn write_table<const M: usize>(
    path: Option<&Path>,
    header: [&str; M],
    rows: impl IntoIterator<Item = Option<[f64; M]>>,
) -> Result<TableWriteSummary, IoError> {
    let mut text = String::with_capacity(64);
    text.push_str(&header.join(","));
    text.push('\n');
    let nan_row = vec!["NaN"; M].join(",");
    let mut summary = TableWriteSummary {
        rows: 0,
        nan_rows: 0,
    };
    for row in rows {
        summary.rows += 1;
        match row {
            Some(values) => {
                for (i, v) in values.iter().enumerate() {
                    if i > 0 {
                        text.push(',');
                    }
                    // Display for f64 is the shortest round-trip representation.
                    std::fmt::Write::write_fmt(&mut text, format_args!("{v}"))
                        .expect("writing to a String");
                }
            }
            None => {
                summary.nan_rows += 1;
                text.push_str(&nan_row);
            }
        }
        text.push('\n');
    }
    match path {
        Some(path) if path.as_os_str() != "-" => write_atomic(path, text.as_bytes())?,
        _ => {
            let mut out = std::io::stdout().lock();
            out.write_all(text.as_bytes())
                .and_then(|()| out.flush())
                .map_err(|source| IoError::Write {
                    path: "-".into(),
                    source,
                })?;
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

    /// (line, column, message) of a CSV error.
    fn failure(text: &str) -> (usize, String, String) {
        match read(text) {
            Err(e @ IoError::Csv { .. }) => {
                let message = e.to_string();
                let IoError::Csv { line, column, .. } = e else {
                    unreachable!()
                };
                (line, column, message)
            }
            other => panic!("expected IoError::Csv, got {other:?}"),
        }
    }

    #[test]
    fn reads_rows_in_order_with_spaces() {
        let rows = read("x, y, z\n1,2,3\n 4.5 , -6e-3 ,7\n\n  \n").unwrap();
        assert_eq!(rows, vec![[1.0, 2.0, 3.0], [4.5, -6e-3, 7.0]]);
        // CRLF, a UTF-8 byte-order mark, quoted values, numbers without leading/trailing digits.
        let rows = read("\u{feff}x,y,z\r\n\"1\",.5,2.\r\n").unwrap();
        assert_eq!(rows, vec![[1.0, 0.5, 2.0]]);
        // The shortest round-trip text reads back exactly.
        let rows = read("x,y,z\n0.30000000000000004,5e-324,1.7976931348623157e308\n").unwrap();
        assert_eq!(rows, vec![[0.1 + 0.2, f64::from_bits(1), f64::MAX]]);
    }

    #[test]
    fn header_only_is_an_empty_table() {
        assert!(read("x,y,z\n").unwrap().is_empty());
        assert!(read("x,y,z").unwrap().is_empty());
        assert!(read("\n x , y , z \n\n").unwrap().is_empty());
    }

    #[test]
    fn header_must_match() {
        let (line, column, m) = failure("x,y,w\n1,2,3\n");
        assert_eq!((line, column.as_str()), (1, "3"));
        assert_eq!(
            m,
            "p.csv:1: column '3': header is 'x,y,w', expected 'x,y,z'"
        );
        let (_, column, m) = failure("x,y\n1,2\n");
        assert_eq!(column, "3");
        assert!(m.contains("header is 'x,y', expected 'x,y,z'"), "{m}");
        let (_, column, _) = failure("x,y,z,w\n1,2,3,4\n");
        assert_eq!(column, "4");
        // A file without a header: its first data line is reported as the header found.
        let (line, column, m) = failure("1,2,3\n");
        assert_eq!((line, column.as_str()), (1, "1"));
        assert!(m.contains("header is '1,2,3'"), "{m}");
        let (line, _, m) = failure("\n\nX,y,z\n");
        assert_eq!(line, 3, "{m}");
    }

    #[test]
    fn empty_file_is_an_error() {
        for text in ["", "\n\n", "  \n"] {
            let (line, _, m) = failure(text);
            assert_eq!(line, 1);
            assert!(
                m.contains("file is empty; expected the header 'x,y,z'"),
                "{m}"
            );
        }
    }

    #[test]
    fn wrong_column_count_names_line_and_column() {
        let (line, column, m) = failure("x,y,z\n1,2,3\n1,2\n");
        assert_eq!((line, column.as_str()), (3, "z"));
        assert!(
            m.starts_with("p.csv:3: column 'z': line has 2 values, expected 3"),
            "{m}"
        );
        let (line, column, _) = failure("x,y,z\n1,2,3\n1,2,3,4\n");
        assert_eq!((line, column.as_str()), (3, "4"));
        // Blank lines before it do not shift the line number.
        let (line, _, _) = failure("x,y,z\n\n1,2,3\n\n1,2,3,\n");
        assert_eq!(line, 5);
    }

    #[test]
    fn values_must_be_finite_numbers() {
        let (line, column, m) = failure("x,y,z\n1,2,3\n1,abc,3\n");
        assert_eq!((line, column.as_str()), (3, "y"));
        assert_eq!(m, "p.csv:3: column 'y': not a number: \"abc\"");
        let (_, column, m) = failure("x,y,z\n1,,3\n");
        assert_eq!(column, "y");
        assert!(m.contains("not a number: \"\""), "{m}");
        for bad in ["NaN", "nan", "inf", "-inf", "infinity", "1e999"] {
            let (line, column, m) = failure(&format!("x,y,z\n1,2,{bad}\n"));
            assert_eq!((line, column.as_str()), (2, "z"), "{bad}");
            assert!(m.contains("must be a finite number"), "{m}");
        }
        let error = read_table_from(
            &b"x,y,z\n1,\xff,3\n"[..],
            Path::new("p.csv"),
            ["x", "y", "z"],
        )
        .unwrap_err();
        assert!(
            matches!(&error, IoError::Csv { line: 2, column, .. } if column == "y"),
            "{error:?}"
        );
    }

    #[test]
    fn files_are_read_by_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.csv");
        std::fs::write(&path, "ul,vl,ur,vr\n1,2,3,4\n").unwrap();
        assert_eq!(
            read_table(&path, ["ul", "vl", "ur", "vr"]).unwrap(),
            vec![[1.0, 2.0, 3.0, 4.0]]
        );
        let missing = dir.path().join("missing.csv");
        let error = read_table(&missing, ["u", "v"]).unwrap_err();
        assert!(matches!(error, IoError::Read { .. }));
        assert!(error.to_string().contains("missing.csv"), "{error}");
    }

    #[test]
    fn writes_nan_rows_and_counts_them() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.csv");
        let rows = [
            Some([1.5, -0.1]),
            None,
            Some([0.1 + 0.2, 3.0]),
            None,
            Some([1e-7, -0.0]),
            Some([5e-324, 1e300]),
        ];
        let summary = write_table(Some(&path), ["u", "v"], rows).unwrap();
        assert_eq!(
            summary,
            TableWriteSummary {
                rows: 6,
                nan_rows: 2
            }
        );
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[..6],
            [
                "u,v",
                "1.5,-0.1",
                "NaN,NaN",
                "0.30000000000000004,3",
                "NaN,NaN",
                "0.0000001,-0"
            ]
        );
        // `{}` writes positional notation, never an exponent: 5e-324 takes 327 characters.
        assert!(
            lines[6].starts_with("0.000") && lines[6].len() > 600,
            "{}",
            lines[6]
        );
        assert_eq!(lines.len(), 7);
        // Every finite row reads back bit for bit.
        let finite: String = text
            .lines()
            .filter(|l| !l.contains("NaN"))
            .map(|l| format!("{l}\n"))
            .collect();
        let back = read_table_from(finite.as_bytes(), &path, ["u", "v"]).unwrap();
        let expected: Vec<[f64; 2]> = rows.into_iter().flatten().collect();
        assert_eq!(back.len(), expected.len());
        for (a, b) in back.iter().zip(&expected) {
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
        }
        // NaN rows mark "no answer" in outputs; they are not valid input.
        assert!(read_table_from(text.as_bytes(), &path, ["u", "v"]).is_err());
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no temporary file is left behind"
        );
    }

    #[test]
    fn failed_write_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no_such_dir").join("out.csv");
        let error = write_table(Some(&path), ["u", "v"], [Some([1.0, 2.0])]).unwrap_err();
        assert!(matches!(error, IoError::Write { .. }));
        assert!(error.to_string().contains("out.csv"), "{error}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        // A header-only table for no rows.
        let path = dir.path().join("empty.csv");
        assert_eq!(
            write_table(Some(&path), ["u", "v"], []).unwrap(),
            TableWriteSummary {
                rows: 0,
                nan_rows: 0
            }
        );
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "u,v\n");
    }
}
