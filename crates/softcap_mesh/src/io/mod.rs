//! Mesh file formats: Wavefront OBJ, PLY, Gmsh 4.1 `.msh`, TetGen `.node`/`.ele`.
//!
//! Every reader comes in two forms: `read_*(path)` and `read_*_from(reader, name)`, where
//! `name` is used in error messages. Writers write to `NAME.PID-N.tmp`, fsync and rename
//! ([`softcap_app::fs`]), so a failed write never leaves a file that looks finished.

pub mod msh;
pub mod obj;
pub mod ply;
pub mod tetgen;

use crate::error::{MeshError, Result};
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// Opens `path` for buffered reading, naming it in the error.
pub(crate) fn open(path: &Path) -> Result<BufReader<File>> {
    File::open(path)
        .map(BufReader::new)
        .map_err(|e| MeshError::io(path, e))
}

/// Writes `path` atomically ([`softcap_app::write_atomic_with`]: `NAME.PID-N.tmp`, fsync, rename).
pub(crate) fn write_atomic(
    path: &Path,
    body: impl FnOnce(&mut softcap_app::AtomicFile) -> std::io::Result<()>,
) -> Result<()> {
    softcap_app::write_atomic_with(path, body).map_err(|e| MeshError::io(path, e))
}

/// Parses the next whitespace token as `T`, or explains which field is missing or malformed.
pub(crate) fn field<'a, T: std::str::FromStr>(
    tokens: &mut impl Iterator<Item = &'a str>,
    what: &str,
) -> std::result::Result<T, String> {
    let tok = tokens.next().ok_or_else(|| format!("missing {what}"))?;
    tok.parse()
        .map_err(|_| format!("cannot parse {what} from {tok:?}"))
}
