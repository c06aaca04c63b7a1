//! NumPy `.npy` files (format 1.0, little-endian f64 or f32, C order), written as a stream so a large
//! array never has to be in memory, into a temporary file renamed into place by
//! [`NpyWriter::finish`], and read as a stream by [`NpyReader`].
//!
//! Reading goes through the `npyz` crate: it parses the header dict as the Python literal it is
//! (any key order, quoting or spacing numpy or another writer uses; format 1.0, 2.0 and 3.0) and
//! decodes the values (`<f8` and `>f8`) one by one from any reader. Before handing it the header,
//! the header's length is checked here against the file and a bound, as npyz allocates whatever
//! length a file claims (up to 4 GiB), and the element count is recomputed with overflow checks,
//! as npyz multiplies the shape unchecked.
//!
//! Writing stays here, for two reasons npyz does not serve: its header spells the shape `(2, 3, )`
//! where numpy writes `(2, 3)`, and a sweep's `cost.npy` is compared byte for byte with a header
//! written from numpy's format (tests/sizes.rs), sharded and merged sweeps byte for byte with each
//! other; and its writer keeps the output it writes to (no `into_inner`), while the file must go
//! back to [`OutputFile::finish`] to be renamed into place. The writer is 20 lines of the format:
//! the preamble, the dict and the values' little-endian bytes.

use std::io::Write;
use std::path::Path;

use crate::io::error::{EXCERPT_CHARS, excerpt};
use crate::io::{IoError, OutputFile};

/// The 10-byte preamble and the header dict, padded with spaces and a newline so the data starts
/// on a 64-byte boundary, as numpy writes it.
pub fn npy_header(shape: &[usize]) -> Vec<u8> {
    npy_header_of(shape, NpyDtype::F64)
}

/// Element type of a `.npy` file flatport writes (little-endian).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NpyDtype {
    /// `<f4`.
    F32,
    /// `<f8`.
    F64,
}

impl NpyDtype {
    /// numpy's `descr`.
    fn descr(self) -> &'static str {
        match self {
            Self::F32 => "<f4",
            Self::F64 => "<f8",
        }
    }
}

/// [`npy_header`] for elements of `dtype`.
pub fn npy_header_of(shape: &[usize], dtype: NpyDtype) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut dict = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {shape}, }}",
        dtype.descr()
    );
    let unpadded = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
    dict.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    bytes.extend_from_slice(dict.as_bytes());
    bytes
}

/// A `.npy` file being written value by value in C order, through an [`OutputFile`] (a temporary
/// file renamed into place by [`finish`](Self::finish)). Dropped before `finish` (an error, an
/// interruption), it removes its temporary file.
pub struct NpyWriter {
    out: OutputFile,
    dtype: NpyDtype,
    expected: usize,
    written: usize,
}

impl NpyWriter {
    /// Starts `path` (written under a temporary name until [`finish`](Self::finish)).
    pub fn create(path: &Path, shape: &[usize]) -> Result<Self, IoError> {
        Self::create_of(path, shape, NpyDtype::F64)
    }

    /// [`create`](Self::create) for elements of `dtype`; [`write`](Self::write) rounds f64 values
    /// to it.
    pub fn create_of(path: &Path, shape: &[usize], dtype: NpyDtype) -> Result<Self, IoError> {
        let mut out = OutputFile::create(Some(path))?;
        out.write_all(&npy_header_of(shape, dtype))
            .map_err(|source| out.write_error(source))?;
        Ok(Self {
            out,
            dtype,
            expected: shape.iter().product(),
            written: 0,
        })
    }

    /// Appends values.
    pub fn write(&mut self, values: &[f64]) -> Result<(), IoError> {
        let written = match self.dtype {
            NpyDtype::F64 => values
                .iter()
                .try_for_each(|v| self.out.write_all(&v.to_le_bytes())),
            NpyDtype::F32 => values
                .iter()
                .try_for_each(|&v| self.out.write_all(&(v as f32).to_le_bytes())),
        };
        written.map_err(|source| self.out.write_error(source))?;
        self.written += values.len();
        Ok(())
    }

    /// Flushes and renames into place. Errors (and removes the temporary file) when fewer or more
    /// values than the shape holds were written.
    pub fn finish(self) -> Result<(), IoError> {
        if self.written != self.expected {
            return Err(self.out.write_error(std::io::Error::other(format!(
                "{} values written for a shape of {}",
                self.written, self.expected
            ))));
        }
        self.out.finish()
    }
}

/// Reads a little-endian f64 `.npy` file (C order): (shape, values). For tests and tools; a
/// sweep's arrays are read in bounded memory with [`NpyReader`].
pub fn read_npy(path: &Path) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    NpyReader::open(path)?.read_to_end()
}

