//! CSV tables with a header row (DESIGN.md §1): points `x,y,z`, pixels `u,v`, matches
//! `ul,vl,ur,vr`, rays `ox,oy,oz,dx,dy,dz`, and the outputs of every command.
//!
//! Input: the header must be exactly the expected names (spaces around names and values are
//! ignored); every data line must have one finite number per column. Output keeps input order, one
//! row per input row, `NaN` in every column of a row without an answer.
//!
//! Two ways to use them, with the same parser, the same errors and the same number format:
//! - whole tables in memory: [`read_table`], [`write_table`];
//! - streaming in bounded memory, for inputs larger than memory: [`TableReader`] hands out rows
//!   chunk by chunk, [`TableWriter`] takes them chunk by chunk and puts a file in place only when
//!   [`TableWriter::finish`] succeeds, and [`validate_table`] checks a whole input without keeping
//!   it (to report malformed input before anything reaches standard output).

use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};

use crate::io::error::{EXCERPT_CHARS, head, quoted};
use crate::io::{IoError, OutputFile};

/// Buffer size of the readers and writers opened here: large enough that system calls cost
/// nothing next to parsing and formatting.
const BUFFER_BYTES: usize = 1 << 16;

/// Reads a CSV file (`-` = standard input) whose header row must be exactly `header` (after
/// trimming spaces around names). Returns one row of N numbers per data line, in file order.
///
/// Spaces around values are allowed; blank lines are skipped. Errors name the file, the 1-based
/// line and the column: a missing or different header, a line with another number of values, a
/// value that is not a number or not finite (NaN and infinities are not valid input).
///
/// This holds the whole table in memory; [`TableReader`] reads the same files chunk by chunk.
pub fn read_table<const N: usize>(
    path: &Path,
    header: [&str; N],
) -> Result<Vec<[f64; N]>, IoError> {
    TableReader::open(path, header)?.read_to_end()
}

/// [`read_table`] from any reader (standard input, a byte slice in tests); `path` labels errors.
pub fn read_table_from<R: Read, const N: usize>(
    reader: R,
    path: &Path,
    header: [&str; N],
) -> Result<Vec<[f64; N]>, IoError> {
    TableReader::from_reader(BufReader::new(reader), path, header)?.read_to_end()
}

/// Parses a whole CSV file (`-` = standard input) as [`read_table`] does, with the same errors,
/// keeping nothing: returns the number of data rows.
///
/// For a command that writes to standard output, which cannot be taken back: validating first
/// keeps the contract that malformed input writes nothing, and the count sizes a progress report.
/// Standard input can be read only once, so it cannot be validated and then read again.
pub fn validate_table<const N: usize>(path: &Path, header: [&str; N]) -> Result<u64, IoError> {
    let mut reader = TableReader::open(path, header)?;
    while reader.next_row()?.is_some() {}
    Ok(reader.rows_read())
}

/// The byte source of a [`TableReader`] opened by path: a buffered file or standard input.
pub type TableSource = Box<dyn BufRead + Send>;

/// Reads a CSV table chunk by chunk in bounded memory: the streaming form of [`read_table`], with
/// the same header check, parsing and errors (file, 1-based line, column).
///
/// ```no_run
/// # fn main() -> Result<(), flatport::io::IoError> {
/// use flatport::io::TableReader;
/// let mut points = TableReader::open("points.csv".as_ref(), ["x", "y", "z"])?;
/// let mut chunk = Vec::new();
/// while points.next_chunk(1 << 16, &mut chunk)? > 0 {
///     // … process `chunk` (at most 65 536 rows) …
/// }
/// # Ok(()) }
/// ```
pub struct TableReader<const N: usize, R = TableSource> {
    lines: Lines<R>,
    /// Data rows returned so far.
    rows: u64,
    /// Labels errors (`-` for standard input).
    path: PathBuf,
    header: [String; N],
    /// The header names joined by commas, for messages.
    expected: String,
}

