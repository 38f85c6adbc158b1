//! Atomic output files, and paths read from input files kept inside their folder.
//!
//! Every output goes to a temporary file `NAME.PID-N.tmp` in the same folder (so the rename
//! cannot cross a file system; unique per writer, so two processes writing the same output at
//! once never share one), is flushed and fsynced, renamed over `NAME`, and the folder is fsynced
//! so the rename itself survives a crash. A write that fails — or an [`AtomicFile`] dropped
//! without [`AtomicFile::commit`] — removes its temporary file and leaves any previous `NAME`
//! untouched. A process killed mid-write (SIGKILL, power loss) may leave its `*.tmp` file
//! behind, never a partial `NAME`; of two writers racing, the last rename wins whole.
//!
//! [`path_inside`] checks a file name that an input file (session.toml, target.toml) gives
//! relative to its own folder: no absolute path, no `..` out of the folder, no symlink out of it.

use std::fs::File;
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A fresh temporary file name for an atomic write of `path`: `dir/NAME` → `dir/NAME.PID-N.tmp`
/// (this process's id and a per-process counter, so no two writers share a temporary file).
///
/// An output path without a file name (`/`, `..`) is refused with `InvalidInput`.
pub fn tmp_path(path: &Path) -> io::Result<PathBuf> {
    static NEXT: AtomicU64 = AtomicU64::new(0);
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
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    tmp.push(format!(".{}-{n}.tmp", std::process::id()));
    Ok(path.with_file_name(tmp))
}

/// Whether `entry` is a temporary file of an atomic write of `path` (see [`tmp_path`]).
pub fn is_tmp_of(path: &Path, entry: &Path) -> bool {
    let (Some(name), Some(other)) = (path.file_name(), entry.file_name()) else {
        return false;
    };
    let (name, other) = (name.to_string_lossy(), other.to_string_lossy());
    entry.parent() == path.parent()
        && other
            .strip_prefix(name.as_ref())
            .and_then(|rest| rest.strip_prefix('.'))
            .and_then(|rest| rest.strip_suffix(".tmp"))
            .is_some_and(|id| id.split_once('-').is_some())
}

/// `folder/name` for a file name `name` that a file in `folder` gives (a session.toml's
/// `[files]`, a target.toml), or what is wrong with it: an absolute path, a `..` that leaves
/// the folder, or a path that resolves (symlinks followed) outside the folder.
pub fn path_inside(folder: &Path, name: &str) -> Result<PathBuf, String> {
    let relative = Path::new(name);
    let mut depth = 0usize;
    for c in relative.components() {
        match c {
            Component::Prefix(_) | Component::RootDir => {
                return Err(format!(
                    "`{name}` is an absolute path; name a file inside {}",
                    folder.display()
                ));
            }
            Component::ParentDir if depth == 0 => {
                return Err(format!(
                    "`{name}` leaves the folder {} (`..`)",
                    folder.display()
                ));
            }
            Component::ParentDir => depth -= 1,
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
        }
    }
    let joined = folder.join(relative);
    // Symlinks: the deepest existing ancestor's real path must stay inside the folder's.
    if let Ok(root) = folder.canonicalize() {
        let existing = joined.ancestors().find(|a| a.exists());
        if let Some(real) = existing.and_then(|a| a.canonicalize().ok())
            && !real.starts_with(&root)
        {
            return Err(format!(
                "`{name}` resolves to {} (through a symlink), outside the folder {}",
                real.display(),
                folder.display()
            ));
        }
    }
    Ok(joined)
}

/// Writes `bytes` to `path` atomically (temporary file, fsync, rename, fsync the folder).
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> io::Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Writes `path` atomically with `body` writing into a buffered temporary file.
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
    /// Creates a fresh temporary file ([`tmp_path`]) next to `path`.
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

    /// Flushes, fsyncs, renames the temporary file over `NAME` and fsyncs the folder. On error the
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

    /// No `*.tmp` file is left in `dir`.
    fn no_tmp(dir: &Path) -> bool {
        std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .all(|e| !e.file_name().to_string_lossy().ends_with(".tmp"))
    }

    #[test]
    fn tmp_path_appends_a_unique_suffix_to_the_file_name() {
        let out = Path::new("out/a.mcap");
        let (a, b) = (tmp_path(out).unwrap(), tmp_path(out).unwrap());
        assert_ne!(a, b);
        let pid = std::process::id();
        assert!(
            a.to_string_lossy()
                .starts_with(&format!("out/a.mcap.{pid}-"))
        );
        assert!(is_tmp_of(out, &a) && is_tmp_of(out, &b));
        assert!(!is_tmp_of(out, Path::new("out/a.mcap")));
        assert!(!is_tmp_of(out, Path::new("other/a.mcap.1-2.tmp")));
        assert!(tmp_path(Path::new("/")).is_err());
        assert!(tmp_path(Path::new("a/..")).is_err());
    }

    #[test]
    fn paths_from_input_files_stay_inside_their_folder() {
        let dir = tempfile::tempdir().unwrap();
        let session = dir.path().join("session");
        std::fs::create_dir_all(session.join("rig")).unwrap();
        std::fs::write(dir.path().join("secret.csv"), "x").unwrap();
        assert_eq!(
            path_inside(&session, "rig/cameras.toml").unwrap(),
            session.join("rig/cameras.toml")
        );
        assert!(path_inside(&session, "rig/../fsr.csv").is_ok());
        let e = path_inside(&session, "/etc/passwd").unwrap_err();
        assert!(e.contains("absolute"), "{e}");
        let e = path_inside(&session, "rig/../../secret.csv").unwrap_err();
        assert!(e.contains("leaves the folder"), "{e}");
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(dir.path(), session.join("up")).unwrap();
            let e = path_inside(&session, "up/secret.csv").unwrap_err();
            assert!(e.contains("symlink"), "{e}");
            std::os::unix::fs::symlink(session.join("rig"), session.join("rig2")).unwrap();
            assert!(path_inside(&session, "rig2/cameras.toml").is_ok());
        }
    }

    #[test]
    fn write_atomic_replaces_and_leaves_no_tmp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.json");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert!(no_tmp(dir.path()));
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
        assert!(no_tmp(dir.path()));
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
        assert!(!p.exists() && no_tmp(dir.path()));
        let mut f = AtomicFile::create(&p).unwrap();
        f.write_all(b"abc").unwrap();
        f.seek(SeekFrom::Start(1)).unwrap();
        f.write_all(b"X").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"aXc");
    }

    #[test]
    fn concurrent_writers_of_one_path_leave_one_whole_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("race.bin");
        let bodies: Vec<Vec<u8>> = (0..4u8).map(|k| vec![k; 1 << 20]).collect();
        std::thread::scope(|s| {
            for body in &bodies {
                let p = &p;
                s.spawn(move || {
                    for _ in 0..5 {
                        write_atomic(p, body).unwrap();
                    }
                });
            }
        });
        let got = std::fs::read(&p).unwrap();
        assert!(bodies.contains(&got), "a mixed or truncated file");
        assert!(no_tmp(dir.path()));
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
