//! Small shared helpers: the input gate every reader goes through
//! ([`input`]), atomic output, deterministic number formatting,
//! reports at a stated precision ([`report`]), the one quantile helper
//! ([`quantiles`]), the one progress bar ([`progress`]) and the shared SVG
//! figures ([`svg`]).

pub mod guard;
pub mod input;
pub mod output;
pub mod progress;
pub mod quantiles;
pub mod report;
pub mod svg;

pub use input::{read_bytes_capped, read_text_capped};
pub use quantiles::{iqr, median, quantile};

use crate::error::{Error, Result};
use std::io::Write;
use std::path::Path;

/// Write `bytes` to `path` atomically: a temporary file in the same folder,
/// flushed and then renamed over `path`. Readers never see a half-written
/// file, and on error nothing is left behind.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let mut tmp = tempfile::Builder::new()
        .prefix(".osim-spine-")
        .suffix(".tmp")
        .tempfile_in(dir)
        .map_err(|e| Error::io(dir, e))?;
    tmp.write_all(bytes).map_err(|e| Error::io(path, e))?;
    tmp.as_file().sync_all().map_err(|e| Error::io(path, e))?;
    // tempfile creates its files 0600; an output is an ordinary file (0644).
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(tmp.path(), std::fs::Permissions::from_mode(0o644))
            .map_err(|e| Error::io(path, e))?;
    }
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

/// Format a float the way the project writes numbers into text files: the
/// shortest representation that reads back to the same f64 (Rust's `{}`),
/// with `-0` normalised to `0` so outputs are byte-stable.
pub fn fmt_f64(x: f64) -> String {
    if x == 0.0 {
        "0".to_string()
    } else {
        format!("{x}")
    }
}

/// `text` with every line whose first non-blank character is `#` made
/// empty (line ends kept), so a CSV reader that skips empty lines still
/// reports the file's own line numbers (the csv crate does not count
/// comment lines it skips itself).
pub fn blank_comment_lines(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for l in text.split_inclusive('\n') {
        if l.trim_start().starts_with('#') {
            if l.ends_with("\r\n") {
                out.push_str("\r\n");
            } else if l.ends_with('\n') {
                out.push('\n');
            }
        } else {
            out.push_str(l);
        }
    }
    out
}

/// The 1-based line of `text` on which a csv-crate record starts. The
/// crate's own `Position::line` miscounts CRLF files and skipped blank
/// lines, and its byte offset may point at the line end before the record:
/// count the newlines before the offset, then step over line ends.
pub fn csv_line(text: &str, pos: &csv::Position) -> u64 {
    let b = usize::try_from(pos.byte())
        .unwrap_or(usize::MAX)
        .min(text.len());
    let bytes = text.as_bytes();
    let mut line = bytes[..b].iter().filter(|&&c| c == b'\n').count() as u64 + 1;
    for &c in &bytes[b..] {
        match c {
            b'\n' => line += 1,
            b'\r' => {}
            _ => break,
        }
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        let n = std::fs::read_dir(dir.path()).unwrap().count();
        assert_eq!(n, 1, "temporary file left behind");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&p).unwrap().permissions().mode() & 0o777;
            assert_eq!(
                mode, 0o644,
                "outputs must be world-readable like any written file"
            );
        }
    }

    #[test]
    fn float_format_round_trips() {
        for x in [0.1, 1e-300, -2.5, 149000.0, std::f64::consts::PI] {
            assert_eq!(fmt_f64(x).parse::<f64>().unwrap(), x);
        }
        assert_eq!(fmt_f64(-0.0), "0");
    }

    #[test]
    fn csv_lines_are_the_file_lines() {
        for text in [
            "\r\nh,a\r\nx,1\r\n# c\r\n,\r\nz,3\r\n",
            "\nh,a\nx,1\n# c\n,\nz,3\n",
            "h,a\r\n\r\nx,1\r\n\r\n\r\n,\nz,3",
        ] {
            let blank = blank_comment_lines(text);
            // where each record starts, by hand: the line holding its first cell
            let want: Vec<u64> = blank
                .split('\n')
                .enumerate()
                .filter(|(_, l)| !l.trim_end_matches('\r').is_empty())
                .map(|(i, _)| i as u64 + 1)
                .collect();
            let mut r = csv::ReaderBuilder::new()
                .flexible(true)
                .has_headers(false)
                .from_reader(blank.as_bytes());
            let got: Vec<u64> = r
                .records()
                .map(|rec| csv_line(&blank, rec.unwrap().position().unwrap()))
                .collect();
            assert_eq!(got, want, "{text:?}");
        }
    }
}