impl<const N: usize> TableReader<N> {
    /// Opens a CSV file (`-` = standard input) and checks its header row, which must be exactly
    /// `header` after trimming spaces around names (a UTF-8 byte-order mark is ignored).
    ///
    /// Errors: [`IoError::Read`] when the file cannot be opened or read; [`IoError::Csv`] when the
    /// file is empty (line 1) or its header differs (its line, the first differing column by
    /// number).
    pub fn open(path: &Path, header: [&str; N]) -> Result<Self, IoError> {
        let source: TableSource = if path.as_os_str() == "-" {
            // `Stdin` rather than its lock, so the reader can move to another thread.
            Box::new(BufReader::with_capacity(BUFFER_BYTES, std::io::stdin()))
        } else {
            let file = File::open(path).map_err(|source| IoError::Read {
                path: path.to_path_buf(),
                source,
            })?;
            Box::new(BufReader::with_capacity(BUFFER_BYTES, file))
        };
        TableReader::from_reader(source, path, header)
    }
}

impl<const N: usize, R: BufRead> TableReader<N, R> {
    /// [`TableReader::open`] over any buffered reader (a byte slice in tests); `path` labels
    /// errors. Reads up to and including the header line.
    pub fn from_reader(reader: R, path: &Path, header: [&str; N]) -> Result<Self, IoError> {
        let mut table = TableReader {
            lines: Lines {
                reader,
                buffer: Vec::new(),
                number: 0,
                finished: false,
            },
            rows: 0,
            path: path.to_path_buf(),
            header: header.map(str::to_owned),
            expected: header.join(","),
        };
        table.check_header()?;
        Ok(table)
    }

    /// Clears `rows` and fills it with the next data rows, at most `max_rows` of them (0 is taken
    /// as 1), in file order. Returns how many it read: 0 only at the end of the input.
    ///
    /// Blank lines are skipped; every other line must hold N finite numbers. Errors:
    /// [`IoError::Csv`] naming the file, the 1-based line of the file and the column (its header
    /// name, or the number of the first extra value) for a line with another number of values, a
    /// value that is not a number or not finite, or text that is not UTF-8; [`IoError::Read`] when
    /// reading fails. After an error `rows` holds the good rows before the bad line; stop reading
    /// there (a further call would go on after the bad line).
    pub fn next_chunk(
        &mut self,
        max_rows: usize,
        rows: &mut Vec<[f64; N]>,
    ) -> Result<usize, IoError> {
        rows.clear();
        let max_rows = max_rows.max(1);
        rows.reserve(max_rows.min(BUFFER_BYTES));
        while rows.len() < max_rows {
            match self.next_row()? {
                Some(row) => rows.push(row),
                None => break,
            }
        }
        Ok(rows.len())
    }

    /// The next data row, `None` at the end of the input; the errors of
    /// [`next_chunk`](Self::next_chunk).
    pub fn next_row(&mut self) -> Result<Option<[f64; N]>, IoError> {
        loop {
            let Some((line, text)) = self.lines.next_line(&self.path, &self.header)? else {
                return Ok(None);
            };
            if text.trim().is_empty() {
                continue;
            }
            let row = parse_row(text, line, &self.path, &self.header, &self.expected)?;
            self.rows += 1;
            return Ok(Some(row));
        }
    }

    /// Data rows returned so far.
    pub fn rows_read(&self) -> u64 {
        self.rows
    }

    /// 1-based number of the last line read (the header and blank lines count).
    pub fn line(&self) -> usize {
        self.lines.number
    }

    /// All remaining rows.
    fn read_to_end(mut self) -> Result<Vec<[f64; N]>, IoError> {
        let mut rows = Vec::new();
        while let Some(row) = self.next_row()? {
            rows.push(row);
        }
        Ok(rows)
    }

