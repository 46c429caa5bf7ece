//! Reading input files without trusting them: the one way every nmat tool opens a file it reads
//! (map images, JPEG files to index, `.nmat` files).
//!
//! Only regular files are read (after following symlinks): a folder, a device such as
//! `/dev/zero`, a pipe or a socket is refused before it is read, so an endless input cannot fill
//! memory and a FIFO cannot block the process. A read never goes past the caller's limit.

use crate::EncodeError;
use std::fs::File;
use std::io::Read as _;
use std::path::Path;

/// Opens `path` for reading if it is a regular file; returns the file and its length in bytes.
///
/// The kind is checked before opening and again on the open handle (the path may have been
/// replaced in between). On Linux the file is opened non-blocking, so even a FIFO swapped in at
/// that moment is refused instead of waiting for a writer.
pub fn open_regular(path: &Path) -> Result<(File, u64), EncodeError> {
    let meta = std::fs::metadata(path).map_err(crate::error::io(path))?;
    check_kind(path, &meta)?;
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::fs::OpenOptionsExt as _;
        // Reads from a regular file ignore O_NONBLOCK; only the open of a FIFO is affected.
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(crate::error::io(path))?;
    let meta = file.metadata().map_err(crate::error::io(path))?;
    check_kind(path, &meta)?;
    Ok((file, meta.len()))
}

/// The whole of the regular file `path`, refused before reading if it is longer than `limit`
/// bytes, and never read past `limit` (a file that grows while it is read is refused too).
pub fn read_regular(path: &Path, limit: u64) -> Result<Vec<u8>, EncodeError> {
    let (file, len) = open_regular(path)?;
    let too_large = |size| EncodeError::FileTooLarge { path: path.to_path_buf(), size, limit };
    if len > limit {
        return Err(too_large(len));
    }
    let mut bytes = Vec::new();
    bytes.try_reserve_exact(len as usize).map_err(|_| too_large(len))?;
    // One byte more than the limit tells a file that grew past it from one that ends there.
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes).map_err(crate::error::io(path))?;
    if bytes.len() as u64 > limit {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

fn check_kind(path: &Path, meta: &std::fs::Metadata) -> Result<(), EncodeError> {
    let kind = if meta.is_file() {
        return Ok(());
    } else if meta.is_dir() {
        "a folder"
    } else {
        "a device, pipe or socket"
    };
    Err(EncodeError::NotAFile { path: path.to_path_buf(), kind })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_folders_and_fifos_are_refused_before_they_are_read() {
        let dir = std::env::temp_dir().join(format!("nmat-input-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let folder = read_regular(&dir, 1 << 20).unwrap_err();
        assert!(matches!(folder, EncodeError::NotAFile { kind: "a folder", .. }), "{folder}");
        #[cfg(unix)]
        {
            let zero = read_regular(Path::new("/dev/zero"), 1 << 20).unwrap_err();
            assert!(zero.to_string().contains("is a device, pipe or socket"), "{zero}");
            let fifo = dir.join("fifo");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status();
            if made.is_ok_and(|s| s.success()) {
                // Opening a FIFO for reading would wait for a writer forever.
                let e = read_regular(&fifo, 1 << 20).unwrap_err();
                assert!(matches!(e, EncodeError::NotAFile { .. }), "{e}");
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_over_the_limit_is_refused_and_one_at_the_limit_is_read() {
        let path = std::env::temp_dir().join(format!("nmat-input-{}.bin", std::process::id()));
        std::fs::write(&path, [7u8; 100]).unwrap();
        assert_eq!(read_regular(&path, 100).unwrap(), [7u8; 100]);
        let e = read_regular(&path, 99).unwrap_err();
        assert!(matches!(e, EncodeError::FileTooLarge { size: 100, limit: 99, .. }), "{e:?}");
        std::fs::remove_file(&path).unwrap();
    }
}
