//! Structured tetrahedral meshing of axis-aligned boxes.

use crate::types::TetMesh;
use nalgebra::Vector3;

/// Tet mesh of the box `[min, max]` with `cells` hexahedral cells per axis, each split into
/// six tets around its main diagonal (Kuhn / Freudenthal subdivision). The split is the same
/// in every cell, so faces match across cells and the mesh is conforming.
///
/// Vertex `(i, j, k)` has index `i + (nx + 1) * (j + (ny + 1) * k)`.
pub fn box_tet_mesh(min: [f64; 3], max: [f64; 3], cells: [usize; 3]) -> TetMesh {
    let [nx, ny, nz] = cells.map(|n| n.max(1));
    let idx = |i: usize, j: usize, k: usize| i + (nx + 1) * (j + (ny + 1) * k);
    let mut vertices = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                let t = [
                    i as f64 / nx as f64,
                    j as f64 / ny as f64,
                    k as f64 / nz as f64,
                ];
                vertices.push(Vector3::new(
                    min[0] + t[0] * (max[0] - min[0]),
                    min[1] + t[1] * (max[1] - min[1]),
                    min[2] + t[2] * (max[2] - min[2]),
                ));
            }
        }
    }
    // Corners of a unit cell by bit (x = bit 0, y = bit 1, z = bit 2); every tet runs from
    // corner 0 to corner 7 along one monotone path.
    const PATHS: [[usize; 4]; 6] = [
        [0, 1, 3, 7],
        [0, 1, 5, 7],
        [0, 2, 3, 7],
        [0, 2, 6, 7],
        [0, 4, 5, 7],
        [0, 4, 6, 7],
    ];
    let mut tets = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let corner = |b: usize| idx(i + (b & 1), j + ((b >> 1) & 1), k + ((b >> 2) & 1));
                for p in PATHS {
                    tets.push(p.map(corner));
                }
            }
        }
    }
    let mut mesh = TetMesh { vertices, tets };
    for t in 0..mesh.tets.len() {
        if mesh.tet_volume(t) < 0.0 {
            mesh.tets[t].swap(2, 3);
        }
    }
    mesh
}

/// Unit icosphere: the icosahedron with every triangle split into 4, `subdivisions` times,
/// new vertices projected onto the unit sphere. `10·4ˢ + 2` vertices, `20·4ˢ` triangles,
/// counter-clockwise seen from outside.
pub fn icosphere(subdivisions: u32) -> crate::types::TriMesh {
    use std::collections::HashMap;
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut vertices: Vec<Vector3<f64>> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|p| Vector3::from(*p).normalize())
    .collect();
    let mut triangles: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        let mut mid: HashMap<(usize, usize), usize> = HashMap::new();
        let mut midpoint = |a: usize, b: usize, vertices: &mut Vec<Vector3<f64>>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                vertices.push(((vertices[a] + vertices[b]) * 0.5).normalize());
                vertices.len() - 1
            })
        };
        let mut next = Vec::with_capacity(triangles.len() * 4);
        for [a, b, c] in triangles {
            let ab = midpoint(a, b, &mut vertices);
            let bc = midpoint(b, c, &mut vertices);
            let ca = midpoint(c, a, &mut vertices);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = next;
    }
    crate::types::TriMesh {
        vertices,
        triangles,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_mesh_is_positive_and_closed() {
        let m = box_tet_mesh([0.0, 0.0, 0.0], [2.0, 1.0, 1.0], [3, 2, 2]);
        assert!((0..m.tets.len()).all(|t| m.tet_volume(t) > 0.0));
        assert!((m.volume() - 2.0).abs() < 1e-12);
        // Boundary of a 3x2x2 box: 2 triangles per boundary quad.
        let quads = 2 * (3 * 2 + 3 * 2 + 2 * 2);
        assert_eq!(m.boundary_faces().len(), 2 * quads);
    }
}
