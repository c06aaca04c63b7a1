//! NumPy `.npy` files (format 1.0, little-endian f64 or f32, C order), written as a stream so a large
//! array never has to be in memory, into a temporary file renamed into place by
//! [`NpyWriter::finish`].

use std::io::Write;
use std::path::Path;

use super::{IoError, OutputFile};

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

/// Parses the bytes of a `.npy` file as [`read_npy`] does; `path` only labels errors.
pub fn npy_from_bytes(bytes: &[u8], path: &Path) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    NpyReader::from_reader(bytes, bytes.len() as u64, path)?.read_to_end()
}

/// Longest `.npy` header read, bytes (numpy's own are a few hundred).
const MAX_HEADER_BYTES: usize = 1 << 20;

/// A little-endian f64 `.npy` file (format 1.0 or 2.0, C order) read value by value in bounded
/// memory: the reading twin of [`NpyWriter`], for sweeps whose arrays do not fit in memory. Its
/// header is checked whole on opening: the data must hold exactly the values of the shape.
pub struct NpyReader<R = std::io::BufReader<std::fs::File>> {
    path: std::path::PathBuf,
    input: R,
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
        let mut preamble = [0u8; 8];
        input
            .read_exact(&mut preamble)
            .map_err(|_| invalid("not a .npy file (too short)".into()))?;
        if &preamble[..6] != b"\x93NUMPY" {
            return Err(invalid("not a .npy file (no \\x93NUMPY magic)".into()));
        }
        let header_len = match preamble[6] {
            1 => {
                let mut n = [0u8; 2];
                input
                    .read_exact(&mut n)
                    .map_err(|_| invalid("truncated header".into()))?;
                u16::from_le_bytes(n) as usize
            }
            2 | 3 => {
                let mut n = [0u8; 4];
                input
                    .read_exact(&mut n)
                    .map_err(|_| invalid("truncated header".into()))?;
                u32::from_le_bytes(n) as usize
            }
            v => return Err(invalid(format!("unknown .npy format version {v}"))),
        };
        let prefix = if preamble[6] == 1 { 10 } else { 12 };
        if (prefix + header_len) as u64 > length || header_len > MAX_HEADER_BYTES {
            return Err(invalid("the file ends inside the header".into()));
        }
        let mut header = vec![0u8; header_len];
        input
            .read_exact(&mut header)
            .map_err(|_| invalid("the file ends inside the header".into()))?;
        let header =
            String::from_utf8(header).map_err(|_| invalid("the header is not text".into()))?;
        if !header.contains("'descr': '<f8'") || !header.contains("'fortran_order': False") {
            return Err(invalid(format!(
                "only little-endian f64 in C order is read, the header says {}",
                header.trim()
            )));
        }
        let shape_text = header
            .split("'shape': (")
            .nth(1)
            .and_then(|s| s.split(')').next())
            .ok_or_else(|| invalid("the header has no shape".into()))?;
        let shape: Vec<usize> = shape_text
            .split(',')
            .filter(|s| !s.trim().is_empty())
            .map(|s| {
                s.trim()
                    .parse()
                    .map_err(|_| invalid(format!("bad shape ({shape_text})")))
            })
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
        Ok(Self {
            path: path.to_path_buf(),
            input,
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
        let mut bytes = vec![0u8; 8 * n];
        self.input
            .read_exact(&mut bytes)
            .map_err(|source| IoError::Read {
                path: self.path.clone(),
                source,
            })?;
        values.extend(
            bytes
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes"))),
        );
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
