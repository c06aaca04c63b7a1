//! Import of OpenCV `stereoCalibrate` results saved with `cv::FileStorage` as YAML
//! (`%YAML:1.0`, `!!opencv-matrix` entries).
//!
//! The text is parsed by `saphyr-parser`, a YAML 1.2 event parser, after every `%YAML:1.0` line
//! is blanked: that directive (YAML 1.0, written with a colon) is not YAML 1.2, and a parser
//! refuses it before a document without `---` and between two documents without `...`. Blanking
//! keeps every line number. The crate gives tags (`!!opencv-matrix` and its verbatim form
//! `!<tag:yaml.org,2002:opencv-matrix>` alike), the line of every event, and aliases as events
//! (never expanded).
//!
//! Only the top-level keys are interpreted: `key: scalar`, `key: [sequence]` and
//! `key: !!opencv-matrix` mappings (`rows`, `cols`, `dt`, `data`). Everything else (nested
//! mappings, `!!opencv-nd-matrix`, E, F, R1, P1, Q, per-view errors, …) is passed over event by
//! event without being interpreted, so it cannot make the import fail. Several documents in one
//! file (`cat intrinsics.yml extrinsics.yml`) are read as one.
//!
//! Done here because the crate does not: the `%YAML` first line is required (a YAML file of
//! another tool is refused as no FileStorage output); numbers are read from the scalars' text
//! (the crate resolves no schema at the event level; OpenCV writes `1.`, `.5e-3`, `-3.7e-01`,
//! `.Nan`, `.Inf`, all of which Rust's `f64` parser reads, non-finite ones refused by name); a key
//! given twice, also across documents, is an error; and the crate's syntax errors are said in the
//! file's terms where the cause is plain (a `[` never closed, a top-level line without `key:`).

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use saphyr_parser::{Event, Marker, Parser, ScanError, Span, StrInput, Tag};

use crate::io::error::{EXCERPT_CHARS, excerpt};
use crate::io::{IoError, read_text};
use crate::model::{Interface, PinholeCamera, Rig, RigCamera};

/// The two cameras of an OpenCV stereo calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenCvStereo {
    /// Camera matrices K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] of the first (master) and second camera.
    pub camera_matrix: [Matrix3<f64>; 2],
    /// Distortion `[k1, k2, p1, p2, k3]` of both cameras.
    pub distortion: [[f64; 5]; 2],
    /// R: rotation from the first camera's frame to the second's.
    pub rotation: Matrix3<f64>,
    /// T: X₂ = R·X₁ + T, in the unit the calibration board was given in (flatport expects metres).
    pub translation: Vector3<f64>,
    /// Image size (width, height) when the file has one.
    pub image_size: Option<(u32, u32)>,
}

/// A scalar's text and its 1-based line.
#[derive(Debug, Clone)]
struct Scalar {
    text: String,
    line: usize,
}

/// A value of the file, as far as it is read.
#[derive(Debug)]
enum Value {
    Scalar(Scalar),
    /// A sequence of scalars (`[ 1, 2 ]` or a block list).
    Sequence(Vec<Scalar>),
    Matrix(Box<RawMatrix>),
    /// `*name`: a reference to an anchored value (OpenCV writes none; not followed).
    Alias,
    /// Anything else (a mapping, a sequence holding collections, another type tag): not
    /// interpreted.
    Other,
}

/// A field of an `!!opencv-matrix` and the line of its name.
#[derive(Debug)]
struct Field {
    line: usize,
    value: Value,
}

#[derive(Debug, Default)]
struct RawMatrix {
    rows: Option<Field>,
    cols: Option<Field>,
    dt: Option<Field>,
    data: Option<Field>,
}

#[derive(Debug)]
struct Entry {
    /// 1-based line of the key.
    line: usize,
    value: Value,
}

/// Reads and parses an OpenCV FileStorage YAML file (`-` = standard input).
pub fn read_opencv_stereo(path: &Path) -> Result<OpenCvStereo, IoError> {
    parse_opencv_stereo(&read_text(path)?, path)
}

/// The text with every `%YAML:…` directive line emptied (its line end kept, so line numbers stay).
fn without_yaml_directives(text: &str) -> String {
    let mut kept = String::with_capacity(text.len());
    for line in text.split_inclusive('\n') {
        if line.starts_with("%YAML:") {
            kept.push_str(if line.ends_with("\r\n") { "\r\n" } else { "\n" });
        } else {
            kept.push_str(line);
        }
    }
    kept
}

/// Whether `tag` is OpenCV's matrix tag, `!!opencv-matrix` (`tag:yaml.org,2002:opencv-matrix`).
fn is_opencv_matrix(tag: &Tag) -> bool {
    tag.handle == "tag:yaml.org,2002:" && tag.suffix == "opencv-matrix"
        || tag.handle.is_empty() && tag.suffix == "tag:yaml.org,2002:opencv-matrix"
}

/// The byte offset of character `index` of `text` (its length past the end).
fn byte_offset(text: &str, index: usize) -> usize {
    text.char_indices()
        .nth(index)
        .map_or(text.len(), |(b, _)| b)
}

/// The events of one file, read into top-level entries, with what is needed to say where a
/// syntax error is in the file's terms.
struct Reader<'t> {
    events: Parser<'t, StrInput<'t>>,
    text: &'t str,
    path: &'t Path,
    /// The top-level key whose value is being read, and its line.
    key: Option<String>,
    key_line: usize,
    /// Where each collection still open starts, innermost last.
    open: Vec<Marker>,
    /// Where the last event ended.
    last_end: Marker,
}

impl<'t> Reader<'t> {
    fn new(text: &'t str, path: &'t Path) -> Self {
        Self {
            events: Parser::new_from_str(text),
            text,
            path,
            key: None,
            key_line: 0,
            open: Vec::new(),
            last_end: Marker::new(0, 1, 0),
        }
    }