/// Reads a little-endian f32 `.npy` file in C order, as `flatport stereo` writes its depth and
/// confidence maps: (shape, values). Errors name the file: unreadable, not f32 in C order, or
/// data that do not match the shape.
pub fn read_npy_f32(path: &Path) -> Result<(Vec<usize>, Vec<f32>), IoError> {
    let invalid = |reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field: String::new(),
        reason,
    };
    let bytes = std::fs::read(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let file = npyz::NpyFile::new(&bytes[..]).map_err(|e| {
        invalid(format!(
            "not a .npy file: {}",
            e.to_string().lines().next().unwrap_or_default()
        ))
    })?;
    if file.header().dtype().descr() != "'<f4'" || file.order() != npyz::Order::C {
        return Err(invalid(format!(
            "only little-endian f32 in C order is read here, the file holds {} ({:?} order)",
            file.header().dtype().descr(),
            file.order()
        )));
    }
    let shape: Vec<usize> = file.shape().iter().map(|&d| d as usize).collect();
    let values = file
        .into_vec::<f32>()
        .map_err(|e| invalid(format!("the data do not match the header: {e}")))?;
    if values.len() != shape.iter().product::<usize>() {
        return Err(invalid(format!(
            "{} values for the shape {shape:?}",
            values.len()
        )));
    }
    Ok((shape, values))
}

/// Parses the bytes of a `.npy` file as [`read_npy`] does; `path` only labels errors.
pub fn npy_from_bytes(bytes: &[u8], path: &Path) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    NpyReader::from_reader(bytes, bytes.len() as u64, path)?.read_to_end()
}

/// Longest `.npy` header read, bytes (numpy's own are a few hundred).
const MAX_HEADER_BYTES: usize = 1 << 20;

/// An f64 `.npy` file (format 1.0, 2.0 or 3.0, C order, little- or big-endian) read value by value
/// in bounded memory: the reading twin of [`NpyWriter`], for sweeps whose arrays do not fit in
/// memory. Its header is checked whole on opening: the data must hold exactly the values of the
/// shape.
pub struct NpyReader<R: std::io::Read = std::io::BufReader<std::fs::File>> {
    path: std::path::PathBuf,
    values: npyz::NpyReader<f64, R>,
    shape: Vec<usize>,
    left: usize,
}

impl NpyReader {
    /// Opens `path` and reads its header.
    ///
    /// Errors: [`IoError::Read`] when it cannot be read; [`IoError::Invalid`] naming the file when
    /// it is not an f64 C-order `.npy` file or its data do not match its shape.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        let read_error = |source| IoError::Read {
            path: path.to_path_buf(),
            source,
        };
        let file = std::fs::File::open(path).map_err(read_error)?;
        let length = file.metadata().map_err(read_error)?.len();
        NpyReader::from_reader(std::io::BufReader::new(file), length, path)
    }
}

impl<R: std::io::Read> NpyReader<R> {
    /// [`NpyReader::open`] over any reader holding `length` bytes; `path` only labels errors.
    pub fn from_reader(mut input: R, length: u64, path: &Path) -> Result<Self, IoError> {
        let invalid = |reason: String| IoError::Invalid {
            path: path.to_path_buf(),
            field: String::new(),
            reason,
        };
        // The preamble and the header's length, read here to bound what npyz will allocate.
        let mut bytes = vec![0u8; 8];
        input
            .read_exact(&mut bytes)
            .map_err(|_| invalid("not a .npy file (too short)".into()))?;
        if &bytes[..6] != b"\x93NUMPY" {
            return Err(invalid("not a .npy file (no \\x93NUMPY magic)".into()));
        }
        let size_bytes = match bytes[6] {
            1 => 2,
            2 | 3 => 4,
            v => return Err(invalid(format!("unknown .npy format version {v}"))),
        };
        bytes.resize(8 + size_bytes, 0);
        input
            .read_exact(&mut bytes[8..])
            .map_err(|_| invalid("truncated header".into()))?;
        let header_len = bytes[8..]
            .iter()
            .rev()
            .fold(0usize, |n, &b| n << 8 | usize::from(b));
        let prefix = bytes.len();
        if (prefix + header_len) as u64 > length || header_len > MAX_HEADER_BYTES {
            return Err(invalid("the file ends inside the header".into()));
        }
        bytes.resize(prefix + header_len, 0);
        input
            .read_exact(&mut bytes[prefix..])
            .map_err(|_| invalid("the file ends inside the header".into()))?;
        let text = std::str::from_utf8(&bytes[prefix..])
            .map_err(|_| invalid("the header is not text".into()))?;
        let shown = excerpt(text.trim(), 4 * EXCERPT_CHARS);
        let header = npyz::NpyHeader::from_reader(&bytes[..]).map_err(|e| {
            // npyz's parse errors quote the whole header after their first line.
            let e = e.to_string();
            let why = excerpt(e.lines().next().unwrap_or_default(), 2 * EXCERPT_CHARS);
            invalid(format!("the header {shown} is not numpy's: {why}"))
        })?;
        if header.dtype().descr() != "'<f8'" && header.dtype().descr() != "'>f8'"
            || header.order() != npyz::Order::C
        {
            return Err(invalid(format!(
                "only f64 in C order is read, the header says {shown}"
            )));
        }
        let shape: Vec<usize> = header
            .shape()
            .iter()
            .map(|&d| usize::try_from(d).map_err(|_| invalid("the shape overflows".into())))
            .collect::<Result<_, _>>()?;
        let values = shape
            .iter()
            .try_fold(1usize, |a, &b| a.checked_mul(b))
            .ok_or_else(|| invalid("the shape overflows".into()))?;
        let data = length - (prefix + header_len) as u64;
        if Some(data) != (values as u64).checked_mul(8) {
            return Err(invalid(format!(
                "{data} data bytes for the shape {shape:?} ({values} values of 8 bytes)"
            )));
        }
        let values_in = npyz::NpyFile::with_header(header, input)
            .data::<f64>()
            .map_err(|e| invalid(format!("only f64 is read: {e}")))?;
        Ok(Self {
            path: path.to_path_buf(),
            values: values_in,
            shape,
            left: values,
        })
    }

