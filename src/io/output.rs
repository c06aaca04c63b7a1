//! Output files that appear whole or not at all, and never harm what their path names.
//!
//! What a path names decides how it is written:
//! - a **new path or a regular file** (also through symbolic links, which are followed to the
//!   file they point to): the bytes go to a temporary file beside that file, which
//!   [`OutputFile::finish`] flushes to disk and renames onto it. Until then the file keeps its old
//!   content; its permissions are kept; the link stays a link.
//! - **anything else** (a device node such as `/dev/null` or `/dev/full`, a FIFO, a socket,
//!   `/dev/stdout`, `/dev/fd/N`, `/proc/self/fd/N`): written directly, as a shell redirection
//!   would. Renaming onto such a path would replace the device node with a regular file (as root)
//!   or fail (as a user).
//! - `-` or no path: standard output.
//!
//! Direct outputs cannot be taken back, so [`OutputFile::streams`] tells a caller to check its
//! input before the first byte. Every write error, `ENOSPC` from a full device included, is an
//! [`IoError::Write`] naming the path.
//!
//! Every temporary file is registered while it exists; [`remove_temporaries`] removes them all, for
//! a signal handler that ends the process right after (the CLI's SIGINT/SIGTERM/SIGHUP handler).

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Stdout, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard};

use super::IoError;

/// Buffer of an output: large enough that system calls cost nothing next to formatting.
const BUFFER_BYTES: usize = 1 << 16;

/// Symbolic links followed before a path is taken as a loop (Linux's own limit).
const MAX_LINKS: usize = 40;

/// An output being written (see the [module docs](self) for what each kind of path gets).
///
/// ```no_run
/// # fn main() -> Result<(), flatport::io::IoError> {
/// use std::io::Write;
/// use flatport::io::OutputFile;
/// let mut out = OutputFile::create(Some("result.txt".as_ref()))?;
/// writeln!(out, "42").map_err(|e| out.write_error(e))?;
/// out.finish()?; // result.txt appears here, whole
/// # Ok(()) }
/// ```
#[derive(Debug)]
pub struct OutputFile {
    // Declared before `kind`: the file is closed before its temporary is removed.
    sink: BufWriter<Sink>,
    kind: Kind,
    /// The path as the caller gave it (`-` for standard output), for messages.
    label: PathBuf,
}

#[derive(Debug)]
enum Kind {
    /// Written into `temporary`, renamed onto `target` (the resolved regular file) at the end.
    Replace {
        temporary: Temporary,
        target: PathBuf,
    },
    /// A device node, FIFO, socket or descriptor path, written as it comes.
    Direct,
    Stdout,
}

#[derive(Debug)]
enum Sink {
    File(File),
    Stdout(Stdout),
}

impl Write for Sink {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        match self {
            Sink::File(file) => file.write(bytes),
            Sink::Stdout(stdout) => stdout.write(bytes),
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Sink::File(file) => file.flush(),
            Sink::Stdout(stdout) => stdout.flush(),
        }
    }
}

impl OutputFile {
    /// Opens `path` for writing (`None` or `-`: standard output).
    ///
    /// Errors: [`IoError::Write`] naming `path` when it is a folder, a loop of links, or when the
    /// temporary file or the device cannot be opened (a missing folder, no permission).
    pub fn create(path: Option<&Path>) -> Result<Self, IoError> {
        let Some(path) = path.filter(|p| p.as_os_str() != "-") else {
            return Ok(Self {
                sink: BufWriter::with_capacity(BUFFER_BYTES, Sink::Stdout(std::io::stdout())),
                kind: Kind::Stdout,
                label: "-".into(),
            });
        };
        let error = |source| IoError::Write {
            path: path.to_path_buf(),
            source,
        };
        let (file, kind) = match resolve(path).map_err(error)? {
            Destination::Regular(target) => {
                let (file, temporary) = Temporary::create(&target).map_err(error)?;
                (file, Kind::Replace { temporary, target })
            }
            Destination::Direct => {
                // No `create`: a device node or FIFO exists already; no `truncate`: it has no
                // length to cut, and a descriptor path shares its file with the caller's shell.
                let file = OpenOptions::new().write(true).open(path).map_err(error)?;
                (file, Kind::Direct)
            }
        };
        Ok(Self {
            sink: BufWriter::with_capacity(BUFFER_BYTES, Sink::File(file)),
            kind,
            label: path.to_path_buf(),
        })
    }