    fn error(&self, line: usize, reason: String) -> IoError {
        IoError::OpenCv {
            path: self.path.to_path_buf(),
            line,
            reason,
        }
    }

    /// The next event; a syntax error is located and explained.
    fn next(&mut self) -> Result<(Event<'t>, Span), IoError> {
        match self.events.next_event() {
            Some(Ok((event, span))) => {
                match event {
                    Event::SequenceStart(..) | Event::MappingStart(..) => {
                        self.open.push(span.start)
                    }
                    Event::SequenceEnd | Event::MappingEnd => {
                        self.open.pop();
                    }
                    _ => {}
                }
                self.last_end = span.end;
                Ok((event, span))
            }
            Some(Err(e)) => Err(self.syntax_error(&e)),
            // The parser ends with StreamEnd, after which nothing is asked.
            None => Err(self.error(self.last_end.line(), "unexpected end of the YAML".into())),
        }
    }

    /// A parser error said in the file's terms where the cause is plain: a `[` (or `{`) still
    /// open where the file ends or a later line goes on, a top-level line that is no `key: value`.
    fn syntax_error(&self, e: &ScanError) -> IoError {
        let (info, at) = (e.info(), e.marker());
        let key = self.key.as_deref().map(|k| excerpt(k, EXCERPT_CHARS));
        let innermost = self.open.last();
        let flow = innermost
            .and_then(|m| {
                self.text[byte_offset(self.text, m.index())..]
                    .chars()
                    .next()
            })
            .filter(|c| matches!(c, '[' | '{'));
        if let (Some(open), Some(start), Some(key)) = (flow, innermost, &key) {
            let close = if open == '[' { ']' } else { '}' };
            if at.index() >= self.text.chars().count() {
                return self.error(
                    start.line(),
                    format!("{key}: '{open}' is never closed with '{close}'"),
                );
            }
            if at.line() > start.line() {
                return self.error(
                    at.line(),
                    format!(
                        "{key}: '{open}' is never closed with '{close}' before this line (YAML: {info})"
                    ),
                );
            }
        }
        let text = self
            .text
            .split('\n')
            .nth(at.line().saturating_sub(1))
            .unwrap_or_default()
            .trim_end_matches('\r');
        // YAML 1.2 keeps a key written without '?' to 1024 characters.
        if let Some((name, _)) = text.trim_start().split_once(':')
            && name.chars().count() > 1024
        {
            return self.error(
                at.line(),
                format!(
                    "key '{}' is longer than YAML allows a plain key (1024 characters)",
                    excerpt(name.trim(), EXCERPT_CHARS)
                ),
            );
        }
        if key.is_none() && self.open.len() <= 1 {
            // Between two top-level entries: the first line after the last one read that holds
            // no `key:` is the culprit.
            let from = byte_offset(self.text, self.last_end.index());
            let to = byte_offset(self.text, at.index()).max(from);
            let found = self.text[from..to]
                .split('\n')
                .enumerate()
                .map(|(i, l)| (self.last_end.line() + i, l.trim()))
                .find(|(_, l)| !l.is_empty() && !l.starts_with('#'));
            if let Some((line, found)) = found
                && !found.contains(':')
            {
                return self.error(
                    line,
                    format!(
                        "expected 'key: value' at the top level, found '{}'",
                        excerpt(found, EXCERPT_CHARS)
                    ),
                );
            }
        }
        // The key names the value being read unless the line is a top-level line of its own
        // (a value's lines are indented).
        let prefix = match key {
            Some(k)
                if at.line() == self.key_line
                    || !text.starts_with(|c: char| !c.is_whitespace()) =>
            {
                format!("{k}: ")
            }
            _ => String::new(),
        };
        let shown = match text.trim() {
            "" => String::new(),
            t => format!("; the line reads '{}'", excerpt(t, EXCERPT_CHARS)),
        };
        self.error(at.line(), format!("{prefix}not valid YAML: {info}{shown}"))
    }

    /// Every top-level entry of every document.
    fn entries(mut self) -> Result<HashMap<String, Entry>, IoError> {
        let mut entries = HashMap::new();
        loop {
            let (event, span) = self.next()?;
            let found = match event {
                Event::StreamStart | Event::DocumentStart(_) | Event::DocumentEnd => continue,
                Event::StreamEnd => return Ok(entries),
                Event::MappingStart(..) if self.open.len() == 1 => {
                    self.mapping(&mut entries)?;
                    continue;
                }
                // An empty document.
                Event::Scalar(text, ..) if text.trim().is_empty() => continue,
                Event::Scalar(text, ..) => {
                    // A key too long for YAML comes as a scalar document, then the parser's
                    // complaint about its ':': that complaint says more.
                    self.next()?;
                    format!("'{}'", excerpt(&text, EXCERPT_CHARS))
                }
                Event::SequenceStart(..) => "a sequence".into(),
                _ => "something else".into(),
            };
            return Err(self.error(
                span.start.line(),
                format!("expected 'key: value' at the top level, found {found}"),
            ));
        }
    }

    /// The entries of a document's top-level mapping, whose start was just read.
    fn mapping(&mut self, entries: &mut HashMap<String, Entry>) -> Result<(), IoError> {
        loop {
            let (event, span) = self.next()?;
            let key = match event {
                Event::MappingEnd => return Ok(()),
                Event::Scalar(text, ..) => text.into_owned(),
                // A collection or an alias as key: no name flatport reads; passed over.
                Event::SequenceStart(..) | Event::MappingStart(..) => {
                    self.skip_rest()?;
                    self.value(false)?;
                    continue;
                }
                _ => {
                    self.value(false)?;
                    continue;
                }
            };
            self.key = Some(key);
            self.key_line = span.start.line();
            let value = self.value(true)?;
            let key = self.key.take().unwrap_or_default();
            insert(
                entries,
                key,
                Entry {
                    line: span.start.line(),
                    value,
                },
                self.path,
            )?;
        }
    }

