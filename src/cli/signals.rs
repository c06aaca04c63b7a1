//! How the process ends when it is told to stop, or when its reader goes away.
//!
//! - SIGINT (Ctrl-C), SIGTERM and SIGHUP: one handler for every command removes every temporary
//!   file that a writer has open ([`flatport::io::remove_temporaries`]), so an interrupted command
//!   leaves neither a partial output nor a `.NAME.PID.N.tmp` behind, and exits with 128 + the
//!   signal's number, as a shell reports a command killed by it.
//! - A closed standard output (`flatport project … | head`): Rust ignores SIGPIPE, so the write
//!   fails with `EPIPE`; the command then removes its temporaries and exits quietly with 141
//!   (128 + SIGPIPE), as Unix tools killed by SIGPIPE do, without an error message.

use std::io::Write;

use signal_hook::consts::{SIGHUP, SIGINT, SIGPIPE, SIGTERM};
use signal_hook::iterator::Signals;

/// Installs the handler (once, first thing in `main`). When it cannot be installed the signals
/// keep their default action, which ends the process without removing temporaries.
pub fn install() {
    let Ok(mut signals) = Signals::new([SIGINT, SIGTERM, SIGHUP]) else {
        return;
    };
    std::thread::spawn(move || {
        if let Some(signal) = signals.forever().next() {
            flatport::io::remove_temporaries();
            let name = match signal {
                SIGINT => "SIGINT",
                SIGTERM => "SIGTERM",
                _ => "SIGHUP",
            };
            let _ = writeln!(
                std::io::stderr(),
                "\ninterrupted by {name}: partial outputs removed"
            );
            std::process::exit(128 + signal);
        }
    });
}

/// Whether `error` (or one of its causes) is a write onto a closed pipe.
pub fn is_broken_pipe(error: &anyhow::Error) -> bool {
    error.chain().any(|cause| {
        cause
            .downcast_ref::<std::io::Error>()
            .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
            || cause
                .downcast_ref::<flatport::io::IoError>()
                .is_some_and(|e| {
                    matches!(e, flatport::io::IoError::Write { source, .. }
                        if source.kind() == std::io::ErrorKind::BrokenPipe)
                })
    })
}

/// Ends the process as a Unix tool whose reader went away: temporaries removed, no message,
/// exit status 128 + SIGPIPE.
pub fn exit_on_broken_pipe() -> ! {
    flatport::io::remove_temporaries();
    std::process::exit(128 + SIGPIPE)
}

/// Writes formatted text to standard output; a closed pipe ends the process quietly
/// ([`exit_on_broken_pipe`]). Used by `outln!` instead of `println!`,
/// which panics there.
pub fn print_stdout(args: std::fmt::Arguments) {
    let mut stdout = std::io::stdout().lock();
    if let Err(error) = stdout.write_fmt(args).and_then(|()| stdout.flush()) {
        if error.kind() == std::io::ErrorKind::BrokenPipe {
            exit_on_broken_pipe();
        }
        let _ = writeln!(
            std::io::stderr(),
            "error: cannot write to standard output: {error}"
        );
        flatport::io::remove_temporaries();
        std::process::exit(1);
    }
}