    /// Whether written bytes reach their destination before [`finish`](Self::finish): standard
    /// output, a device node, a FIFO. A command that promises to write nothing on bad input must
    /// then check all of its input first.
    pub fn streams(&self) -> bool {
        !matches!(self.kind, Kind::Replace { .. })
    }

    /// The path as given (`-` for standard output).
    pub fn label(&self) -> &Path {
        &self.label
    }

    /// An [`IoError::Write`] naming this output, for a failed [`Write`] call.
    pub fn write_error(&self, source: std::io::Error) -> IoError {
        IoError::Write {
            path: self.label.clone(),
            source,
        }
    }

    /// Completes the output: flushes it and, for a regular file, syncs the temporary file to disk
    /// and renames it onto the target, so the target appears whole or not at all.
    ///
    /// Errors: [`IoError::Write`] naming the output when flushing (a full device: `ENOSPC`),
    /// syncing or renaming fails; the temporary file is then removed and the target left as it
    /// was.
    pub fn finish(self) -> Result<(), IoError> {
        let Self { sink, kind, label } = self;
        let error = |source| IoError::Write {
            path: label.clone(),
            source,
        };
        let sink = sink.into_inner().map_err(|e| error(e.into_error()))?;
        match (sink, kind) {
            (Sink::File(file), Kind::Replace { temporary, target }) => {
                file.sync_all().map_err(error)?;
                drop(file);
                temporary.rename_onto(&target).map_err(error)
            }
            (mut sink, _) => sink.flush().map_err(error),
        }
    }
}

impl Write for OutputFile {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        self.sink.write(bytes)
    }

    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.sink.write_all(bytes)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.sink.flush()
    }
}

/// Writes `bytes` to `path` whole or not at all (see [`OutputFile`]): a regular file or new path
/// through a temporary file renamed over it, a device node or FIFO directly.
///
/// Errors: [`IoError::Write`] naming `path`; a failed write leaves `path` as it was and no
/// temporary file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let mut output = OutputFile::create(Some(path))?;
    output
        .write_all(bytes)
        .map_err(|source| output.write_error(source))?;
    output.finish()
}

/// What an output path is, once its links are followed.
enum Destination {
    /// A regular file or a path where none exists yet: replace it by renaming.
    Regular(PathBuf),
    /// Anything that must be written in place.
    Direct,
}

fn resolve(path: &Path) -> std::io::Result<Destination> {
    if is_descriptor_path(path) {
        return Ok(Destination::Direct);
    }
    let mut current = path.to_path_buf();
    for _ in 0..MAX_LINKS {
        let metadata = match std::fs::symlink_metadata(&current) {
            Ok(metadata) => metadata,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Ok(Destination::Regular(current));
            }
            Err(e) => return Err(e),
        };
        let kind = metadata.file_type();
        if kind.is_symlink() {
            let link = std::fs::read_link(&current)?;
            current = match current.parent() {
                Some(dir) => dir.join(link),
                None => link,
            };
            if is_descriptor_path(&current) {
                return Ok(Destination::Direct);
            }
        } else if kind.is_file() {
            return Ok(Destination::Regular(current));
        } else if kind.is_dir() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::IsADirectory,
                "is a folder, not a file",
            ));
        } else {
            return Ok(Destination::Direct);
        }
    }
    Err(std::io::Error::other(format!(
        "more than {MAX_LINKS} symbolic links to follow (a loop?)"
    )))
}