    /// The array's shape.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// Clears `values` and fills it with the next values, at most `max` (0 is taken as 1), in C
    /// order. Returns how many: 0 only at the end.
    pub fn read(&mut self, max: usize, values: &mut Vec<f64>) -> Result<usize, IoError> {
        values.clear();
        let n = max.max(1).min(self.left);
        values.reserve(n);
        for value in self.values.by_ref().take(n) {
            values.push(value.map_err(|source| IoError::Read {
                path: self.path.clone(),
                source,
            })?);
        }
        if values.len() != n {
            return Err(IoError::Read {
                path: self.path.clone(),
                source: std::io::ErrorKind::UnexpectedEof.into(),
            });
        }
        self.left -= n;
        Ok(n)
    }

    /// The shape and every value left, in memory.
    pub fn read_to_end(mut self) -> Result<(Vec<usize>, Vec<f64>), IoError> {
        let mut values = Vec::new();
        self.read(self.left, &mut values)?;
        Ok((self.shape, values))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f32_maps_read_back_and_f64_ones_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.npy");
        let values = [1.5f32, f32::NAN, -2.0, 0.25, 7.0, 3.0];
        crate::io::stereo_files::write_npy_f32(&path, &[2, 3], &values).unwrap();
        let (shape, read) = read_npy_f32(&path).unwrap();
        assert_eq!(shape, vec![2, 3]);
        assert_eq!(read[0], 1.5);
        assert!(read[1].is_nan());
        assert_eq!(&read[2..], &values[2..]);
        let other = dir.path().join("e.npy");
        let mut writer = NpyWriter::create(&other, &[2]).unwrap();
        writer.write(&[1.0, 2.0]).unwrap();
        writer.finish().unwrap();
        let error = read_npy_f32(&other).unwrap_err().to_string();
        assert!(error.contains("e.npy") && error.contains("f8"), "{error}");
    }