    /// The value that comes next; an `!!opencv-matrix` is read as one when `matrices`.
    fn value(&mut self, matrices: bool) -> Result<Value, IoError> {
        let (event, span) = self.next()?;
        Ok(match event {
            Event::Scalar(text, ..) => Value::Scalar(Scalar {
                text: text.into_owned(),
                line: span.start.line(),
            }),
            Event::Alias(_) => Value::Alias,
            Event::SequenceStart(..) => self.sequence()?,
            Event::MappingStart(_, Some(tag)) if matrices && is_opencv_matrix(&tag) => {
                Value::Matrix(Box::new(self.matrix_fields()?))
            }
            Event::MappingStart(..) => {
                self.skip_rest()?;
                Value::Other
            }
            _ => Value::Other,
        })
    }

    /// The rest of a sequence whose start was just read: its scalars, or `Other` when it holds
    /// anything else.
    fn sequence(&mut self) -> Result<Value, IoError> {
        let mut items = Vec::new();
        let mut flat = true;
        loop {
            let (event, span) = self.next()?;
            match event {
                Event::SequenceEnd => break,
                Event::Scalar(text, ..) => items.push(Scalar {
                    text: text.into_owned(),
                    line: span.start.line(),
                }),
                Event::SequenceStart(..) | Event::MappingStart(..) => {
                    flat = false;
                    self.skip_rest()?;
                }
                _ => flat = false,
            }
        }
        Ok(if flat {
            Value::Sequence(items)
        } else {
            Value::Other
        })
    }

    /// The fields of an `!!opencv-matrix` mapping whose start was just read.
    fn matrix_fields(&mut self) -> Result<RawMatrix, IoError> {
        let mut matrix = RawMatrix::default();
        loop {
            let (event, span) = self.next()?;
            let name = match event {
                Event::MappingEnd => return Ok(matrix),
                Event::Scalar(text, ..) => text,
                Event::SequenceStart(..) | Event::MappingStart(..) => {
                    self.skip_rest()?;
                    self.value(false)?;
                    continue;
                }
                _ => {
                    self.value(false)?;
                    continue;
                }
            };
            let field = Some(Field {
                line: span.start.line(),
                value: self.value(false)?,
            });
            match &*name {
                "rows" => matrix.rows = field,
                "cols" => matrix.cols = field,
                "dt" => matrix.dt = field,
                "data" => matrix.data = field,
                _ => {}
            }
        }
    }

    /// Passes over the rest of a collection whose start was just read.
    fn skip_rest(&mut self) -> Result<(), IoError> {
        let mut depth = 1usize;
        while depth > 0 {
            match self.next()?.0 {
                Event::SequenceStart(..) | Event::MappingStart(..) => depth += 1,
                Event::SequenceEnd | Event::MappingEnd => depth -= 1,
                _ => {}
            }
        }
        Ok(())
    }
}

fn parse_entries(text: &str, path: &Path) -> Result<HashMap<String, Entry>, IoError> {
    let err = |line: usize, reason: String| IoError::OpenCv {
        path: path.to_path_buf(),
        line,
        reason,
    };
    // A UTF-8 byte order mark before %YAML carries no meaning: skip it, as the CSV reader does.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let first = text.lines().enumerate().find(|(_, l)| {
        let l = l.trim();
        !l.is_empty() && !l.starts_with('#')
    });
    match first {
        Some((_, l)) if l.trim_start().starts_with("%YAML") => {}
        Some((n, _)) => {
            return Err(err(
                n + 1,
                "not an OpenCV FileStorage YAML file: it must start with %YAML:1.0".into(),
            ));
        }
        None => {
            return Err(err(
                0,
                "file is empty: expected an OpenCV FileStorage YAML file (%YAML:1.0)".into(),
            ));
        }
    }
    let text = without_yaml_directives(text);
    Reader::new(&text, path).entries()
}

fn insert(
    entries: &mut HashMap<String, Entry>,
    key: String,
    entry: Entry,
    path: &Path,
) -> Result<(), IoError> {
    if let Some(first) = entries.get(&key) {
        return Err(IoError::OpenCv {
            path: path.to_path_buf(),
            line: entry.line,
            reason: format!(
                "key {} appears twice (first on line {})",
                excerpt(&key, EXCERPT_CHARS),
                first.line
            ),
        });
    }
    entries.insert(key, entry);
    Ok(())
}

/// The finite numbers of a sequence; errors name the line of the bad value.
fn numbers(key: &str, items: &[Scalar], path: &Path) -> Result<Vec<f64>, IoError> {
    items
        .iter()
        .map(|Scalar { text, line }| {
            let err = |reason: String| IoError::OpenCv {
                path: path.to_path_buf(),
                line: *line,
                reason,
            };
            let s = text.trim();
            // OpenCV writes non-finite values as .Nan, .Inf, -.Inf.
            let word = s.trim_start_matches(['+', '-', '.']).to_ascii_lowercase();
            if word == "nan" || word == "inf" || word == "infinity" {
                return Err(err(format!("{key}: '{s}' is not finite")));
            }
            s.parse().map_err(|_| {
                err(format!(
                    "{key}: '{}' is not a number",
                    excerpt(s, EXCERPT_CHARS)
                ))
            })
        })
        .collect()
}

