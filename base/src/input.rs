//! The one way an input file is opened: only a regular file (through any links) is read. A
//! FIFO would block the open until a writer comes, and a device such as `/dev/zero` never
//! ends; given where a photo, a splat file, weights or a checkpoint is expected, each is
//! refused at once with what it is, before a byte is read.

use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

/// What `path` is when it is not a regular file, in words; None for a regular file. Errors
/// are the metadata's (a missing file, a dangling link).
pub fn not_regular(path: &Path) -> io::Result<Option<&'static str>> {
    let kind = std::fs::metadata(path)?.file_type();
    if kind.is_file() {
        return Ok(None);
    }
    Ok(Some(describe(&kind)))
}

#[cfg(unix)]
fn describe(kind: &std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if kind.is_dir() {
        "a folder"
    } else if kind.is_fifo() {
        "a named pipe (FIFO)"
    } else if kind.is_char_device() || kind.is_block_device() {
        "a device"
    } else if kind.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

#[cfg(not(unix))]
fn describe(kind: &std::fs::FileType) -> &'static str {
    if kind.is_dir() {
        "a folder"
    } else {
        "not a regular file"
    }
}

/// The error an input that is not a regular file gives.
fn refused(what: &str) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("{what}, not a regular file: inputs are read from files"),
    )
}

/// Opens an input for reading, refusing anything but a regular file before opening it.
pub fn open(path: &Path) -> io::Result<File> {
    if let Some(what) = not_regular(path)? {
        return Err(refused(what));
    }
    File::open(path)
}

/// Reads a whole input (see [`open`]).
pub fn read(path: &Path) -> io::Result<Vec<u8>> {
    let mut file = open(path)?;
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// Reads a whole input as UTF-8 text (see [`open`]).
pub fn read_to_string(path: &Path) -> io::Result<String> {
    let mut file = open(path)?;
    let mut text = String::new();
    file.read_to_string(&mut text)?;
    Ok(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_regular_files_are_read() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.bin");
        std::fs::write(&file, b"abc").unwrap();
        assert_eq!(read(&file).unwrap(), b"abc");
        let e = read(dir.path()).unwrap_err();
        assert!(e.to_string().contains("a folder"), "{e}");
        #[cfg(unix)]
        {
            // An endless device through a link, and a FIFO with no writer: refused at once.
            let link = dir.path().join("zero.ply");
            std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
            let e = read(&link).unwrap_err();
            assert!(e.to_string().contains("a device"), "{e}");
            let fifo = dir.path().join("pipe");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status();
            assert!(
                made.is_ok_and(|s| s.success()),
                "mkfifo (coreutils) made no FIFO"
            );
            let e = read_to_string(&fifo).unwrap_err();
            assert!(e.to_string().contains("FIFO"), "{e}");
        }
        assert!(read(&dir.path().join("missing")).is_err());
    }
}