    #[test]
    fn short_and_overflowing_files_are_errors_not_panics() {
        let path = Path::new("x.npy");
        // A header length past the end of the file (sliced unchecked before: a panic).
        assert!(npy_from_bytes(b"\x93NUMPY\x01\x00\xff\x00{'descr'", path).is_err());
        // A shape whose element count overflows usize.
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        let dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (18446744073709551615, 3), }";
        bytes.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        bytes.extend_from_slice(dict.as_bytes());
        assert!(npy_from_bytes(&bytes, path).is_err());
    }

    /// A `.npy` file as numpy 2.4's `np.save` writes one (format 1.0, the dict padded with spaces
    /// to 118 bytes and a newline, so the data start at byte 128), with the header dict `dict`:
    /// `b = io.BytesIO(); np.save(b, np.arange(6.0).reshape(2, 3)); b.getvalue()` gives the
    /// 176 bytes of `numpy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }", …)`.
    fn numpy_file(dict: &str, version: u8, data: &[u8]) -> Vec<u8> {
        let mut bytes = b"\x93NUMPY".to_vec();
        bytes.extend_from_slice(&[version, 0]);
        let size = if version == 1 { 2 } else { 4 };
        let text = format!("{dict:<width$}\n", width = 128 - 8 - size - 1);
        bytes.extend_from_slice(&(text.len() as u32).to_le_bytes()[..size]);
        bytes.extend_from_slice(text.as_bytes());
        bytes.extend_from_slice(data);
        bytes
    }

    fn le(values: &[f64]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    #[test]
    fn files_numpy_writes_are_read() {
        let path = Path::new("numpy.npy");
        let six = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        let c = numpy_file(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }",
            1,
            &le(&six),
        );
        assert_eq!(c.len(), 176);
        assert_eq!(
            npy_from_bytes(&c, path).unwrap(),
            (vec![2, 3], six.to_vec())
        );
        // Big-endian, as `a.astype('>f8')` saves.
        let be: Vec<u8> = six.iter().flat_map(|v| v.to_be_bytes()).collect();
        let big = numpy_file(
            "{'descr': '>f8', 'fortran_order': False, 'shape': (2, 3), }",
            1,
            &be,
        );
        assert_eq!(
            npy_from_bytes(&big, path).unwrap(),
            (vec![2, 3], six.to_vec())
        );
        // One dimension, none (np.float64(2.5)), and another spelling of the dict in format 2.0.
        let one = numpy_file(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (7,), }",
            1,
            &le(&[1.5; 7]),
        );
        assert_eq!(npy_from_bytes(&one, path).unwrap(), (vec![7], vec![1.5; 7]));
        let scalar = numpy_file(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (), }",
            1,
            &le(&[2.5]),
        );
        assert_eq!(npy_from_bytes(&scalar, path).unwrap(), (vec![], vec![2.5]));
        let spelled = numpy_file(
            "{\"shape\": (3, 2), \"descr\": \"<f8\", \"fortran_order\": False}",
            2,
            &le(&six),
        );
        assert_eq!(
            npy_from_bytes(&spelled, path).unwrap(),
            (vec![3, 2], six.to_vec())
        );
    }

    #[test]
    fn what_is_not_read_is_named() {
        let path = Path::new("x.npy");
        let message = |bytes: &[u8]| npy_from_bytes(bytes, path).unwrap_err().to_string();
        let m = message(&numpy_file(
            "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 3), }",
            1,
            &le(&[0.0; 6]),
        ));
        assert!(m.starts_with("x.npy: only f64 in C order is read, the header says {'descr': '<f8', 'fortran_order': True"), "{m}");
        let m = message(&numpy_file(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2,), }",
            1,
            &[0; 8],
        ));
        assert!(
            m.contains("only f64 in C order is read") && m.contains("'<f4'"),
            "{m}"
        );
        let m = message(&numpy_file(
            "{'descr': '<f8', 'fortran_order': False}",
            1,
            &[],
        ));
        assert!(m.contains("is not numpy's") && m.contains("shape"), "{m}");
        let m = message(&numpy_file(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }",
            1,
            &le(&[0.0; 5]),
        ));
        assert!(
            m.contains("40 data bytes for the shape [2, 3] (6 values of 8 bytes)"),
            "{m}"
        );
        // A dict nested 60 000 deep (the parser recurses): an error, not a stack overflow.
        let deep = format!("{}{}", "(".repeat(60_000), ")".repeat(5000));
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(deep.len() as u16).to_le_bytes());
        bytes.extend_from_slice(deep.as_bytes());
        let m = message(&bytes);
        assert!(m.len() < 600 && m.contains("is not numpy's"), "{m}");
    }

    #[test]
    fn header_is_aligned_and_round_trips() {
        let h = npy_header(&[256, 3]);
        assert_eq!(h.len() % 64, 0);
        assert!(String::from_utf8_lossy(&h).contains("'shape': (256, 3), }"));
        assert!(String::from_utf8_lossy(&npy_header(&[7])).contains("(7,)"));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npy");
        let mut w = NpyWriter::create(&path, &[2, 3]).unwrap();
        w.write(&[1.0, 2.0]).unwrap();
        w.write(&[3.0, f64::INFINITY, -5.5, 6.0]).unwrap();
        w.finish().unwrap();
        let (shape, values) = read_npy(&path).unwrap();
        assert_eq!(shape, vec![2, 3]);
        assert_eq!(values, vec![1.0, 2.0, 3.0, f64::INFINITY, -5.5, 6.0]);
        // A short write leaves nothing behind.
        let short = dir.path().join("b.npy");
        let mut w = NpyWriter::create(&short, &[4]).unwrap();
        w.write(&[1.0]).unwrap();
        assert!(w.finish().is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
