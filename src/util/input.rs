//! The one input gate: every file the tool reads goes through
//! [`read_bytes_capped`] or [`read_text_capped`].
//!
//! - Only regular files are read (symlinks are followed first): devices
//!   such as `/dev/zero`, FIFOs, sockets and directories are refused before
//!   they are opened, so a FIFO cannot block the reader.
//! - The size cap is enforced on the bytes actually read (`take(cap + 1)`),
//!   not on the metadata, which is 0 for devices and may change while the
//!   file is read.
//! - Text files must be UTF-8 (a UTF-8 byte-order mark is allowed and
//!   dropped; UTF-16 is named as such).

use crate::error::{Error, Result};
use std::fs::File;
use std::io::Read;
use std::path::Path;

/// Size cap for tables, reports and configuration files read as text
/// (stiffness and ratio tables, truth CSVs, templates, generate reports).
pub const MAX_TABLE_BYTES: u64 = 64 * 1024 * 1024;

/// What a path is, when it is not a regular file (for the refusal message).
fn kind_of(ft: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if ft.is_char_device() || ft.is_block_device() {
            return "a device";
        }
        if ft.is_socket() {
            return "a socket";
        }
    }
    if ft.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

/// Refuse what is not a regular file (after following symlinks).
fn check_regular(path: &Path, meta: &std::fs::Metadata, what: &str) -> Result<()> {
    if meta.is_file() {
        return Ok(());
    }
    Err(Error::parse(
        path,
        "file",
        format!(
            "is {}; {what} must be regular files",
            kind_of(&meta.file_type())
        ),
    ))
}

/// Open a file without blocking (O_NONBLOCK on unix: a FIFO swapped in
/// after the type check cannot hang the open).
fn open_nonblocking(path: &Path) -> std::io::Result<File> {
    let mut opts = std::fs::OpenOptions::new();
    opts.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        opts.custom_flags(libc_o_nonblock());
    }
    opts.open(path)
}

/// `O_NONBLOCK` on Linux and the BSDs/macOS (no libc dependency).
#[cfg(unix)]
fn libc_o_nonblock() -> i32 {
    if cfg!(any(target_os = "linux", target_os = "android")) {
        0o4000
    } else {
        0x0004
    }
}

/// Read at most `cap` bytes of the regular file `path`; a longer file is
/// refused (`what` names the kind of file, e.g. "landmark files").
pub fn read_bytes_capped(path: &Path, cap: u64, what: &str) -> Result<Vec<u8>> {
    // Type check before opening: opening a FIFO would block.
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    check_regular(path, &meta, what)?;
    if meta.len() > cap {
        return Err(too_large(path, cap, what));
    }
    // Open, then check the opened file again (the path may have changed).
    let file = open_nonblocking(path).map_err(|e| Error::io(path, e))?;
    let meta = file.metadata().map_err(|e| Error::io(path, e))?;
    check_regular(path, &meta, what)?;
    // Cap on the bytes actually read.
    let mut bytes = Vec::with_capacity(meta.len().min(cap) as usize);
    file.take(cap.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > cap {
        return Err(too_large(path, cap, what));
    }
    Ok(bytes)
}

fn too_large(path: &Path, cap: u64, what: &str) -> Error {
    Error::parse(
        path,
        "file",
        format!(
            "larger than the {} limit ({what} are limited to that size); refusing to read it",
            human(cap)
        ),
    )
}

/// `cap` in the largest whole binary unit (bytes, KB, MB, GB of 1024).
fn human(cap: u64) -> String {
    for (unit, size) in [("GB", 1u64 << 30), ("MB", 1 << 20), ("KB", 1 << 10)] {
        if cap >= size && cap % size == 0 {
            return format!("{} {unit}", cap / size);
        }
    }
    format!("{cap} bytes")
}

/// [`read_bytes_capped`], then the encoding check: UTF-8 text (a leading
/// byte-order mark is dropped); the error names the first bad line.
pub fn read_text_capped(path: &Path, cap: u64, what: &str) -> Result<String> {
    let bytes = read_bytes_capped(path, cap, what)?;
    decode_utf8(path, bytes)
}

/// `bytes` as UTF-8 text, or an error naming the line of the first bad byte
/// (and UTF-16 by its byte-order mark).
pub fn decode_utf8(path: &Path, mut bytes: Vec<u8>) -> Result<String> {
    if bytes.starts_with(&[0xFF, 0xFE]) || bytes.starts_with(&[0xFE, 0xFF]) {
        return Err(Error::parse(
            path,
            "line 1",
            "file is UTF-16 text; save it as UTF-8",
        ));
    }
    if bytes.starts_with(&[0xEF, 0xBB, 0xBF]) {
        bytes.drain(..3);
    }
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let line = 1 + e.as_bytes()[..at].iter().filter(|&&b| b == b'\n').count();
        Error::parse(path, format!("line {line}"), "file is not valid UTF-8 text")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_devices_directories_and_oversize() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_bytes_capped(dir.path(), 10, "test files").unwrap_err();
        assert!(e.to_string().contains("directory"), "{e}");
        #[cfg(unix)]
        {
            let e = read_bytes_capped(Path::new("/dev/zero"), 10, "test files").unwrap_err();
            assert!(e.to_string().contains("device"), "{e}");
            let link = dir.path().join("z.csv");
            std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
            let e = read_bytes_capped(&link, 10, "test files").unwrap_err();
            assert!(e.to_string().contains("z.csv"), "{e}");
        }
        let p = dir.path().join("big.txt");
        std::fs::write(&p, [b'a'; 11]).unwrap();
        assert!(read_bytes_capped(&p, 10, "test files").is_err());
        assert_eq!(read_bytes_capped(&p, 11, "test files").unwrap().len(), 11);
    }

    #[test]
    fn encoding_is_checked() {
        let p = Path::new("x.csv");
        assert_eq!(decode_utf8(p, b"\xEF\xBB\xBFa,b".to_vec()).unwrap(), "a,b");
        let e = decode_utf8(p, b"a\nb\xFF".to_vec()).unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
        assert!(decode_utf8(p, b"\xFF\xFEa\0".to_vec()).is_err());
    }
}
