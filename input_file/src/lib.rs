//! Every input file the project reads (specs, weights, models, layouts, worlds, schedules,
//! deploy.yaml, ONNX, logs) goes through [`read_capped`] or [`read_text_capped`]:
//! - the file is opened non-blocking, so a FIFO named as an input cannot hang `open()`;
//! - anything but a regular file (FIFO, character or block device, directory, socket) is refused,
//!   naming what it is, before a byte is read: `/dev/zero` is not read until memory runs out;
//! - a file over the caller's limit is refused before anything of its size is allocated.
//!
//! The error is an `std::io::Error` whose message is complete on its own (the OS reason appears
//! once): callers add the path and what the file is for.
pub mod text;

use std::fs::OpenOptions;
use std::io::{Error, ErrorKind, Read};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// Reads the whole of the regular file at `path`, of at most `max` bytes.
pub fn read_capped(path: &Path, max: u64) -> std::io::Result<Vec<u8>> {
    let too_large = |n: u64| {
        Error::new(
            ErrorKind::InvalidData,
            format!("{n} bytes or more is over the {max}-byte limit for this file"),
        )
    };
    // O_NONBLOCK: opening a FIFO for reading would otherwise wait for a writer forever. It changes
    // nothing for a regular file, the only kind read below.
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)?;
    let meta = file.metadata()?;
    let ty = meta.file_type();
    if !ty.is_file() {
        let what = if ty.is_dir() {
            "a directory"
        } else if ty.is_fifo() {
            "a FIFO (named pipe)"
        } else if ty.is_char_device() {
            "a character device"
        } else if ty.is_block_device() {
            "a block device"
        } else if ty.is_socket() {
            "a socket"
        } else {
            "not a regular file"
        };
        return Err(Error::new(
            ErrorKind::InvalidInput,
            format!("this is {what}, not a regular file: give the path of a file"),
        ));
    }
    let len = meta.len();
    if len > max {
        return Err(too_large(len));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// [`read_capped`] for UTF-8 text.
pub fn read_text_capped(path: &Path, max: u64) -> std::io::Result<String> {
    String::from_utf8(read_capped(path, max)?).map_err(|e| {
        Error::new(
            ErrorKind::InvalidData,
            format!(
                "not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("input-file-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_fifo_is_refused_without_blocking() {
        let dir = scratch("fifo");
        let fifo = dir.join("spec.toml");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path; mkfifo only creates a file system node.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = read_capped(&fifo, 1024).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::InvalidInput);
        assert!(e.to_string().contains("a FIFO (named pipe), not a regular file"), "{e}");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn devices_and_directories_are_refused_naming_what_they_are() {
        let e = read_capped(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert!(e.to_string().contains("a character device"), "{e}");
        let e = read_text_capped(Path::new("/"), 1 << 20).unwrap_err();
        assert_eq!(
            e.to_string(),
            "this is a directory, not a regular file: give the path of a file"
        );
    }

    #[test]
    fn size_cap_and_text() {
        let dir = scratch("cap");
        let f = dir.join("a");
        std::fs::write(&f, b"hello").unwrap();
        assert_eq!(read_text_capped(&f, 5).unwrap(), "hello");
        let e = read_capped(&f, 4).unwrap_err();
        assert!(e.to_string().contains("over the 4-byte limit"), "{e}");
        std::fs::write(&f, [0xff, 0xfe]).unwrap();
        assert!(read_text_capped(&f, 5).unwrap_err().to_string().contains("not UTF-8"));
        std::fs::remove_dir_all(dir).unwrap();
    }
}
