//! Standard output that a departed reader cannot crash.
//!
//! `println!` panics when stdout is a pipe whose reader has gone (`fusiondet eval … | head -3`),
//! which would also abandon the files the command was still to write. [`outln!`] and [`out!`]
//! drop what cannot be written instead: the command finishes its files and exits as it would
//! have. A write that fails for another reason (a full disk behind a redirection) is said once
//! on stderr.

use std::fmt::Arguments;
use std::io::{ErrorKind, Write};
use std::sync::atomic::{AtomicBool, Ordering};

/// Set once stdout has refused a write: later text is dropped without another attempt.
static STDOUT_GONE: AtomicBool = AtomicBool::new(false);

/// Writes `args` to stdout, dropping it when stdout can no longer be written.
pub fn write_stdout(args: Arguments<'_>) {
    if STDOUT_GONE.load(Ordering::Relaxed) {
        return;
    }
    let mut stdout = std::io::stdout().lock();
    if let Err(err) = stdout.write_fmt(args).and_then(|()| stdout.flush()) {
        STDOUT_GONE.store(true, Ordering::Relaxed);
        if err.kind() != ErrorKind::BrokenPipe {
            eprintln!("warning: standard output failed ({err}); further output dropped");
        }
    }
}

/// Whether stdout has refused a write (the reader left, or the disk behind it is full).
pub fn stdout_gone() -> bool {
    STDOUT_GONE.load(Ordering::Relaxed)
}

/// `println!` that survives a closed stdout (see the module documentation).
#[macro_export]
macro_rules! outln {
    () => {
        $crate::console::write_stdout(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::console::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `print!` that survives a closed stdout (see the module documentation).
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::console::write_stdout(format_args!($($arg)*))
    };
}
