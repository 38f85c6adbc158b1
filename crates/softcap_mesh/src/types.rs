//! Mesh types. Positions are in metres unless a reader says otherwise.

use nalgebra::Vector3;

/// A triangle surface mesh (counter-clockwise triangles seen from outside).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub vertices: Vec<Vector3<f64>>,
    /// Vertex indices of each triangle.
    pub triangles: Vec<[usize; 3]>,
}

/// A linear tetrahedral mesh. Tets are positively oriented:
/// `(x1 − x0) · ((x2 − x0) × (x3 − x0)) > 0`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TetMesh {
    /// Vertex positions.
    pub vertices: Vec<Vector3<f64>>,
    /// Vertex indices of each tetrahedron.
    pub tets: Vec<[usize; 4]>,
}

impl TriMesh {
    /// Total surface area.
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i]);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }
}

impl TetMesh {
    /// Signed volume of tet `t` (positive when correctly oriented).
    pub fn tet_volume(&self, t: usize) -> f64 {
        let [a, b, c, d] = self.tets[t].map(|i| self.vertices[i]);
        (b - a).dot(&(c - a).cross(&(d - a))) / 6.0
    }

    /// Longest edge of tet `t`.
    pub fn tet_longest_edge(&self, t: usize) -> f64 {
        crate::validate::longest_edge(&self.tets[t].map(|i| self.vertices[i]))
    }

    /// Longest edge of any tet (0 without tets).
    pub fn longest_edge(&self) -> f64 {
        (0..self.tets.len())
            .map(|t| self.tet_longest_edge(t))
            .fold(0.0, f64::max)
    }

    /// Total (signed) volume.
    pub fn volume(&self) -> f64 {
        (0..self.tets.len()).map(|t| self.tet_volume(t)).sum()
    }

    /// The boundary surface: faces used by exactly one tet, oriented outward.
    pub fn boundary_faces(&self) -> Vec<[usize; 3]> {
        use std::collections::BTreeMap;
        // Faces of a positively oriented tet (a,b,c,d), outward.
        const FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];
        let mut count: BTreeMap<[usize; 3], ([usize; 3], u32)> = BTreeMap::new();
        for tet in &self.tets {
            for f in FACES {
                let face = f.map(|i| tet[i]);
                let mut key = face;
                key.sort_unstable();
                count
                    .entry(key)
                    .and_modify(|e| e.1 += 1)
                    .or_insert((face, 1));
            }
        }
        count
            .into_values()
            .filter(|(_, n)| *n == 1)
            .map(|(f, _)| f)
            .collect()
    }
}
