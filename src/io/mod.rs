//! File formats: rig JSON, OpenCV FileStorage YAML, CSV tables. No geometry here.

pub mod calib_json;
pub mod error;
pub mod npy;
pub mod plot;
pub mod opencv;
pub mod rig_json;
pub mod tabular;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

pub use calib_json::{
    Truth, observations_from_json_str, observations_to_json_string, read_observations, read_truth,
    report_to_json_string, write_observations, write_report, write_truth,
};
pub use error::IoError;
pub use opencv::{OpenCvStereo, parse_opencv_stereo, read_opencv_stereo};
pub use rig_json::{read_rig, rig_from_json_str, rig_to_json_string, write_rig};
pub use tabular::{
    TableReader, TableSource, TableWriteSummary, TableWriter, read_table, read_table_from,
    validate_table, write_table,
};

/// Writes `bytes` to `path` atomically: a temporary file in the same folder, flushed to disk, then
/// renamed over `path`. A failed or interrupted write leaves no half-written file under `path` (an
/// existing file keeps its old content), and a failed write removes its temporary file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let err = |source| IoError::Write {
        path: path.to_path_buf(),
        source,
    };
    let temporary = temporary_path(path);
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

/// A fresh name for a temporary file beside `path` (same folder, so a rename onto `path` is
/// atomic): `.NAME.PID.N.tmp`, unique per process and call, so concurrent writers never share one.
pub(crate) fn temporary_path(path: &Path) -> PathBuf {
    static COUNTER: AtomicUsize = AtomicUsize::new(0);
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let call = COUNTER.fetch_add(1, Ordering::Relaxed);
    dir.join(format!(".{name}.{}.{call}.tmp", std::process::id()))
}

/// Reads a whole file (`-` = standard input) into a string.
pub(crate) fn read_text(path: &Path) -> Result<String, IoError> {
    let err = |source| IoError::Read {
        path: path.to_path_buf(),
        source,
    };
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

    fn names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "two");
        assert_eq!(names(dir.path()), ["out.txt"]);
    }

    #[test]
    fn failed_atomic_write_keeps_the_old_state() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no/such/dir/out.txt");
        let error = write_atomic(&missing, b"x").unwrap_err();
        assert!(matches!(error, IoError::Write { .. }));
        assert!(
            error
                .to_string()
                .starts_with(&missing.display().to_string()),
            "{error}"
        );
        // Renaming onto a non-empty folder fails after the temporary file was written: it is removed.
        let folder = dir.path().join("taken");
        std::fs::create_dir(&folder).unwrap();
        std::fs::write(folder.join("inside.txt"), "keep").unwrap();
        assert!(matches!(
            write_atomic(&folder, b"x"),
            Err(IoError::Write { .. })
        ));
        assert_eq!(names(dir.path()), ["taken"]);
        assert_eq!(
            std::fs::read_to_string(folder.join("inside.txt")).unwrap(),
            "keep"
        );
    }

    #[test]
    fn concurrent_atomic_writes_leave_one_whole_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        std::thread::scope(|scope| {
            for i in 0..8u8 {
                let path = &path;
                scope.spawn(move || write_atomic(path, &vec![b'a' + i; 100_000]).unwrap());
            }
        });
        let text = std::fs::read(&path).unwrap();
        assert_eq!(text.len(), 100_000);
        assert!(
            text.iter().all(|&b| b == text[0]),
            "one writer's content, whole"
        );
        assert_eq!(names(dir.path()), ["out.txt"]);
    }
}
