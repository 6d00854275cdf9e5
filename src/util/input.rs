//! The one input gate: every file the tool reads goes through
//! [`read_bytes_capped`] or [`read_text_capped`].
//!
//! - Only regular files are read (symlinks are followed first): devices
//!   such as `/dev/zero`, FIFOs, sockets and directories are refused before
//!   they are opened, so a FIFO cannot block the reader.
//! - The size cap is enforced on the bytes actually read (`take(cap + 1)`),
//!   not on the metadata, which is 0 for devices and may change while the
//!   file is read.
//! - Text files are UTF-8 (a UTF-8 byte-order mark is allowed and
//!   dropped) or UTF-16 (with or without a byte-order mark), decoded; CR-only
//!   line ends read as line ends.

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

/// `bytes` as text: UTF-8 (a byte-order mark dropped), or UTF-16 (by its
/// byte-order mark, or without one by the NUL bytes between ASCII
/// characters, as spreadsheets' "Unicode text" writes it) decoded; classic
/// Mac line ends (CR only) read as line ends. An error names the line of
/// the first byte that is not text (a NUL is not).
pub fn decode_utf8(path: &Path, mut bytes: Vec<u8>) -> Result<String> {
    if let Some(big_endian) = utf16_order(&bytes) {
        return decode_utf16(path, &bytes, big_endian).map(mac_line_ends);
    }
    if bytes.starts_with(&[0xEF, 0xBB, 0xBF]) {
        bytes.drain(..3);
    }
    if let Some(at) = bytes.iter().position(|&b| b == 0) {
        let line = 1 + bytes[..at].iter().filter(|&&b| b == b'\n').count();
        return Err(Error::parse(
            path,
            format!("line {line}"),
            "file holds a NUL byte: not UTF-8 or UTF-16 text",
        ));
    }
    String::from_utf8(bytes).map(mac_line_ends).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let line = 1 + e.as_bytes()[..at].iter().filter(|&&b| b == b'\n').count();
        Error::parse(path, format!("line {line}"), "file is not valid UTF-8 text")
    })
}

/// UTF-16 and its byte order (`true`: big-endian): a byte-order mark, or
/// no mark and a NUL in every other byte of the first characters.
fn utf16_order(bytes: &[u8]) -> Option<bool> {
    if bytes.starts_with(&[0xFF, 0xFE]) {
        return Some(false);
    }
    if bytes.starts_with(&[0xFE, 0xFF]) {
        return Some(true);
    }
    let head = &bytes[..bytes.len().min(64) & !1];
    if head.len() < 4 || bytes.len() % 2 != 0 {
        return None;
    }
    let nul_at = |k: usize| head.chunks_exact(2).all(|c| c[k] == 0 && c[1 - k] != 0);
    if nul_at(1) {
        Some(false)
    } else if nul_at(0) {
        Some(true)
    } else {
        None
    }
}

/// UTF-16 bytes (a byte-order mark dropped) as a string; an unpaired
/// surrogate is an error naming its line.
fn decode_utf16(path: &Path, bytes: &[u8], big_endian: bool) -> Result<String> {
    if bytes.len() % 2 != 0 {
        return Err(Error::parse(
            path,
            "file",
            "UTF-16 text of an odd number of bytes: truncated",
        ));
    }
    let units = bytes.chunks_exact(2).map(|c| {
        if big_endian {
            u16::from_be_bytes([c[0], c[1]])
        } else {
            u16::from_le_bytes([c[0], c[1]])
        }
    });
    let mut text = String::with_capacity(bytes.len() / 2);
    for c in char::decode_utf16(units) {
        match c {
            Ok('\u{FEFF}') if text.is_empty() => {}
            Ok('\0') | Err(_) => {
                let line = 1 + text.matches('\n').count();
                return Err(Error::parse(
                    path,
                    format!("line {line}"),
                    "file is not valid UTF-16 text",
                ));
            }
            Ok(c) => text.push(c),
        }
    }
    Ok(text)
}

/// Text whose lines end in CR alone (no LF anywhere) with LF line ends.
fn mac_line_ends(text: String) -> String {
    if text.contains('\r') && !text.contains('\n') {
        text.replace('\r', "\n")
    } else {
        text
    }
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
        assert_eq!(decode_utf8(p, b"\xFF\xFEa\0,\0".to_vec()).unwrap(), "a,");
        assert_eq!(decode_utf8(p, b"\0a\0,\0b\0\n".to_vec()).unwrap(), "a,b\n");
        assert_eq!(
            decode_utf8(p, b"a,b\rc,d\r".to_vec()).unwrap(),
            "a,b\nc,d\n"
        );
        assert_eq!(decode_utf8(p, b"a\r\nb".to_vec()).unwrap(), "a\r\nb");
        let e = decode_utf8(p, b"ab\ncd\0".to_vec())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 2") && e.contains("NUL") && !e.contains('\0'),
            "{e}"
        );
    }
}