    /// Reads the first line that is not blank and checks it against the expected header.
    fn check_header(&mut self) -> Result<(), IoError> {
        let found = loop {
            match self.lines.next_line(&self.path, &self.header)? {
                None => {
                    return Err(csv_error(
                        &self.path,
                        1,
                        "1".into(),
                        format!("file is empty; expected the header '{}'", self.expected),
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
        if found == self.expected {
            return Ok(());
        }
        let found: Vec<&str> = found.split(',').collect();
        let column = (0..N.max(found.len()))
            .find(|&i| found.get(i).copied() != self.header.get(i).map(String::as_str))
            .unwrap_or(0)
            + 1;
        // A header of millions of columns is shown by its start and its size.
        let joined = found.join(",");
        let shown = match head(&joined, HEADER_CHARS) {
            None => format!("'{joined}'"),
            Some(start) => format!(
                "'{start}…' ({} columns, {} bytes)",
                found.len(),
                joined.len()
            ),
        };
        Err(csv_error(
            &self.path,
            self.lines.number,
            column.to_string(),
            format!("header is {shown}, expected '{}'", self.expected),
        ))
    }
}

/// Lines of a reader, counted from 1, with `\n` or `\r\n` ends removed.
struct Lines<R> {
    reader: R,
    /// The bytes of the line last read, reused for every line.
    buffer: Vec<u8>,
    /// 1-based number of the line last read.
    number: usize,
    /// The end of the input was reached.
    finished: bool,
}

impl<R: BufRead> Lines<R> {
    /// The next line and its number, `None` at the end; `path` and `header` label errors.
    fn next_line(
        &mut self,
        path: &Path,
        header: &[String],
    ) -> Result<Option<(usize, &str)>, IoError> {
        if self.finished {
            return Ok(None);
        }
        self.buffer.clear();
        let read = self
            .reader
            .read_until(b'\n', &mut self.buffer)
            .map_err(|source| IoError::Read {
                path: path.to_path_buf(),
                source,
            })?;
        if read == 0 {
            self.finished = true;
            return Ok(None);
        }
        self.number += 1;
        let mut bytes = &self.buffer[..];
        bytes = bytes.strip_suffix(b"\n").unwrap_or(bytes);
        bytes = bytes.strip_suffix(b"\r").unwrap_or(bytes);
        match std::str::from_utf8(bytes) {
            Ok(text) => Ok(Some((self.number, text))),
            Err(e) => {
                let index = bytes[..e.valid_up_to()]
                    .iter()
                    .filter(|&&b| b == b',')
                    .count();
                Err(csv_error(
                    path,
                    self.number,
                    column_name(header, index),
                    "not valid UTF-8 text".into(),
                ))
            }
        }
    }
}

impl<const N: usize, R> std::fmt::Debug for TableReader<N, R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TableReader")
            .field("path", &self.path)
            .field("header", &self.expected)
            .field("line", &self.lines.number)
            .field("rows", &self.rows)
            .finish_non_exhaustive()
    }
}

/// One data line (not blank) as N finite numbers; `line` and `path` label errors.
///
/// The tables hold numbers only, so lines are split here rather than through the `csv` crate,
/// whose record positions are off after blank lines (BurntSushi/rust-csv#208).
fn parse_row<const N: usize>(
    text: &str,
    line: usize,
    path: &Path,
    header: &[String; N],
    expected: &str,
) -> Result<[f64; N], IoError> {
    let mut row = [0.0; N];
    let mut count = 0;
    for value in text.split(',').map(field) {
        if let (Some(slot), Some(name)) = (row.get_mut(count), header.get(count)) {
            let number: f64 = value.parse().map_err(|_| {
                csv_error(
                    path,
                    line,
                    name.clone(),
                    format!("not a number: {}", shown(value)),
                )
            })?;
            if !number.is_finite() {
                return Err(csv_error(
                    path,
                    line,
                    name.clone(),
                    format!("must be a finite number, got {}", shown(value)),
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
            .map_or_else(|| (N + 1).to_string(), String::clone);
        return Err(csv_error(
            path,
            line,
            column,
            format!("line has {count} values, expected {N} ({expected})"),
        ));
    }
    Ok(row)
}

/// The header name of the 0-based column `index`, or its 1-based number past the header.
fn column_name(header: &[String], index: usize) -> String {
    header
        .get(index)
        .map_or_else(|| (index + 1).to_string(), String::clone)
}

/// Longest cell text echoed in an error, in characters.
const SHOWN_CHARS: usize = 40;

/// Longest header text echoed in an error, in characters.
const HEADER_CHARS: usize = EXCERPT_CHARS;

/// A cell's text for an error message, quoted: whole up to [`SHOWN_CHARS`] characters, else its
/// start and its length (a 300 MB cell must not be copied into the message).
fn shown(value: &str) -> String {
    quoted(value, '"', SHOWN_CHARS)
}

fn csv_error(path: &Path, line: usize, column: String, reason: String) -> IoError {
    IoError::Csv {
        path: path.to_path_buf(),
        line,
        column,
        reason,
    }
}

/// A value without the spaces around it and without enclosing double quotes.
fn field(text: &str) -> &str {
    let text = text.trim();
    text.strip_prefix('"')
        .and_then(|t| t.strip_suffix('"'))
        .unwrap_or(text)
}

/// What [`write_table`] or [`TableWriter`] wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TableWriteSummary {
    /// Data rows written.
    pub rows: usize,
    /// Rows written as NaN (no answer).
    pub nan_rows: usize,
}

/// Writes the header and one line per row, `None` as `NaN` in every column, to `path` atomically
/// (a temporary file renamed into place, as [`write_atomic`](crate::io::write_atomic) does), or to
/// standard output when `path` is `None` or `-`. Numbers are written with Rust's `{}` for f64: the
/// shortest text that reads back to the same f64.
///
/// Errors: [`IoError::Write`] naming `path` (or `-`); a failed write to a file leaves neither
/// `path` changed nor a temporary file. The rows are written as they come: [`TableWriter`] does
/// the same chunk by chunk.
pub fn write_table<const M: usize>(
    path: Option<&Path>,
    header: [&str; M],
    rows: impl IntoIterator<Item = Option<[f64; M]>>,
) -> Result<TableWriteSummary, IoError> {
    let mut writer = TableWriter::create(path, header)?;
    writer.write_rows(rows)?;
    writer.finish()
}

/// Writes a CSV table chunk by chunk in bounded memory: the streaming form of [`write_table`],
/// with the same bytes for the same rows.
///
/// The lines go through an [`OutputFile`]: to a regular file (or a new path, or a link to one)
/// through a temporary file beside it, which [`finish`](Self::finish) flushes to disk and renames
/// onto the target; until then the target is untouched, and a writer dropped without `finish` (an
/// error, a panic, an interrupted command) removes its temporary file. To standard output, a device
/// node or a FIFO the lines go out as they come and cannot be taken back
/// ([`streams`](Self::streams)).
///
/// ```no_run
/// # fn main() -> Result<(), flatport::io::IoError> {
/// use flatport::io::TableWriter;
/// let mut pixels = TableWriter::create(Some("pixels.csv".as_ref()), ["u", "v"])?;
/// pixels.write_rows([Some([320.5, 240.25]), None])?;
/// let summary = pixels.finish()?; // pixels.csv appears here, whole
/// assert_eq!((summary.rows, summary.nan_rows), (2, 1));
/// # Ok(()) }
/// ```
#[derive(Debug)]
pub struct TableWriter<const M: usize> {
    output: OutputFile,
    /// The header row, written before the first data row (or at `finish` for an empty table).
    header: Option<String>,
    /// The text of the row being written, reused for every row.
    line: String,
    /// `NaN,…,NaN\n`.
    nan_line: String,
    summary: TableWriteSummary,
}

impl<const M: usize> TableWriter<M> {
    /// Starts a table with the header row `header` into `output` (standard output when `None` or
    /// `-`; see [`OutputFile`] for files, links, devices and FIFOs). Nothing reaches a streamed
    /// output before the first [`write_rows`](Self::write_rows) or [`finish`](Self::finish).
    ///
    /// Errors: [`IoError::Write`] naming `output` when it cannot be opened (a missing folder, no
    /// permission, a folder).
    pub fn create(output: Option<&Path>, header: [&str; M]) -> Result<Self, IoError> {
        let output = OutputFile::create(output)?;
        let mut nan_line = vec!["NaN"; M].join(",");
        nan_line.push('\n');
        let mut header = header.join(",");
        header.push('\n');
        Ok(TableWriter {
            output,
            header: Some(header),
            line: String::new(),
            nan_line,
            summary: TableWriteSummary {
                rows: 0,
                nan_rows: 0,
            },
        })
    }

    /// Whether written rows reach the destination at once (standard output, a device, a FIFO)
    /// rather than at [`finish`](Self::finish): see [`OutputFile::streams`].
    pub fn streams(&self) -> bool {
        self.output.streams()
    }

    /// Appends one line per row, in order: the numbers of `Some` with Rust's `{}` for f64 (the
    /// shortest text that reads back to the same f64), `NaN` in every column for `None`.
    ///
    /// Errors: [`IoError::Write`] naming the output (`-` for standard output) when writing fails.
    pub fn write_rows(
        &mut self,
        rows: impl IntoIterator<Item = Option<[f64; M]>>,
    ) -> Result<(), IoError> {
        self.write_header()?;
        let Self {
            output,
            line,
            nan_line,
            summary,
            ..
        } = self;
        write_lines(output, rows, line, nan_line, summary)
            .map_err(|source| self.output.write_error(source))
    }

    /// Rows written so far.
    pub fn summary(&self) -> TableWriteSummary {
        self.summary
    }

    /// Completes the table (see [`OutputFile::finish`]): the target appears whole or not at all.
    /// Returns the rows written.
    ///
    /// Errors: [`IoError::Write`] naming the output when writing, flushing, syncing or renaming
    /// fails (a full device among them); the temporary file is then removed and the target left
    /// as it was.
    pub fn finish(mut self) -> Result<TableWriteSummary, IoError> {
        self.write_header()?;
        self.output.finish()?;
        Ok(self.summary)
    }

    fn write_header(&mut self) -> Result<(), IoError> {
        if let Some(header) = self.header.take() {
            self.output
                .write_all(header.as_bytes())
                .map_err(|source| self.output.write_error(source))?;
        }
        Ok(())
    }
}

/// Writes `rows` to `sink`, one line each, counting them in `summary`; `line` is scratch space.
fn write_lines<W: Write, const M: usize>(
    sink: &mut W,
    rows: impl IntoIterator<Item = Option<[f64; M]>>,
    line: &mut String,
    nan_line: &str,
    summary: &mut TableWriteSummary,
) -> std::io::Result<()> {
    for row in rows {
        summary.rows += 1;
        let text = match row {
            Some(values) => {
                line.clear();
                for (i, v) in values.iter().enumerate() {
                    if i > 0 {
                        line.push(',');
                    }
                    // Display for f64 is the shortest round-trip representation.
                    std::fmt::Write::write_fmt(line, format_args!("{v}"))
                        .expect("writing to a String");
                }
                line.push('\n');
                line.as_str()
            }
            None => {
                summary.nan_rows += 1;
                nan_line
            }
        };
        sink.write_all(text.as_bytes())?;
    }
    Ok(())
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
    fn a_huge_header_is_shown_by_its_start_and_size() {
        // 20 million columns, 40 MB: the message names file, line, column and what is wrong in a
        // few hundred bytes.
        let header = format!("{}x", "x,".repeat(19_999_999));
        let (line, column, m) = failure(&format!("\n{header}\n1,2,3\n"));
        assert_eq!((line, column.as_str()), (2, "2"));
        assert_eq!(
            m,
            format!(
                "p.csv:2: column '2': header is '{}…' (20000000 columns, 39999999 bytes), expected 'x,y,z'",
                "x,".repeat(30)
            )
        );
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
        // A huge cell is shown by its start and length, not copied whole into the message.
        let cell = "z".repeat(1 << 20);
        let (_, column, m) = failure(&format!("x,y,z\n1,{cell},3\n"));
        assert_eq!(column, "y");
        assert!(
            m.len() < 200
                && m.ends_with(&format!(
                    "not a number: \"{}…\" (1048576 bytes)",
                    "z".repeat(40)
                )),
            "{}",
            &m[..m.len().min(300)]
        );
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
