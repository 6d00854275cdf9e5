//! Console output that never panics: a closed stdout (`osim-spine info m |
//! head`) ends the process quietly with exit code 0, and a closed stderr
//! is ignored. Every command prints through [`crate::out!`],
//! [`crate::outln!`] and [`crate::errln!`] instead of `print!`/`println!`/
//! `eprintln!`, which panic on a broken pipe.

use std::io::Write;

/// Write formatted text to stdout; on a broken pipe (the reader went away)
/// exit quietly with code 0, on any other error exit with a one-line
/// message and code 1.
pub fn write_stdout(args: std::fmt::Arguments<'_>) {
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|_| out.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        let _ = writeln!(std::io::stderr(), "error: writing to stdout: {e}");
        std::process::exit(1);
    }
}

/// Write formatted text to stderr, ignoring errors (a closed stderr has no
/// one left to tell).
pub fn write_stderr(args: std::fmt::Arguments<'_>) {
    let _ = std::io::stderr().lock().write_fmt(args);
}

/// `print!` that never panics (see [`write_stdout`]).
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::util::output::write_stdout(format_args!($($arg)*))
    };
}

/// `println!` that never panics (see [`write_stdout`]).
#[macro_export]
macro_rules! outln {
    () => {
        $crate::util::output::write_stdout(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::util::output::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `eprintln!` that never panics (see [`write_stderr`]).
#[macro_export]
macro_rules! errln {
    () => {
        $crate::util::output::write_stderr(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::util::output::write_stderr(format_args!("{}\n", format_args!($($arg)*)))
    };
}
