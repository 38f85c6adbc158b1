//! One-rings, tet neighbourhoods and surface extraction.
//!
//! All lists are sorted and free of duplicates, so results are deterministic.

use crate::types::{TetMesh, TriMesh};
use std::collections::{BTreeMap, HashMap};

/// Vertex → neighbouring vertices (the one-ring `N₁(vᵢ)` of thesis eq. 3.4) for triangles
/// (`N = 3`) or tets (`N = 4`): two vertices are neighbours when an element contains both.
pub fn vertex_vertices<const N: usize>(
    num_vertices: usize,
    elements: &[[usize; N]],
) -> Vec<Vec<usize>> {
    let mut ring = vec![Vec::new(); num_vertices];
    for e in elements {
        for a in 0..N {
            for b in 0..N {
                if a != b {
                    ring[e[a]].push(e[b]);
                }
            }
        }
    }
    for r in &mut ring {
        r.sort_unstable();
        r.dedup();
    }
    ring
}

/// Vertex → incident elements (triangles or tets), ascending.
pub fn vertex_elements<const N: usize>(
    num_vertices: usize,
    elements: &[[usize; N]],
) -> Vec<Vec<usize>> {
    let mut out = vec![Vec::new(); num_vertices];
    for (i, e) in elements.iter().enumerate() {
        for &v in e {
            if out[v].last() != Some(&i) {
                out[v].push(i);
            }
        }
    }
    out
}

/// Local vertex indices of the face of a tet opposite local vertex `i`.
pub const TET_FACE_OPPOSITE: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// For each tet, the tet across the face opposite each local vertex (`None` on the boundary).
///
/// Faces shared by more than two tets (non-manifold input) pair the first two and leave the
/// rest as boundary.
pub fn tet_face_neighbors(tets: &[[usize; 4]]) -> Vec<[Option<usize>; 4]> {
    let mut out = vec![[None; 4]; tets.len()];
    let mut open: HashMap<[usize; 3], (usize, usize)> = HashMap::with_capacity(tets.len() * 2);
    for (t, tet) in tets.iter().enumerate() {
        for (i, f) in TET_FACE_OPPOSITE.iter().enumerate() {
            let mut key = f.map(|c| tet[c]);
            key.sort_unstable();
            match open.remove(&key) {
                Some((u, j)) => {
                    out[t][i] = Some(u);
                    out[u][j] = Some(t);
                }
                None => {
                    open.insert(key, (t, i));
                }
            }
        }
    }
    out
}

/// Tet → tets sharing a face, ascending.
pub fn tet_face_adjacency(tets: &[[usize; 4]]) -> Vec<Vec<usize>> {
    tet_face_neighbors(tets)
        .into_iter()
        .map(|n| {
            let mut v: Vec<usize> = n.into_iter().flatten().collect();
            v.sort_unstable();
            v.dedup();
            v
        })
        .collect()
}

/// Tet → tets sharing at least one vertex, ascending (the neighbourhood of the umbrella
/// operator in bickel2009 §4.1: `w_ij = 1` iff tets `i` and `j` share a vertex).
pub fn tet_vertex_adjacency(num_vertices: usize, tets: &[[usize; 4]]) -> Vec<Vec<usize>> {
    let v2t = vertex_elements(num_vertices, tets);
    tets.iter()
        .enumerate()
        .map(|(t, tet)| {
            let mut n: Vec<usize> = tet
                .iter()
                .flat_map(|&v| v2t[v].iter().copied())
                .filter(|&u| u != t)
                .collect();
            n.sort_unstable();
            n.dedup();
            n
        })
        .collect()
}

/// The boundary surface of a tet mesh with its own compact vertex numbering.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceMap {
    /// Boundary triangles (outward for positively oriented tets) over the surface vertices.
    pub surface: TriMesh,
    /// Surface vertex → volume vertex, ascending.
    pub surface_to_volume: Vec<usize>,
    /// Volume vertex → surface vertex (`None` for interior vertices).
    pub volume_to_surface: Vec<Option<usize>>,
}

impl SurfaceMap {
    /// Extracts the boundary of `mesh` (see [`TetMesh::boundary_faces`]).
    pub fn new(mesh: &TetMesh) -> Self {
        let faces = mesh.boundary_faces();
        let mut volume_to_surface = vec![None; mesh.vertices.len()];
        let mut used: Vec<usize> = faces.iter().flatten().copied().collect();
        used.sort_unstable();
        used.dedup();
        for (s, &v) in used.iter().enumerate() {
            volume_to_surface[v] = Some(s);
        }
        let triangles = faces
            .iter()
            .map(|f| f.map(|v| volume_to_surface[v].unwrap_or(usize::MAX)))
            .collect();
        SurfaceMap {
            surface: TriMesh {
                vertices: used.iter().map(|&v| mesh.vertices[v]).collect(),
                triangles,
            },
            surface_to_volume: used,
            volume_to_surface,
        }
    }
}

