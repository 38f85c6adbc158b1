//! Triangle and tetrahedral meshes for softcap.
//!
//! | module | what |
//! |---|---|
//! | [`types`] | [`TriMesh`], [`TetMesh`] |
//! | [`structured`] | structured tet meshing of boxes |
//! | [`io`] | OBJ, PLY (ASCII/binary), Gmsh 4.1 `.msh`, TetGen `.node`/`.ele` readers and writers |
//! | [`triangulate`] | ear-clipping of polygons |
//! | [`error`] | [`MeshError`] |
//!
//! ```
//! use softcap_mesh::box_tet_mesh;
//! let mesh = box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [4, 4, 2]);
//! assert_eq!(mesh.tets.len(), 4 * 4 * 2 * 6);
//! assert!((mesh.volume() - 0.04 * 0.04 * 0.02).abs() < 1e-12);
//! ```

pub mod error;
pub mod io;
pub mod structured;
pub mod triangulate;
pub mod types;

pub use error::{MeshError, Result};
pub use io::msh::{MshMesh, read_msh, read_msh_from, read_msh_tet_mesh, write_msh};
pub use io::obj::{
    ObjMesh, read_obj, read_obj_from, read_obj_tri_mesh, write_obj, write_tri_mesh_obj,
};
pub use io::ply::{
    PlyFormat, PlyMesh, read_ply, read_ply_from, read_ply_tri_mesh, write_ply, write_tri_mesh_ply,
};
pub use io::tetgen::{read_tetgen, read_tetgen_from, write_tetgen};
pub use nalgebra;
pub use structured::box_tet_mesh;
pub use triangulate::triangulate_polygon;
pub use types::{TetMesh, TriMesh};
pub mod shell;
pub use shell::{LinearShell, ShellBasis, ShellError, ShellSettings};
