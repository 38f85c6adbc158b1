//! Triangle and tetrahedral meshes for softcap.
//!
//! | module | what |
//! |---|---|
//! | [`types`] | [`TriMesh`], [`TetMesh`] |
//! | [`structured`] | structured tet meshing of boxes |
//! | [`io`] | OBJ, PLY (ASCII/binary), Gmsh 4.1 `.msh`, TetGen `.node`/`.ele` readers and writers |
//! | [`refine`] | uniform 1 → 8 (red) refinement of tet meshes |
//! | [`refine_local`] | conforming local refinement inside balls by longest-edge bisection (Rivara 1991) |
//! | [`triangulate`](mod@triangulate) | ear-clipping of polygons |
//! | [`adjacency`] | one-rings, vertex→elements, tet face/vertex adjacency, [`SurfaceMap`] |
//! | [`laplacian`] | cotangent Laplacian + mixed Voronoi areas (thesis eq. 3.4–3.5), bi-Laplacian, umbrella graph Laplacian (bickel2009 eq. 9) |
//! | [`raycast`] | first hit of a ray on a triangle surface, occlusion tests (parry3d BVH): depth rendering, visibility |
//! | [`embed`] | barycentric embedding in tets / closest points on triangles, AABB tree ([`bvh`]) |
//! | [`validate`] | validity checks ([`ValidationSettings`]), orientation repair, unit scaling |
//! | [`shell`] | bi-Laplacian linear shell with handles (thesis eq. 5.1) |
//! | [`quality`] | dihedral angles, inverted tets, radius-ratio aspect ([`TetQuality`]) |
//! | [`layer`] | a tet layer under a surface (offset along smoothed inward normals, conforming prism split) |
//! | [`error`] | [`MeshError`] |
//!
//! ```
//! use softcap_mesh::{box_tet_mesh, icosphere, CotanLaplacian, TetLocator, ValidationSettings};
//! use softcap_mesh::nalgebra::Vector3;
//! let mesh = box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [4, 4, 2]);
//! assert_eq!(mesh.tets.len(), 4 * 4 * 2 * 6);
//! assert!((mesh.volume() - 0.04 * 0.04 * 0.02).abs() < 1e-12);
//! mesh.validate(&ValidationSettings::default()).unwrap();
//!
//! // Embed a point: barycentric weights reproduce it.
//! let p = Vector3::new(0.013, 0.021, 0.007);
//! let e = TetLocator::new(&mesh).locate(&p).unwrap();
//! assert_eq!(e.distance, 0.0);
//! assert!((e.position(&mesh.tets, &mesh.vertices) - p).norm() < 1e-15);
//!
//! // Cotangent Laplacian on the unit sphere: Δ(xy) ≈ −6·xy.
//! let sphere = icosphere(3);
//! let lap = CotanLaplacian::new(&sphere).unwrap();
//! let f: Vec<f64> = sphere.vertices.iter().map(|v| v.x * v.y).collect();
//! let df = lap.apply(&f);
//! let err = df.iter().zip(&f).map(|(d, f)| (d + 6.0 * f).abs()).fold(0.0, f64::max);
//! assert!(err < 0.1);
//! ```

pub mod adjacency;
pub mod bvh;
pub mod embed;
pub mod error;
pub mod io;
pub mod laplacian;
pub mod layer;
pub mod quality;
pub mod raycast;
pub mod refine;
pub mod refine_local;
pub mod structured;
pub mod triangulate;
pub mod types;
pub mod validate;

pub use adjacency::{
    SurfaceMap, tet_face_adjacency, tet_face_neighbors, tet_vertex_adjacency, vertex_elements,
    vertex_vertices,
};
pub use bvh::Bvh;
pub use embed::{
    TetEmbedding, TetLocator, TriEmbedding, TriLocator, closest_point_on_triangle, embed_in_tets,
    embed_on_triangles, line_triangle, tet_barycentric,
};
pub use error::{MeshError, Result};
pub use faer;
pub use io::msh::{MshMesh, read_msh, read_msh_from, read_msh_tet_mesh, write_msh};
pub use io::obj::{
    ObjMesh, read_obj, read_obj_from, read_obj_tri_mesh, write_obj, write_tri_mesh_obj,
};
pub use io::ply::{
    PlyFormat, PlyMesh, read_ply, read_ply_from, read_ply_tri_mesh, write_ply, write_tri_mesh_ply,
};
pub use io::tetgen::{read_tetgen, read_tetgen_from, write_tetgen};
pub use laplacian::{
    CotanLaplacian, cotan_laplacian, mass_matrix, sparse_from_triplets, sparse_mul_vec,
    umbrella_laplacian, voronoi_areas,
};
pub use layer::{LayerSettings, extrude_layer, smoothed_vertex_normals};
pub use nalgebra;
pub use quality::{TetQuality, aspect_ratio, dihedral_angles, tet_quality};
pub use raycast::{RayHit, SurfaceRayCaster};
pub use refine::{RefinedTetMesh, refine_tets};
pub use refine_local::{RefineBall, refine_near};
pub use structured::{box_tet_mesh, icosphere};
pub use triangulate::triangulate_polygon;
pub use types::{TetMesh, TriMesh};
pub use validate::{CM_TO_M, MM_TO_M, ValidationSettings};
pub mod shell;
pub use shell::{LinearShell, ShellBasis, ShellError, ShellOrdering, ShellSettings};
