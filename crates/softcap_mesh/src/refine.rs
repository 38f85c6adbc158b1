//! Uniform refinement of tet meshes.
//!
//! [`refine_tets`] splits every tet into eight ("red" refinement, Bey 1995, *Tetrahedral grid
//! refinement*, Computing 55): a new node at every edge midpoint; four corner tets, each with one
//! original vertex and the midpoints of its three edges; the inner octahedron cut along its
//! shortest diagonal into four tets (the usual choice for well-shaped children). Every face is split into the same four triangles from both of its tets, so the
//! refined mesh is conforming whenever the input is, and it fills exactly the same volume.

use crate::types::TetMesh;
use std::collections::HashMap;

/// A refined tet mesh and where each of its pieces came from.
#[derive(Clone, Debug, PartialEq)]
pub struct RefinedTetMesh {
    /// The refined mesh. Vertices `0..n` are the input's vertices (same indices, same
    /// positions); the rest are edge midpoints. Tets are positively oriented.
    pub mesh: TetMesh,
    /// For every refined tet, the index of the input tet it lies in ([`refine_tets`]: eight
    /// children each, `8 t .. 8 t + 8`).
    pub parent_tet: Vec<usize>,
    /// For every vertex `n + k` (n input vertices), the edge [a, b] (a < b) whose midpoint it is.
    /// [`refine_tets`]: both are input vertices; [`crate::refine_near`]: either may be an
    /// earlier midpoint (a, b < n + k), so a property defined by "both endpoints" can be
    /// propagated in index order.
    pub midpoint_of: Vec<[usize; 2]>,
}

/// Splits every tet of `mesh` into eight (module docs). Degenerate input tets give degenerate
/// children; nothing else is checked.
pub fn refine_tets(mesh: &TetMesh) -> RefinedTetMesh {
    let n = mesh.vertices.len();
    let mut vertices = mesh.vertices.clone();
    let mut midpoint_of: Vec<[usize; 2]> = Vec::new();
    let mut index: HashMap<[usize; 2], usize> = HashMap::new();
    let mut tets = Vec::with_capacity(8 * mesh.tets.len());
    let mut parent_tet = Vec::with_capacity(8 * mesh.tets.len());
    for (t, tet) in mesh.tets.iter().enumerate() {
        // m[i][j]: the midpoint of edge (i, j) of this tet
        let mut m = [[usize::MAX; 4]; 4];
        for i in 0..4 {
            for j in i + 1..4 {
                let (a, b) = (tet[i].min(tet[j]), tet[i].max(tet[j]));
                let v = *index.entry([a, b]).or_insert_with(|| {
                    vertices.push((mesh.vertices[a] + mesh.vertices[b]) * 0.5);
                    midpoint_of.push([a, b]);
                    n + midpoint_of.len() - 1
                });
                m[i][j] = v;
                m[j][i] = v;
            }
        }
        let mut children: Vec<[usize; 4]> = (0..4)
            .map(|i| {
                let o: Vec<usize> = (0..4).filter(|&j| j != i).collect();
                [tet[i], m[i][o[0]], m[i][o[1]], m[i][o[2]]]
            })
            .collect();
        // The octahedron of the six midpoints: opposite pairs (01, 23), (02, 13), (03, 12).
        // Cut along the shortest diagonal; the other four midpoints form a cycle around it.
        let diagonals = [
            (m[0][1], m[2][3], [m[0][2], m[0][3], m[1][3], m[1][2]]),
            (m[0][2], m[1][3], [m[0][1], m[0][3], m[2][3], m[1][2]]),
            (m[0][3], m[1][2], [m[0][1], m[0][2], m[2][3], m[1][3]]),
        ];
        let length = |a: usize, b: usize| (vertices[a] - vertices[b]).norm_squared();
        let &(a, b, ring) = diagonals
            .iter()
            .min_by(|x, y| length(x.0, x.1).total_cmp(&length(y.0, y.1)))
            .expect("three diagonals");
        for i in 0..4 {
            children.push([a, b, ring[i], ring[(i + 1) % 4]]);
        }
        tets.extend(children);
        parent_tet.extend([t; 8]);
    }
    let mut refined = TetMesh { vertices, tets };
    refined.orient_positive();
    RefinedTetMesh {
        mesh: refined,
        parent_tet,
        midpoint_of,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::structured::box_tet_mesh;
    use crate::validate::ValidationSettings;

    #[test]
    fn eight_children_fill_each_parent_and_the_mesh_stays_conforming() {
        let mesh = box_tet_mesh([0.0, 0.0, 0.0], [0.04, 0.03, 0.02], [3, 2, 2]);
        let r = refine_tets(&mesh);
        assert_eq!(r.mesh.tets.len(), 8 * mesh.tets.len());
        assert_eq!(r.parent_tet.len(), r.mesh.tets.len());
        // the refined box is the structured box with twice the cells: same vertex count
        assert_eq!(r.mesh.vertices.len(), 7 * 5 * 5);
        assert_eq!(
            r.midpoint_of.len(),
            r.mesh.vertices.len() - mesh.vertices.len()
        );
        for t in 0..mesh.tets.len() {
            let v: f64 = (0..8).map(|c| r.mesh.tet_volume(8 * t + c)).sum();
            assert!((v - mesh.tet_volume(t)).abs() < 1e-12 * mesh.tet_volume(t).abs());
            assert!((0..8).all(|c| r.parent_tet[8 * t + c] == t));
        }
        for t in 0..r.mesh.tets.len() {
            // children are a positive fraction of their parent (corner tets 1/8)
            assert!(r.mesh.tet_volume(t) > 1e-3 * mesh.tet_volume(r.parent_tet[t]));
        }
        for (i, &[a, b]) in r.midpoint_of.iter().enumerate() {
            let mid = (mesh.vertices[a] + mesh.vertices[b]) * 0.5;
            assert!((r.mesh.vertices[mesh.vertices.len() + i] - mid).norm() < 1e-15);
        }
        // conforming: every interior face shared by exactly two tets, the boundary area equal
        r.mesh.validate(&ValidationSettings::default()).unwrap();
        let area = |m: &TetMesh| -> f64 {
            m.boundary_faces()
                .iter()
                .map(|f| {
                    let [a, b, c] = f.map(|i| m.vertices[i]);
                    0.5 * (b - a).cross(&(c - a)).norm()
                })
                .sum()
        };
        assert!((area(&r.mesh) - area(&mesh)).abs() < 1e-12);
        assert_eq!(
            r.mesh.boundary_faces().len(),
            4 * mesh.boundary_faces().len()
        );
        // a second refinement keeps working
        let rr = refine_tets(&r.mesh);
        assert!((rr.mesh.volume() - mesh.volume()).abs() < 1e-12 * mesh.volume());
        rr.mesh.validate(&ValidationSettings::default()).unwrap();
    }
}