impl TriMesh {
    /// Edges used by exactly one triangle, oriented as in that triangle, sorted.
    pub fn boundary_edges(&self) -> Vec<[usize; 2]> {
        let mut count: BTreeMap<[usize; 2], ([usize; 2], u32)> = BTreeMap::new();
        for t in &self.triangles {
            for k in 0..3 {
                let e = [t[k], t[(k + 1) % 3]];
                let key = [e[0].min(e[1]), e[0].max(e[1])];
                count.entry(key).and_modify(|c| c.1 += 1).or_insert((e, 1));
            }
        }
        count
            .into_values()
            .filter(|(_, n)| *n == 1)
            .map(|(e, _)| e)
            .collect()
    }

    /// Vertices on an open boundary, ascending.
    pub fn boundary_vertices(&self) -> Vec<usize> {
        let mut v: Vec<usize> = self.boundary_edges().into_iter().flatten().collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    /// Vertex → neighbouring vertices (one-ring), see [`vertex_vertices`].
    pub fn one_rings(&self) -> Vec<Vec<usize>> {
        vertex_vertices(self.vertices.len(), &self.triangles)
    }

    /// Vertex → incident triangles, see [`vertex_elements`].
    pub fn vertex_triangles(&self) -> Vec<Vec<usize>> {
        vertex_elements(self.vertices.len(), &self.triangles)
    }
}

impl TetMesh {
    /// Vertex → neighbouring vertices along tet edges.
    pub fn one_rings(&self) -> Vec<Vec<usize>> {
        vertex_vertices(self.vertices.len(), &self.tets)
    }

    /// Vertex → incident tets.
    pub fn vertex_tets(&self) -> Vec<Vec<usize>> {
        vertex_elements(self.vertices.len(), &self.tets)
    }

    /// Boundary surface with vertex maps, see [`SurfaceMap`].
    pub fn surface_map(&self) -> SurfaceMap {
        SurfaceMap::new(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::structured::box_tet_mesh;

    #[test]
    fn single_cube_neighbourhoods() {
        let m = box_tet_mesh([0.0; 3], [1.0; 3], [1, 1, 1]);
        // Kuhn split: every tet touches corners 0 and 7, so all 6 tets share vertices.
        let va = tet_vertex_adjacency(m.vertices.len(), &m.tets);
        assert!(va.iter().all(|n| n.len() == 5));
        // Each tet has 2 interior faces (it shares a triangle with the two tets next to it
        // around the main diagonal) and 2 boundary faces.
        let fa = tet_face_adjacency(&m.tets);
        assert!(fa.iter().all(|n| n.len() == 2), "{fa:?}");
        let nb = tet_face_neighbors(&m.tets);
        for (t, n) in nb.iter().enumerate() {
            for (i, u) in n.iter().enumerate() {
                if let Some(u) = *u {
                    assert!(nb[u].contains(&Some(t)));
                    let mut a = TET_FACE_OPPOSITE[i].map(|c| m.tets[t][c]);
                    a.sort_unstable();
                    assert!(a.iter().all(|v| m.tets[u].contains(v)));
                }
            }
        }
        // Corner 0 and 7 connect to all other corners; corner 1 to 0, 3, 5, 7.
        let rings = m.one_rings();
        assert_eq!(rings[0], vec![1, 2, 3, 4, 5, 6, 7]);
        assert_eq!(rings[1], vec![0, 3, 5, 7]);
        assert_eq!(m.vertex_tets()[0], vec![0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn surface_map_of_box() {
        let m = box_tet_mesh([0.0; 3], [2.0, 1.0, 1.0], [2, 2, 2]);
        let s = m.surface_map();
        // 27 grid vertices, only the centre is interior.
        assert_eq!(s.surface_to_volume.len(), 26);
        assert_eq!(
            s.volume_to_surface.iter().filter(|v| v.is_none()).count(),
            1
        );
        for (si, &vi) in s.surface_to_volume.iter().enumerate() {
            assert_eq!(s.volume_to_surface[vi], Some(si));
            assert_eq!(s.surface.vertices[si], m.vertices[vi]);
        }
        assert!((s.surface.area() - 10.0).abs() < 1e-12);
        assert!(s.surface.boundary_edges().is_empty());
        let one = TriMesh {
            vertices: s.surface.vertices[..3].to_vec(),
            triangles: vec![[0, 1, 2]],
        };
        assert_eq!(one.boundary_edges(), vec![[0, 1], [2, 0], [1, 2]]);
    }
}