/// `/dev/stdout`, `/dev/stderr`, `/dev/stdin`, `/dev/fd/N`, `/proc/self/fd/N`, `/proc/PID/fd/N`:
/// names of an open descriptor, whose link target (`pipe:[…]`, a terminal, the shell's file) is
/// not a path to rename onto.
fn is_descriptor_path(path: &Path) -> bool {
    let Some(text) = path.to_str() else {
        return false;
    };
    matches!(text, "/dev/stdout" | "/dev/stderr" | "/dev/stdin")
        || text.starts_with("/dev/fd/")
        || (text.starts_with("/proc/") && text.contains("/fd/"))
}

/// Paths of the temporary files alive in this process.
static TEMPORARIES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn temporaries() -> MutexGuard<'static, Vec<PathBuf>> {
    // A writer that panicked while holding the lock left the list intact: take it.
    TEMPORARIES
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Removes every temporary file of this process and keeps any other from being created, renamed or
/// removed afterwards: writers that try wait for ever. For a handler that ends the process right
/// after (an interrupted command leaves no partial file behind).
pub fn remove_temporaries() {
    let guard = temporaries();
    for path in guard.iter() {
        let _ = std::fs::remove_file(path);
    }
    // Held until the process exits: no writer can create or rename a file from now on.
    std::mem::forget(guard);
}

/// A registered temporary file beside its target, removed when dropped unless renamed.
#[derive(Debug)]
struct Temporary {
    path: PathBuf,
    renamed: bool,
}

impl Temporary {
    /// Creates `.NAME.PID.N.tmp` beside `target` (same folder, so the rename is atomic), with the
    /// permissions of `target` when it exists.
    fn create(target: &Path) -> std::io::Result<(File, Self)> {
        let path = temporary_path(target);
        let mut list = temporaries();
        let file = File::create(&path)?;
        list.push(path.clone());
        drop(list);
        let temporary = Self {
            path,
            renamed: false,
        };
        if let Ok(metadata) = std::fs::metadata(target) {
            file.set_permissions(metadata.permissions())?;
        }
        Ok((file, temporary))
    }

    fn rename_onto(mut self, target: &Path) -> std::io::Result<()> {
        let mut list = temporaries();
        std::fs::rename(&self.path, target)?;
        self.renamed = true;
        list.retain(|p| p != &self.path);
        Ok(())
    }
}

impl Drop for Temporary {
    fn drop(&mut self) {
        if !self.renamed {
            let mut list = temporaries();
            let _ = std::fs::remove_file(&self.path);
            list.retain(|p| p != &self.path);
        }
    }
}

