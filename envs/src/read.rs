//! Reading a file named by outside input (a CLI argument, a config key, a job spec):
//! only a regular file is read. Opened non-blocking, so that a FIFO is refused by the
//! regular-file check instead of waiting for a writer (a plain open of a FIFO blocks);
//! a device such as `/dev/zero` is refused before it is read until memory runs out.

use std::fs::File;
use std::io::Read;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

/// Opens `path` for reading if it is a regular file (links followed).
pub fn open_regular(path: &Path) -> std::io::Result<File> {
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)?;
    if !file.metadata()?.is_file() {
        return Err(std::io::Error::other("not a regular file"));
    }
    Ok(file)
}

/// The whole of the regular file `path` (see [`open_regular`]).
pub fn read_regular(path: &Path) -> std::io::Result<Vec<u8>> {
    let mut file = open_regular(path)?;
    let mut bytes = Vec::with_capacity(file.metadata()?.len() as usize);
    file.read_to_end(&mut bytes)?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_and_fifos_are_refused_without_blocking_and_files_read() {
        let dir = tempfile::tempdir().expect("tmp");
        let fifo = dir.path().join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.expect("mkfifo").success());
        for path in [std::path::PathBuf::from("/dev/zero"), fifo] {
            let (tx, rx) = std::sync::mpsc::channel();
            let p = path.clone();
            std::thread::spawn(move || {
                let _ = tx.send(read_regular(&p).map_err(|e| e.to_string()));
            });
            let got = rx.recv_timeout(std::time::Duration::from_secs(20));
            let err = got
                .unwrap_or_else(|_| panic!("reading {} blocked", path.display()))
                .expect_err("not a regular file");
            assert_eq!(err, "not a regular file");
        }
        let file = dir.path().join("f");
        std::fs::write(&file, b"bytes").expect("write");
        assert_eq!(read_regular(&file).expect("read"), b"bytes");
    }
}
