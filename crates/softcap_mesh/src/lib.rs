//! Triangle and tetrahedral meshes for softcap.
//!
//! | module | what |
//! |---|---|
//! | [`types`] | [`TriMesh`], [`TetMesh`] |
//! | [`structured`] | structured tet meshing of boxes |
//!
//! ```
//! use softcap_mesh::box_tet_mesh;
//! let mesh = box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [4, 4, 2]);
//! assert_eq!(mesh.tets.len(), 4 * 4 * 2 * 6);
//! assert!((mesh.volume() - 0.04 * 0.04 * 0.02).abs() < 1e-12);
//! ```

pub mod structured;
pub mod types;

pub use nalgebra;
pub use structured::box_tet_mesh;
pub use types::{TetMesh, TriMesh};
pub mod shell;
pub use shell::{LinearShell, ShellBasis, ShellError, ShellSettings};
