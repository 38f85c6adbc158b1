//! Surface samples of the template: the GMM components of wang2015 §5 (the vertices s_k of the
//! fine surface mesh S embedded in the simulation mesh T). The boundary triangles of the tet mesh
//! are sampled on a barycentric lattice with about `spacing` between samples (vertices once,
//! edge points once per edge, interior points per triangle), so the samples are dense enough for
//! a σ of a few millimetres even on a coarse tet mesh. A sample is a fixed barycentric
//! combination s_k = Σ_a w_ka x_a of one boundary triangle's nodes — the mesh embedding that
//! carries virtual forces to the nodes and positions back to the surface.

use std::collections::BTreeMap;

use nalgebra::Vector3;
use softcap_mesh::TetMesh;

/// The samples of a tet mesh's boundary.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceSamples {
    /// Boundary triangles (node indices of the tet mesh), outward.
    pub faces: Vec<[usize; 3]>,
    /// `entries[offsets[k]..offsets[k + 1]]`: the (node, weight) pairs of sample k (weights > 0,
    /// summing to 1).
    offsets: Vec<usize>,
    entries: Vec<(usize, f64)>,
    /// Faces whose normals make up sample k's normal (area-weighted): `face_entries[face_offsets[k]
    /// ..face_offsets[k + 1]]`.
    face_offsets: Vec<usize>,
    face_entries: Vec<usize>,
    /// Surface area each sample stands for on the template, m²: the mixture weight π_k ∝ area
    /// (uniform weights would pull points towards densely sampled regions: the lattice is denser
    /// along long edges).
    pub areas_m2: Vec<f64>,
}

impl SurfaceSamples {
    /// Samples the boundary of `mesh` with a lattice of about `spacing_m` (≤ 0: vertices only).
    pub fn new(mesh: &TetMesh, spacing_m: f64) -> Self {
        let faces = mesh.boundary_faces();
        let x = &mesh.vertices;
        let mut out = Self {
            faces: faces.clone(),
            offsets: vec![0],
            entries: Vec::new(),
            face_offsets: vec![0],
            face_entries: Vec::new(),
            areas_m2: Vec::new(),
        };
        let divisions = |a: usize, b: usize| -> usize {
            if spacing_m > 0.0 {
                ((x[a] - x[b]).norm() / spacing_m).ceil().max(1.0) as usize
            } else {
                1
            }
        };
        // vertices, each with its incident faces
        let mut vertex_faces: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (f, t) in faces.iter().enumerate() {
            for &v in t {
                vertex_faces.entry(v).or_default().push(f);
            }
        }
        for (v, fs) in &vertex_faces {
            out.push(&[(*v, 1.0)], fs);
        }
        // interior points of every edge, once, with the (one or two) faces that share it
        let mut edges: BTreeMap<[usize; 2], Vec<usize>> = BTreeMap::new();
        for (f, t) in faces.iter().enumerate() {
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                edges.entry([a.min(b), a.max(b)]).or_default().push(f);
            }
        }
        for ([a, b], fs) in &edges {
            let n = divisions(*a, *b);
            for i in 1..n {
                let t = i as f64 / n as f64;
                out.push(&[(*a, 1.0 - t), (*b, t)], fs);
            }
        }
        // strictly interior lattice points of every face
        for (f, t) in faces.iter().enumerate() {
            let n = divisions(t[0], t[1])
                .max(divisions(t[1], t[2]))
                .max(divisions(t[2], t[0]));
            for i in 1..n {
                for j in 1..n - i {
                    let k = n - i - j;
                    let w = [i, j, k].map(|v| v as f64 / n as f64);
                    out.push(&[(t[0], w[0]), (t[1], w[1]), (t[2], w[2])], &[f]);
                }
            }
        }
        out.areas_m2 = out.sample_areas(x);
        out
    }

    /// Σ over the faces a sample lies on of the face's area shared equally among its samples.
    fn sample_areas(&self, x: &[Vector3<f64>]) -> Vec<f64> {
        let mut count = vec![0usize; self.faces.len()];
        for &f in &self.face_entries {
            count[f] += 1;
        }
        let share: Vec<f64> = self
            .faces
            .iter()
            .zip(&count)
            .map(|(t, &c)| {
                let area = 0.5 * (x[t[1]] - x[t[0]]).cross(&(x[t[2]] - x[t[0]])).norm();
                area / c.max(1) as f64
            })
            .collect();
        (0..self.len())
            .map(|k| {
                self.face_entries[self.face_offsets[k]..self.face_offsets[k + 1]]
                    .iter()
                    .map(|&f| share[f])
                    .sum()
            })
            .collect()
    }

    fn push(&mut self, entries: &[(usize, f64)], faces: &[usize]) {
        self.entries.extend_from_slice(entries);
        self.offsets.push(self.entries.len());
        self.face_entries.extend_from_slice(faces);
        self.face_offsets.push(self.face_entries.len());
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    /// True without samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The (node, weight) pairs of sample `k`.
    pub fn entries(&self, k: usize) -> &[(usize, f64)] {
        &self.entries[self.offsets[k]..self.offsets[k + 1]]
    }

    /// s_k = Σ_a w_ka x_a for every sample.
    pub fn positions(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        (0..self.len())
            .map(|k| self.entries(k).iter().map(|&(a, w)| x[a] * w).sum())
            .collect()
    }

    /// Unit outward normal of every sample at positions `x`: the area-weighted sum of the normals
    /// of the faces it lies on (zero for a degenerate neighbourhood).
    pub fn normals(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let face_n: Vec<Vector3<f64>> = self
            .faces
            .iter()
            .map(|t| (x[t[1]] - x[t[0]]).cross(&(x[t[2]] - x[t[0]])))
            .collect();
        (0..self.len())
            .map(|k| {
                let n: Vector3<f64> = self.face_entries
                    [self.face_offsets[k]..self.face_offsets[k + 1]]
                    .iter()
                    .map(|&f| face_n[f])
                    .sum();
                n.try_normalize(1e-300).unwrap_or_else(Vector3::zeros)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lattice_samples_lie_on_the_surface_and_cover_it_evenly() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.1, 0.02, 0.02], [4, 1, 1]);
        let s = SurfaceSamples::new(&mesh, 0.005);
        let p = s.positions(&mesh.vertices);
        // on the box surface
        for q in &p {
            let on = [q.x, q.y, q.z]
                .iter()
                .zip([0.1, 0.02, 0.02])
                .any(|(v, m)| v.abs() < 1e-12 || (v - m).abs() < 1e-12);
            assert!(on, "{q}");
        }
        // no duplicates, and every point of the surface has a sample within the spacing
        for (i, a) in p.iter().enumerate() {
            for b in &p[..i] {
                assert!((a - b).norm() > 1e-9);
            }
        }
        let probe = Vector3::new(0.0431, 0.02, 0.0117);
        let nearest = p
            .iter()
            .map(|q| (q - probe).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(nearest < 0.005, "{nearest}");
        // the areas partition the surface
        let total: f64 = s.areas_m2.iter().sum();
        let want = 2.0 * (0.1 * 0.02 * 2.0 + 0.02 * 0.02);
        assert!((total - want).abs() < 1e-12 * want, "{total} vs {want}");
        // normals point outward
        let n = s.normals(&mesh.vertices);
        let centre = Vector3::new(0.05, 0.01, 0.01);
        for (q, m) in p.iter().zip(&n) {
            assert!(m.dot(&(q - centre)) > 0.0);
        }
    }
}
