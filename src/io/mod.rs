//! File formats: rig JSON, OpenCV FileStorage YAML, CSV tables. No geometry here.

pub mod error;
pub mod opencv;
pub mod rig_json;
pub mod tabular;

use std::io::Write;
use std::path::Path;

pub use error::IoError;
pub use opencv::{OpenCvStereo, parse_opencv_stereo, read_opencv_stereo};
pub use rig_json::{read_rig, rig_from_json_str, rig_to_json_string, write_rig};
pub use tabular::{TableWriteSummary, read_table, read_table_from, write_table};

/// Writes `bytes` to `path` atomically: a temporary file in the same folder, then a rename. A
/// failed or interrupted write leaves no half-written file under `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let err = |source| IoError::Write { path: path.to_path_buf(), source };
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let temporary = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    let result = std::fs::File::create(&temporary)
        .and_then(|mut file| {
            file.write_all(bytes)?;
            file.sync_all()
        })
        .and_then(|()| std::fs::rename(&temporary, path));
    if let Err(source) = result {
        let _ = std::fs::remove_file(&temporary);
        return Err(err(source));
    }
    Ok(())
}

/// Reads a whole file (`-` = standard input) into a string.
pub(crate) fn read_text(path: &Path) -> Result<String, IoError> {
    let err = |source| IoError::Read { path: path.to_path_buf(), source };
    if path.as_os_str() == "-" {
        let mut text = String::new();
        std::io::Read::read_to_string(&mut std::io::stdin(), &mut text).map_err(err)?;
        Ok(text)
    } else {
        std::fs::read_to_string(path).map_err(err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "two");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let missing = dir.path().join("no/such/dir/out.txt");
        assert!(matches!(write_atomic(&missing, b"x"), Err(IoError::Write { .. })));
    }
}