/// A used `!!opencv-matrix`: its shape (rows, cols) and values (row-major), checked.
fn matrix(key: &str, entry: &Entry, path: &Path) -> Result<(usize, usize, Vec<f64>), IoError> {
    let err = |line: usize, reason: String| IoError::OpenCv {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let m = match &entry.value {
        Value::Matrix(m) => m,
        Value::Alias => {
            return Err(err(
                entry.line,
                format!(
                    "{key} is a YAML alias (*name), which is not followed: write the !!opencv-matrix itself"
                ),
            ));
        }
        _ => return Err(err(entry.line, format!("{key} is not an !!opencv-matrix"))),
    };
    let count = |field: &Option<Field>, name: &str| match field {
        None => Err(err(
            entry.line,
            format!("{key}: !!opencv-matrix without '{name}'"),
        )),
        Some(Field {
            value: Value::Scalar(Scalar { text, line }),
            ..
        }) => text.parse::<usize>().map_err(|_| {
            err(
                *line,
                format!(
                    "{key}: {name} '{}' is not a count",
                    excerpt(text, EXCERPT_CHARS)
                ),
            )
        }),
        Some(Field { line, .. }) => Err(err(*line, format!("{key}: {name} is not a count"))),
    };
    let (rows, cols) = (count(&m.rows, "rows")?, count(&m.cols, "cols")?);
    match &m.dt {
        Some(Field {
            value: Value::Scalar(Scalar { text, .. }),
            ..
        }) if text == "d" || text == "f" => {}
        Some(Field { line, value }) => {
            let dt = match value {
                Value::Scalar(Scalar { text, .. }) => format!("'{}'", excerpt(text, EXCERPT_CHARS)),
                _ => "(not a scalar)".into(),
            };
            return Err(err(
                *line,
                format!("{key}: element type dt {dt} (expected d or f)"),
            ));
        }
        None => {
            return Err(err(
                entry.line,
                format!("{key}: !!opencv-matrix without 'dt'"),
            ));
        }
    }
    let values = match &m.data {
        None => {
            return Err(err(
                entry.line,
                format!("{key}: !!opencv-matrix without 'data'"),
            ));
        }
        Some(Field {
            value: Value::Sequence(items),
            ..
        }) => numbers(key, items, path)?,
        Some(Field { line, .. }) => {
            return Err(err(
                *line,
                format!("{key}: data must be a sequence of numbers [ … ]"),
            ));
        }
    };
    if rows.checked_mul(cols) != Some(values.len()) {
        return Err(err(
            entry.line,
            format!("{key}: {rows}x{cols} matrix with {} values", values.len()),
        ));
    }
    Ok((rows, cols, values))
}

/// A positive whole number of pixels.
fn pixels(value: f64) -> Option<u32> {
    (value >= 1.0 && value.fract() == 0.0 && value <= f64::from(u32::MAX)).then_some(value as u32)
}

/// Parses the text of an OpenCV FileStorage YAML file; `path` labels errors.
///
/// Keys: `M1 D1 M2 D2 R T`, or `K1`/`K2` for `M1`/`M2`, or `cameraMatrix1 distCoeffs1
/// cameraMatrix2 distCoeffs2`; matrices must have `dt` d or f. Image size from `image_width` +
/// `image_height`, or `imageSize` (`[w, h]` or a 2-element matrix), else `None`. Distortion may
/// have 4, 5, 8, 12 or 14 coefficients in OpenCV order; coefficients past the fifth must be zero
/// (flatport models `[k1, k2, p1, p2, k3]`). K must have zero skew.
pub fn parse_opencv_stereo(text: &str, path: &Path) -> Result<OpenCvStereo, IoError> {
    let entries = parse_entries(text, path)?;
    let err = |line: usize, reason: String| IoError::OpenCv {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let find = |names: &[&'static str]| -> Result<(&'static str, &Entry), IoError> {
        names
            .iter()
            .find_map(|n| entries.get(*n).map(|e| (*n, e)))
            .ok_or_else(|| err(0, format!("missing key {}", names.join(" or "))))
    };
    let shaped = |names: &[&'static str], rows: usize, cols: usize| -> Result<Vec<f64>, IoError> {
        let (name, entry) = find(names)?;
        let (r, c, values) = matrix(name, entry, path)?;
        // A vector may be stored as a row or a column.
        if (r, c) == (rows, cols) || (cols == 1 && (r, c) == (1, rows)) {
            Ok(values)
        } else {
            Err(err(
                entry.line,
                format!("{name} is {r}x{c}, expected {rows}x{cols}"),
            ))
        }
    };
    let distortion = |names: &[&'static str]| -> Result<[f64; 5], IoError> {
        let (name, entry) = find(names)?;
        let (r, c, values) = matrix(name, entry, path)?;
        if r.min(c) != 1 || ![4, 5, 8, 12, 14].contains(&values.len()) {
            return Err(err(
                entry.line,
                format!(
                    "{name} is {r}x{c}; OpenCV distortion has 4, 5, 8, 12 or 14 coefficients in one row or column"
                ),
            ));
        }
        if let Some(i) = values.iter().skip(5).position(|&k| k != 0.0) {
            return Err(err(
                entry.line,
                format!(
                    "{name}: coefficient {} is {} but flatport supports only the 5-term model [k1, k2, p1, p2, k3]",
                    i + 6,
                    values[i + 5]
                ),
            ));
        }
        let mut d = [0.0; 5];
        for (slot, k) in d.iter_mut().zip(values) {
            *slot = k;
        }
        Ok(d)
    };
    let camera_matrix = |names: &[&'static str]| -> Result<Matrix3<f64>, IoError> {
        let k = Matrix3::from_row_slice(&shaped(names, 3, 3)?);
        let (name, entry) = find(names)?;
        if k[(0, 1)] != 0.0 {
            return Err(err(
                entry.line,
                format!(
                    "{name}: skew K[0][1] = {} is not supported (must be 0)",
                    k[(0, 1)]
                ),
            ));
        }
        if k[(1, 0)] != 0.0 || k[(2, 0)] != 0.0 || k[(2, 1)] != 0.0 || k[(2, 2)] != 1.0 {
            return Err(err(
                entry.line,
                format!("{name}: not a camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"),
            ));
        }
        Ok(k)
    };
    Ok(OpenCvStereo {
        camera_matrix: [
            camera_matrix(&["M1", "K1", "cameraMatrix1"])?,
            camera_matrix(&["M2", "K2", "cameraMatrix2"])?,
        ],
        distortion: [
            distortion(&["D1", "distCoeffs1"])?,
            distortion(&["D2", "distCoeffs2"])?,
        ],
        rotation: Matrix3::from_row_slice(&shaped(&["R"], 3, 3)?),
        translation: Vector3::from_column_slice(&shaped(&["T"], 3, 1)?),
        image_size: image_size(&entries, path)?,
    })
}

/// `image_width` + `image_height`, or `imageSize`, or none.
fn image_size(
    entries: &HashMap<String, Entry>,
    path: &Path,
) -> Result<Option<(u32, u32)>, IoError> {
    let err = |line: usize, reason: String| IoError::OpenCv {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let scalar = |name: &str, entry: &Entry| {
        match &entry.value {
            Value::Scalar(s) => s.text.trim().parse::<f64>().ok().and_then(pixels),
            _ => None,
        }
        .ok_or_else(|| {
            err(
                entry.line,
                format!("{name} must be a positive whole number of pixels"),
            )
        })
    };
    match (
        entries.get("image_width"),
        entries.get("image_height"),
        entries.get("imageSize"),
    ) {
        (Some(w), Some(h), _) => Ok(Some((
            scalar("image_width", w)?,
            scalar("image_height", h)?,
        ))),
        (Some(e), None, _) | (None, Some(e), _) => Err(err(
            e.line,
            "image_width and image_height must be given together".into(),
        )),
        (None, None, Some(entry)) => {
            let values = match &entry.value {
                Value::Sequence(items) => numbers("imageSize", items, path)?,
                Value::Matrix(_) => matrix("imageSize", entry, path)?.2,
                _ => vec![],
            };
            match values[..] {
                [w, h] => match (pixels(w), pixels(h)) {
                    (Some(w), Some(h)) => Ok(Some((w, h))),
                    _ => Err(err(
                        entry.line,
                        format!("imageSize [{w}, {h}] is not a positive whole number of pixels"),
                    )),
                },
                _ => Err(err(entry.line, "imageSize must be [width, height]".into())),
            }
        }
        (None, None, None) => Ok(None),
    }
}

/// Longest baseline |T| read as metres without a word: a stereo rig more than 2 m wide is rare,
/// and a T of that length is far more often millimetres (OpenCV keeps the unit of the board's
/// square size, and many give it in mm).
pub const MAX_BASELINE_M: f64 = 2.0;

impl OpenCvStereo {
    /// The same calibration with every length it holds (T; the camera matrices and distortion
    /// are in pixels and unitless) read as millimetres and given in metres.
    pub fn scaled_from_millimetres(mut self) -> Self {
        self.translation /= 1000.0;
        self
    }

    /// A rig with cameras `names[0]` (the master, identity extrinsics) and `names[1]` (R, T) behind
    /// `interface`. `image_size` (width, height) overrides the file's; one of them must be given.
    /// `path` labels errors.
    pub fn to_rig(
        &self,
        names: [&str; 2],
        image_size: Option<(u32, u32)>,
        interface: Interface,
        path: &Path,
    ) -> Result<Rig, IoError> {
        let invalid = |field: String, reason: String| IoError::Invalid {
            path: path.to_path_buf(),
            field,
            reason,
        };
        let (width, height) = image_size.or(self.image_size).ok_or_else(|| {
            invalid(
                "image size".into(),
                "the file has no image_width/image_height or imageSize; give --size WIDTHxHEIGHT"
                    .into(),
            )
        })?;
        let mut cameras = Vec::with_capacity(2);
        for (i, name) in names.iter().enumerate() {
            let k = &self.camera_matrix[i];
            let field = format!("camera {} ('{name}')", i + 1);
            let intrinsics = PinholeCamera::new(
                name,
                width,
                height,
                k[(0, 0)],
                k[(1, 1)],
                k[(0, 2)],
                k[(1, 2)],
                self.distortion[i],
            )
            .map_err(|e| invalid(field.clone(), e.to_string()))?;
            let (rotation, translation) = if i == 0 {
                (Matrix3::identity(), Vector3::zeros())
            } else {
                (self.rotation, self.translation)
            };
            let camera = RigCamera::new(name, intrinsics, rotation, translation)
                .map_err(|e| invalid(format!("{field} R, T"), e.to_string()))?;
            cameras.push(camera);
        }
        Rig::new(cameras, interface).map_err(|e| invalid("rig".into(), e.to_string()))
    }
}

#[cfg(test)]
// The expected values are written as OpenCV writes them (17 significant digits).
#[allow(clippy::excessive_precision)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    /// What `cv::FileStorage` writes for a stereo calibration, with the extras calibration tools add.
    const STEREO: &str = "%YAML:1.0
---
calibration_time: \"Sun 22 Nov 2026 01:07:57 # not a comment: inside quotes\"
# image size of both cameras
image_width: 1280
image_height: 1024
board_width: 9
flags: 0
M1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 8.6491000000000003e+02, 0., 640., 0., 8.6491000000000003e+02,
       512., 0., 0., 1. ]
D1: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -1.0e-01, 1.0000000000000000e-02, .5e-3, -2.5e-03, 0. ]
M2: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 870., 0., 630., 0., 870., 500., 0., 0., 1. ]
D2: !!opencv-matrix
   rows: 8
   cols: 1
   dt: d
   data: [ -0.09, 0.011, 0., 0., 0., 0., 0.,
       0. ]