/// A fresh name for a temporary file beside `path` (same folder, so a rename onto `path` is
/// atomic): `.NAME.PID.N.tmp`, unique per process and call, so concurrent writers never share one.
fn temporary_path(path: &Path) -> PathBuf {
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::{FileTypeExt, PermissionsExt, symlink};

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
        // A folder is refused before anything is written.
        let folder = dir.path().join("taken");
        std::fs::create_dir(&folder).unwrap();
        std::fs::write(folder.join("inside.txt"), "keep").unwrap();
        let error = write_atomic(&folder, b"x").unwrap_err();
        assert!(error.to_string().contains("folder"), "{error}");
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

    #[test]
    fn a_symlink_stays_a_link_and_its_file_is_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let real = dir.path().join("real.txt");
        let link = dir.path().join("link.txt");
        std::fs::write(&real, "old").unwrap();
        std::fs::set_permissions(&real, std::fs::Permissions::from_mode(0o640)).unwrap();
        symlink("real.txt", &link).unwrap();
        // A chain of two links, relative and absolute.
        let link2 = dir.path().join("link2.txt");
        symlink(&link, &link2).unwrap();
        write_atomic(&link2, b"new").unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert!(
            std::fs::symlink_metadata(&link2)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(std::fs::read_to_string(&real).unwrap(), "new");
        let mode = std::fs::metadata(&real).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o640, "permissions kept");
        assert_eq!(names(dir.path()), ["link.txt", "link2.txt", "real.txt"]);
    }

    #[test]
    fn a_dangling_symlink_creates_its_target() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("link.txt");
        symlink("made.txt", &link).unwrap();
        write_atomic(&link, b"hello").unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(
            std::fs::read_to_string(dir.path().join("made.txt")).unwrap(),
            "hello"
        );
    }

    #[test]
    fn a_symlink_loop_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        symlink("b", dir.path().join("a")).unwrap();
        symlink("a", dir.path().join("b")).unwrap();
        let error = write_atomic(&dir.path().join("a"), b"x").unwrap_err();
        assert!(error.to_string().contains("symbolic links"), "{error}");
        assert_eq!(names(dir.path()), ["a", "b"]);
    }

    #[test]
    fn a_fifo_is_written_in_place() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe");
        let status = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(status.success());
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(&fifo).unwrap())
        };
        let mut out = OutputFile::create(Some(&fifo)).unwrap();
        assert!(out.streams());
        out.write_all(b"through the pipe").unwrap();
        out.finish().unwrap();
        assert_eq!(reader.join().unwrap(), b"through the pipe");
        assert!(
            std::fs::symlink_metadata(&fifo)
                .unwrap()
                .file_type()
                .is_fifo()
        );
        assert_eq!(names(dir.path()), ["pipe"]);
    }

    /// The device node tests need `mknod`, that is root (CI and these machines run as root); as a
    /// user they check the system's own `/dev/null` and `/dev/full` instead, which are writable.
    fn device(dir: &Path, name: &str, major: u32, minor: u32) -> PathBuf {
        let path = dir.join(name);
        let made = std::process::Command::new("mknod")
            .arg(&path)
            .args(["c", &major.to_string(), &minor.to_string()])
            .stderr(std::process::Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if made {
            path
        } else {
            PathBuf::from(format!("/dev/{name}"))
        }
    }

    #[test]
    fn a_device_node_is_written_not_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let null = device(dir.path(), "null", 1, 3);
        let out = OutputFile::create(Some(&null)).unwrap();
        assert!(out.streams());
        write_atomic(&null, b"into the void").unwrap();
        assert!(
            std::fs::symlink_metadata(&null)
                .unwrap()
                .file_type()
                .is_char_device(),
            "{} is still a device node",
            null.display()
        );
        drop(out);
        // A link onto the device node is followed to it and writes it in place.
        let link = dir.path().join("to-null");
        symlink(&null, &link).unwrap();
        write_atomic(&link, b"x").unwrap();
        assert!(
            std::fs::symlink_metadata(&null)
                .unwrap()
                .file_type()
                .is_char_device()
        );
        assert!(names(dir.path()).iter().all(|n| !n.ends_with(".tmp")));
    }

    #[test]
    fn a_full_device_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let full = device(dir.path(), "full", 1, 7);
        let error = write_atomic(&full, &vec![b'x'; 200_000]).unwrap_err();
        assert!(matches!(error, IoError::Write { .. }), "{error}");
        assert!(
            error.to_string().contains(&full.display().to_string()),
            "{error}"
        );
        assert!(
            std::fs::symlink_metadata(&full)
                .unwrap()
                .file_type()
                .is_char_device()
        );
    }

    #[test]
    fn descriptor_paths_are_written_in_place() {
        assert!(is_descriptor_path(Path::new("/dev/stdout")));
        assert!(is_descriptor_path(Path::new("/dev/fd/63")));
        assert!(is_descriptor_path(Path::new("/proc/self/fd/1")));
        assert!(!is_descriptor_path(Path::new("/tmp/fd/x")));
    }

    #[test]
    fn removed_temporaries_are_gone() {
        // Not `remove_temporaries` itself (it blocks every writer for ever): the registry it reads.
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.csv");
        let out = OutputFile::create(Some(&target)).unwrap();
        let Kind::Replace { temporary, .. } = &out.kind else {
            panic!("a new path is replaced");
        };
        assert!(temporaries().contains(&temporary.path));
        assert!(temporary.path.exists());
        let temporary = temporary.path.clone();
        drop(out);
        assert!(!temporaries().contains(&temporary));
        assert_eq!(names(dir.path()), Vec::<String>::new());
    }
}
