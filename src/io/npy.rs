//! NumPy `.npy` files (format 1.0, little-endian f64, C order), written as a stream so a large
//! array never has to be in memory, into a temporary file renamed into place by
//! [`NpyWriter::finish`].

use std::io::Write;
use std::path::Path;

use super::{IoError, OutputFile};

/// The 10-byte preamble and the header dict, padded with spaces and a newline so the data starts
/// on a 64-byte boundary, as numpy writes it.
pub fn npy_header(shape: &[usize]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut dict = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape}, }}");
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
    expected: usize,
    written: usize,
}

impl NpyWriter {
    /// Starts `path` (written under a temporary name until [`finish`](Self::finish)).
    pub fn create(path: &Path, shape: &[usize]) -> Result<Self, IoError> {
        let mut out = OutputFile::create(Some(path))?;
        out.write_all(&npy_header(shape)).map_err(|source| out.write_error(source))?;
        Ok(Self { out, expected: shape.iter().product(), written: 0 })
    }

    /// Appends values.
    pub fn write(&mut self, values: &[f64]) -> Result<(), IoError> {
        for v in values {
            self.out.write_all(&v.to_le_bytes()).map_err(|source| self.out.write_error(source))?;
        }
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

/// Reads a little-endian f64 `.npy` file (C order): (shape, values). For tests and tools.
pub fn read_npy(path: &Path) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    let bytes = std::fs::read(path).map_err(|source| IoError::Read { path: path.to_path_buf(), source })?;
    let invalid = |reason: &str| IoError::Invalid { path: path.to_path_buf(), field: String::new(), reason: reason.into() };
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(invalid("not a .npy file"));
    }
    let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(&bytes[10..10 + header_len]).map_err(|_| invalid("header is not text"))?;
    if !header.contains("'descr': '<f8'") || !header.contains("'fortran_order': False") {
        return Err(invalid("only little-endian f64 in C order is read"));
    }
    let shape_text = header.split("'shape': (").nth(1).and_then(|s| s.split(')').next()).ok_or_else(|| invalid("no shape"))?;
    let shape: Vec<usize> = shape_text.split(',').filter(|s| !s.trim().is_empty()).map(|s| s.trim().parse().map_err(|_| invalid("bad shape"))).collect::<Result<_, _>>()?;
    let data = &bytes[10 + header_len..];
    if data.len() != 8 * shape.iter().product::<usize>() {
        return Err(invalid("data length does not match the shape"));
    }
    Ok((shape, data.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes"))).collect()))
}

#[cfg(test)]
mod tests {
    use super::*;

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