R: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 9.9984769515639127e-01, 0., 1.7452406437283512e-02, 0., 1.,
       0., -1.7452406437283512e-02, 0., 9.9984769515639127e-01 ]
T: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ -6.0e-02, 0., 0. ]
E: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ .Nan, 0., 0., 0., 0., 0.06, 0., -0.06, 0. ]
per_view_errors: [ 0.21, 0.19, 0.25,
    0.30, 0.18 ]
image_points: !!opencv-nd-matrix
   sizes: [ 2, 54,
       1 ]
   dt: \"2f\"
   data: [ 1., 2.,
      3., 4. ]
nested:
   inner: [ 1,
      2 ]
";

    fn parse(text: &str) -> Result<OpenCvStereo, IoError> {
        parse_opencv_stereo(text, Path::new("stereo.yml"))
    }

    /// The example with `from` replaced by `to` (which must occur).
    fn edited(from: &str, to: &str) -> String {
        assert!(STEREO.contains(from), "test edit {from:?} does not apply");
        STEREO.replacen(from, to, 1)
    }

    /// (line, message) of an OpenCV error.
    fn failure(text: &str) -> (usize, String) {
        match parse(text) {
            Err(e @ IoError::OpenCv { .. }) => {
                let message = e.to_string();
                let IoError::OpenCv { line, .. } = e else {
                    unreachable!()
                };
                (line, message)
            }
            other => panic!("expected IoError::OpenCv, got {other:?}"),
        }
    }

    fn interface() -> Interface {
        Interface::new(Vector3::new(0.1, 0.1, 1.0), 0.02, vec![], 1.0, 1.333).unwrap()
    }

    #[test]
    fn reads_a_stereo_calibration() {
        let s = parse(STEREO).unwrap();
        // The file's 17-digit text, not the literal 864.91.
        assert_eq!(
            s.camera_matrix[0],
            Matrix3::new(
                8.6491000000000003e+02,
                0.0,
                640.0,
                0.0,
                8.6491000000000003e+02,
                512.0,
                0.0,
                0.0,
                1.0
            )
        );
        assert_eq!(s.camera_matrix[1][(0, 2)], 630.0);
        assert_eq!(s.camera_matrix[1][(1, 2)], 500.0);
        assert_eq!(s.distortion[0], [-0.1, 0.01, 0.0005, -0.0025, 0.0]);
        assert_eq!(s.distortion[1], [-0.09, 0.011, 0.0, 0.0, 0.0]);
        // Row-major data: R[0][2] = +sin 1°.
        assert_eq!(s.rotation[(0, 2)], 1.7452406437283512e-02);
        assert_eq!(s.rotation[(2, 0)], -1.7452406437283512e-02);
        assert_eq!(s.translation, Vector3::new(-0.06, 0.0, 0.0));
        assert_eq!(s.image_size, Some((1280, 1024)));

        let rig = s
            .to_rig(
                ["left", "right"],
                None,
                interface(),
                Path::new("stereo.yml"),
            )
            .unwrap();
        let (left, right) = (&rig.cameras()[0], &rig.cameras()[1]);
        assert_eq!((left.name.as_str(), right.name.as_str()), ("left", "right"));
        assert_eq!(
            (
                right.intrinsics.fx,
                right.intrinsics.cx,
                right.intrinsics.width
            ),
            (870.0, 630.0, 1280)
        );
        assert_eq!(left.intrinsics.distortion, s.distortion[0]);
        // C = −Rᵀ T = 0.06 · Rᵀ x̂ = 0.06 · (first row of R) = 0.06 · (cos 1°, 0, sin 1°).
        let expected = Point3::new(
            0.06 * 9.9984769515639127e-01,
            0.0,
            0.06 * 1.7452406437283512e-02,
        );
        assert!((right.centre_in_master() - expected).norm() < 1e-15);
        let sized = s
            .to_rig(
                ["a", "b"],
                Some((640, 480)),
                interface(),
                Path::new("stereo.yml"),
            )
            .unwrap();
        assert_eq!(
            (
                sized.cameras()[1].intrinsics.width,
                sized.cameras()[1].intrinsics.height
            ),
            (640, 480)
        );
    }

    #[test]
    fn other_key_names_and_size_forms_are_accepted() {
        let k = STEREO.replacen("M1:", "K1:", 1).replacen("M2:", "K2:", 1);
        assert_eq!(parse(&k).unwrap(), parse(STEREO).unwrap());
        let long = STEREO
            .replacen("M1:", "cameraMatrix1:", 1)
            .replacen("D1:", "distCoeffs1:", 1)
            .replacen("M2:", "cameraMatrix2:", 1)
            .replacen("D2:", "distCoeffs2:", 1);
        assert_eq!(parse(&long).unwrap(), parse(STEREO).unwrap());
        let sequence = edited(
            "image_width: 1280\nimage_height: 1024\n",
            "imageSize: [ 640, 480 ]\n",
        );
        assert_eq!(parse(&sequence).unwrap().image_size, Some((640, 480)));
        let matrix = edited(
            "image_width: 1280\nimage_height: 1024\n",
            "imageSize: !!opencv-matrix\n   rows: 2\n   cols: 1\n   dt: d\n   data: [ 800., 600. ]\n",
        );
        assert_eq!(parse(&matrix).unwrap().image_size, Some((800, 600)));
        // Four coefficients (k3 = 0), single precision, a row vector T, CRLF line ends.
        let four = edited(
            "data: [ -0.09, 0.011, 0., 0., 0., 0., 0.,\n       0. ]",
            "data: [ -0.09, 0.011, 0., 0. ]",
        )
        .replacen("rows: 8", "rows: 4", 1)
        .replace("dt: d", "dt: f")
        .replacen(
            "rows: 3\n   cols: 1\n   dt: f\n   data: [ -6.0e-02",
            "rows: 1\n   cols: 3\n   dt: f\n   data: [ -6.0e-02",
            1,
        )
        .replace('\n', "\r\n");
        let s = parse(&four).unwrap();
        assert_eq!(s.distortion[1], [-0.09, 0.011, 0.0, 0.0, 0.0]);
        assert_eq!(s.translation, Vector3::new(-0.06, 0.0, 0.0));
    }

    #[test]
    fn a_byte_order_mark_is_accepted() {
        assert_eq!(
            parse(&format!("\u{feff}{STEREO}")).unwrap(),
            parse(STEREO).unwrap()
        );
    }

    #[test]
    fn split_files_can_be_concatenated() {
        // OpenCV's stereo_calib sample writes intrinsics.yml and extrinsics.yml.
        let (intrinsics, extrinsics) = STEREO.split_at(STEREO.find("R: !!").unwrap());
        let joined = format!("{intrinsics}%YAML:1.0\n---\n{extrinsics}");
        assert_eq!(parse(&joined).unwrap(), parse(STEREO).unwrap());
    }

    #[test]
    fn missing_and_unsupported_content_is_named() {
        let (line, m) = failure(&edited("T: !!", "T_other: !!"));
        assert_eq!(line, 0);
        assert_eq!(m, "stereo.yml: missing key T");
        let (_, m) = failure(&edited("M1: !!", "Mx: !!"));
        assert!(m.contains("missing key M1 or K1 or cameraMatrix1"), "{m}");
        // k4 (coefficient 6 of OpenCV's 8) is not in flatport's model.
        let (line, m) = failure(&edited(
            "0., 0., 0., 0., 0.,\n       0. ]",
            "0., 0., 0., 0.1, 0.,\n       0. ]",
        ));
        assert_eq!(line, 25);
        assert!(
            m.contains("D2: coefficient 6 is 0.1") && m.contains("5-term"),
            "{m}"
        );
        let (line, m) = failure(&edited("%YAML:1.0\n", ""));
        assert_eq!(line, 1);
        assert!(m.contains("%YAML:1.0"), "{m}");
        let (line, m) = failure("");
        assert!(line == 0 && m.contains("empty"), "{m}");
        let (line, m) = failure(&edited(
            "[ 8.6491000000000003e+02, 0., 640.",
            "[ 8.6491000000000003e+02, 0.1, 640.",
        ));
        assert_eq!(line, 9);
        assert!(m.contains("M1: skew K[0][1] = 0.1"), "{m}");
        let (_, m) = failure(&edited(
            "0., 8.6491000000000003e+02,",
            "0.1, 8.6491000000000003e+02,",
        ));
        assert!(m.contains("M1: not a camera matrix"), "{m}");
        let (line, m) = failure(&edited(
            "       512., 0., 0., 1. ]",
            "       512., 0., 0., x ]",
        ));
        assert_eq!(line, 14, "the line of the bad value, not of the key");
        assert!(m.contains("M1: 'x' is not a number"), "{m}");
        let (line, m) = failure(&edited(
            "data: [ -6.0e-02, 0., 0. ]",
            "data: [ -6.0e-02, .Inf, 0. ]",
        ));
        assert_eq!(line, 41);
        assert!(m.contains("T: '.Inf' is not finite"), "{m}");
        let (_, m) = failure(&edited(
            "data: [ -6.0e-02, 0., 0. ]",
            "data: [ -6.0e-02, 0. ]",
        ));
        assert!(m.contains("T: 3x1 matrix with 2 values"), "{m}");
        let (_, m) = failure(
            &edited("rows: 3\n   cols: 1", "rows: 1\n   cols: 3\n   extra: 1").replacen(
                "rows: 3\n   cols: 3\n   dt: d\n   data: [ 9.99",
                "rows: 9\n   cols: 1\n   dt: d\n   data: [ 9.99",
                1,
            ),
        );
        assert!(m.contains("R is 9x1, expected 3x3"), "{m}");
        let (_, m) = failure(&edited(
            "rows: 1\n   cols: 5\n   dt: d",
            "rows: 1\n   cols: 5\n   dt: u",
        ));
        assert!(m.contains("D1: element type dt 'u'"), "{m}");
        let (line, m) = failure(&edited("       0. ]\nR:", "       0. \nR:"));
        assert_eq!(line, 31);
        assert!(m.contains("D2: '[' is never closed"), "{m}");
        let (line, m) = failure(&format!("{STEREO}last: [ 1, 2\n"));
        assert_eq!(line, 58);
        assert!(m.contains("last: '[' is never closed"), "{m}");
        let (_, m) = failure(&format!("{STEREO}T: 1\n"));
        assert!(m.contains("key T appears twice (first on line 37)"), "{m}");
        let (_, m) = failure(&edited("image_height: 1024\n", ""));
        assert!(
            m.contains("image_width and image_height must be given together"),
            "{m}"
        );
        let (_, m) = failure(&edited("image_width: 1280", "image_width: 12.5"));
        assert!(
            m.contains("image_width must be a positive whole number"),
            "{m}"
        );
        let (line, m) = failure(&edited("flags: 0", "just some words"));
        assert_eq!(line, 8);
        assert!(m.contains("expected 'key: value'"), "{m}");
    }

    #[test]
    fn yaml_forms_opencv_and_other_writers_use_are_read() {
        // The verbatim form of the tag, OpenCV's number spellings, a block list for data, a flow
        // mapping over two lines and an anchor in keys flatport does not read.
        let text = edited(
            "M1: !!opencv-matrix",
            "M1: !<tag:yaml.org,2002:opencv-matrix>",
        )
        .replacen(
            "data: [ -6.0e-02, 0., 0. ]",
            "data:\n     - -6.e-02\n     - +0.\n     - -0.0e+00",
            1,
        )
        .replacen(
            "nested:",
            "flow: { a: 1,\n   b: [ 2, 3 ] }\nanchored: &x [ 1 ]\nalias: *x\nnested:",
            1,
        );
        let s = parse(&text).unwrap();
        assert_eq!(s, parse(STEREO).unwrap());
        // A directive line without '---' after it (older OpenCV), and a %YAML 1.2 directive.
        let bare = edited("%YAML:1.0\n---\n", "%YAML:1.0\n");
        assert_eq!(parse(&bare).unwrap(), parse(STEREO).unwrap());
        let standard = edited("%YAML:1.0\n", "%YAML 1.2\n");
        assert_eq!(parse(&standard).unwrap(), parse(STEREO).unwrap());
    }

    #[test]
    fn bad_yaml_is_located_and_named() {
        // Not YAML inside a matrix: the key and the line of the parser's complaint.
        let (line, m) = failure(&edited("   rows: 1\n   cols: 5", "   rows: 1\n  - cols: 5"));
        assert_eq!(line, 17, "{m}");
        assert!(
            m.starts_with("stereo.yml:17: not valid YAML: ")
                && m.ends_with("; the line reads '- cols: 5'"),
            "{m}"
        );
        // An alias where a matrix is read, data that is no sequence, a dt that is a list.
        let (_, m) = failure(&edited("M2: !!opencv-matrix", "M2: &m !!opencv-matrix").replacen(
            "R: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 9.99",
            "R: *m\nR_unused: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 9.99",
            1,
        ));
        assert!(
            m.contains("R is a YAML alias (*name), which is not followed"),
            "{m}"
        );
        let (line, m) = failure(&edited("data: [ -6.0e-02, 0., 0. ]", "data: 0.06"));
        assert_eq!(line, 41);
        assert!(m.contains("T: data must be a sequence of numbers"), "{m}");
        let (line, m) = failure(&edited(
            "rows: 1\n   cols: 5\n   dt: d",
            "rows: 1\n   cols: 5\n   dt: [ d ]",
        ));
        assert_eq!(line, 18);
        assert!(m.contains("D1: element type dt (not a scalar)"), "{m}");
        // A document that is no mapping.
        let (line, m) = failure("%YAML:1.0\n---\n- 1\n- 2\n");
        assert_eq!(line, 3);
        assert!(
            m.contains("expected 'key: value' at the top level, found a sequence"),
            "{m}"
        );
    }

    #[test]
    fn huge_keys_and_lines_are_shown_by_their_start() {
        let long = "k".repeat(1 << 20);
        // Inside the top-level mapping, and as the document's first line.
        let (line, m) = failure(&format!("%YAML:1.0\n---\n{long}: 1\n"));
        assert_eq!(line, 3);
        assert!(m.contains("is longer than YAML allows a plain key"), "{m}");
        let (line, m) = failure(&format!("{STEREO}{long}: 1\n"));
        assert_eq!(line, 58);
        assert!(
            m.ends_with(
                "… (1048576 bytes)' is longer than YAML allows a plain key (1024 characters)"
            ),
            "{}",
            &m[..m.len().min(400)]
        );
        let (_, m) = failure(&format!("{STEREO}{}: 1\n{0}: 2\n", &long[..1000]));
        assert!(m.contains("… (1000 bytes) appears twice"), "{m}");
        for text in [
            format!("{STEREO}{long}: 1\n{long}: 2\n"),
            edited("flags: 0", &long),
            format!("{STEREO}{long}: [ 1,\n2\n"),
        ] {
            let (_, m) = failure(&text);
            assert!(
                m.len() < 300 && m.contains(&format!("'{}… (10485", "k".repeat(60))),
                "{}",
                &m[..m.len().min(400)]
            );
        }
        let (_, m) = failure(&edited(
            "[ -6.0e-02, 0., 0. ]",
            &format!("[ -6.0e-02, {long}, 0. ]"),
        ));
        assert!(
            m.len() < 300 && m.starts_with("stereo.yml:41: T: 'kkk"),
            "{m}"
        );
    }

    #[test]
    fn rig_needs_a_size_and_valid_extrinsics() {
        let no_size = parse(&edited("image_width: 1280\nimage_height: 1024\n", "")).unwrap();
        assert_eq!(no_size.image_size, None);
        let error = no_size
            .to_rig(["l", "r"], None, interface(), Path::new("stereo.yml"))
            .unwrap_err();
        assert!(matches!(error, IoError::Invalid { .. }));
        assert!(error.to_string().contains("--size"), "{error}");
        assert!(
            no_size
                .to_rig(
                    ["l", "r"],
                    Some((1280, 1024)),
                    interface(),
                    Path::new("stereo.yml")
                )
                .is_ok()
        );

        let mut far = parse(STEREO).unwrap();
        far.translation = Vector3::new(0.0, 0.0, -1.0);
        let error = far
            .to_rig(["l", "r"], None, interface(), Path::new("stereo.yml"))
            .unwrap_err();
        assert!(
            error.to_string().contains("'r' is not in the air"),
            "{error}"
        );
        let mut skewed = parse(STEREO).unwrap();
        skewed.rotation[(0, 1)] = 0.1;
        let error = skewed
            .to_rig(["l", "r"], None, interface(), Path::new("stereo.yml"))
            .unwrap_err();
        assert!(
            error.to_string().contains("camera 2 ('r') R, T")
                && error.to_string().contains("not a rotation"),
            "{error}"
        );
    }
}
