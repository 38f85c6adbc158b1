//! Atomic output files: nothing half-written is ever left under an output's name.
//!
//! Every output goes to `NAME.tmp` in the same folder (so the rename cannot cross a file
//! system), is flushed and fsynced, renamed over `NAME`, and the folder is fsynced so the rename
//! itself survives a crash. A write that fails — or an [`AtomicFile`] dropped without
//! [`AtomicFile::commit`] — removes `NAME.tmp` and leaves any previous `NAME` untouched.

use std::fs::File;
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// The temporary file an atomic write fills: `dir/NAME` → `dir/NAME.tmp`.
///
/// An output path without a file name (`/`, `..`) is refused with `InvalidInput`.
pub fn tmp_path(path: &Path) -> io::Result<PathBuf> {
    let name = path
        .file_name()
        .filter(|_| !path.ends_with(".."))
        .ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                "an output path must name a file",
            )
        })?;
    let mut tmp = name.to_os_string();
    tmp.push(".tmp");
    Ok(path.with_file_name(tmp))
}

/// Writes `bytes` to `path` atomically (`NAME.tmp`, fsync, rename, fsync the folder).
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> io::Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Writes `path` atomically with `body` writing into a buffered `NAME.tmp`.
pub fn write_atomic_with(
    path: impl AsRef<Path>,
    body: impl FnOnce(&mut AtomicFile) -> io::Result<()>,
) -> io::Result<()> {
    let mut file = AtomicFile::create(path)?;
    body(&mut file)?;
    file.commit()
}

/// A buffered output file that appears under its name only when [`commit`](Self::commit)ted.
///
/// It is `Write + Seek`, so streaming writers (an MCAP writer, an image encoder) can fill it.
#[derive(Debug)]
pub struct AtomicFile {
    path: PathBuf,
    tmp: PathBuf,
    file: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Creates (or truncates) `NAME.tmp` next to `path`.
    pub fn create(path: impl AsRef<Path>) -> io::Result<Self> {
        let path = path.as_ref().to_path_buf();
        let tmp = tmp_path(&path)?;
        let file = File::create(&tmp)?;
        Ok(Self {
            path,
            tmp,
            file: Some(BufWriter::new(file)),
        })
    }

    /// The final path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The temporary path being written.
    pub fn tmp_path(&self) -> &Path {
        &self.tmp
    }

    /// Flushes, fsyncs, renames `NAME.tmp` over `NAME` and fsyncs the folder. On error the
    /// temporary file is removed.
    pub fn commit(mut self) -> io::Result<()> {
        let Some(buffered) = self.file.take() else {
            return Ok(());
        };
        let result = (|| {
            let file = buffered.into_inner().map_err(|e| e.into_error())?;
            file.sync_all()?;
            drop(file);
            std::fs::rename(&self.tmp, &self.path)?;
            sync_parent(&self.path);
            Ok(())
        })();
        if result.is_err() {
            let _ = std::fs::remove_file(&self.tmp);
        }
        result
    }

    fn inner(&mut self) -> &mut BufWriter<File> {
        self.file
            .as_mut()
            .expect("an AtomicFile is writable until commit() consumes it")
    }
}

/// Makes a rename durable: fsync the folder that holds `path` (best effort — not every platform
/// can open or fsync a directory, and the data itself is already synced).
fn sync_parent(path: &Path) {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.inner().write(buf)
    }

    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        self.inner().write_all(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.inner().flush()
    }
}

impl Seek for AtomicFile {
    fn seek(&mut self, pos: SeekFrom) -> io::Result<u64> {
        self.inner().seek(pos)
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if let Some(file) = self.file.take() {
            drop(file);
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tmp_path_appends_to_the_file_name() {
        assert_eq!(
            tmp_path(Path::new("out/a.mcap")).unwrap(),
            Path::new("out/a.mcap.tmp")
        );
        assert_eq!(tmp_path(Path::new("a")).unwrap(), Path::new("a.tmp"));
        assert!(tmp_path(Path::new("/")).is_err());
        assert!(tmp_path(Path::new("a/..")).is_err());
    }

    #[test]
    fn write_atomic_replaces_and_leaves_no_tmp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.json");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert!(!dir.path().join("x.json.tmp").exists());
    }

    #[test]
    fn a_failed_body_keeps_the_old_file_and_removes_the_tmp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.csv");
        write_atomic(&p, b"old").unwrap();
        let e = write_atomic_with(&p, |w| {
            w.write_all(b"half")?;
            Err(io::Error::other("encoder failed"))
        })
        .unwrap_err();
        assert_eq!(e.to_string(), "encoder failed");
        assert_eq!(std::fs::read(&p).unwrap(), b"old");
        assert!(!dir.path().join("x.csv.tmp").exists());
    }

    #[test]
    fn a_dropped_file_is_never_renamed() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("y.bin");
        let mut f = AtomicFile::create(&p).unwrap();
        f.write_all(b"abc").unwrap();
        f.seek(SeekFrom::Start(1)).unwrap();
        f.write_all(b"X").unwrap();
        assert!(f.tmp_path().exists());
        drop(f);
        assert!(!p.exists() && !dir.path().join("y.bin.tmp").exists());
        let mut f = AtomicFile::create(&p).unwrap();
        f.write_all(b"abc").unwrap();
        f.seek(SeekFrom::Start(1)).unwrap();
        f.write_all(b"X").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"aXc");
    }

    #[test]
    fn a_missing_folder_is_an_error_naming_nothing_written() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("no/such/dir/z.txt");
        let e = write_atomic(&p, b"z").unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::NotFound);
        assert!(!p.exists());
    }
}
