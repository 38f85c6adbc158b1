//! Free-flying objects (saito-barbic §3.6–3.7): the rigid gauge of the equilibrium.
//!
//! Without attachments the equilibrium under a plastic state is unique only up to a rigid motion
//! (Nullspace Lemma). As in eq. 19–20 the motion is fixed by the centroid and the "average
//! rotation" of a point set P — the shape-matching rotation polar(A) of the covariance
//! A = Σ_i w̃_i (x_i − x̄)(X_i − X̄)ᵀ (Müller et al. 2005), X the template. The solver keeps the
//! shape in its *canonical* frame (centroid X̄, rotation I: A symmetric positive definite) and a
//! rigid transform T (world = T(canonical)); the block-coordinate descent of §3.6 alternates a
//! Gauss–Newton step of the plastic strains at fixed T with the optimal T at fixed shape, which is
//! closed form (Horn 1987, [`softcap_core::horn_weighted`]) for any P. Here P is the template's
//! boundary nodes with equal weights (the paper uses the constraint points; with T applied after the
//! canonical frame the rigid block is closed form for either choice, and a fixed P keeps the frame
//! from jumping when ICP closest points move).
//!
//! Canonicalization y ↦ x = R_yᵀ(y − ȳ) + X̄, R_y = polar(A(y)), has at a canonical y the
//! derivative (§3.7: the polar rotation's derivative solves the Sylvester equation ΩS + SΩ =
//! Rᵀ dA − dAᵀR, eq. 22; for Ω = \[ω\]× this is ((tr S) I − S) ω = vee(dA − dAᵀ))
//!
//! D δy = δy − δȳ − ω × (x − X̄),  δȳ = Σ w̃_i δy_i,  ω = ((tr S) I − S)⁻¹ Σ w̃_i d_i × δy_i,
//!
//! with d_i = X_i − X̄. D annihilates the rigid modes, so the Jacobian of the canonical shape is
//! J = −D K⁺ ∂f/∂s with any solution of the singular system (singular lemma (ii)).

use faer::Mat;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// The rigid gauge over a fixed point set P (see the module docs).
#[derive(Clone, Debug)]
pub struct Gauge {
    nodes: Vec<usize>,
    rest_offsets: Vec<Vector3<f64>>,
    rest_centroid: Vector3<f64>,
}

impl Gauge {
    /// Gauge over the template positions `rest` of the nodes `nodes` (equal weights).
    pub fn new(nodes: Vec<usize>, rest: &[Vector3<f64>]) -> Self {
        let n = nodes.len().max(1) as f64;
        let rest_centroid = nodes.iter().map(|&v| rest[v]).sum::<Vector3<f64>>() / n;
        let rest_offsets = nodes.iter().map(|&v| rest[v] - rest_centroid).collect();
        Self {
            nodes,
            rest_offsets,
            rest_centroid,
        }
    }

    /// Centroid X̄ of P on the template (the canonical frame's centroid).
    pub fn rest_centroid(&self) -> Vector3<f64> {
        self.rest_centroid
    }

    /// (ȳ, A(y)) of positions `y`.
    fn centroid_covariance(&self, y: &[Vector3<f64>]) -> (Vector3<f64>, Matrix3<f64>) {
        let w = 1.0 / self.nodes.len().max(1) as f64;
        let c = self.nodes.iter().map(|&v| y[v]).sum::<Vector3<f64>>() * w;
        let a = self
            .nodes
            .iter()
            .zip(&self.rest_offsets)
            .map(|(&v, d)| (y[v] - c) * d.transpose())
            .sum::<Matrix3<f64>>()
            * w;
        (c, a)
    }

    /// Moves `y` into the canonical frame in place and returns the rigid transform T with
    /// y_before = T(y_after).
    pub fn canonicalize(&self, y: &mut [Vector3<f64>]) -> Isometry3<f64> {
        let (c, a) = self.centroid_covariance(y);
        let r = softcap_core::polar_decomposition(&a).rotation;
        let rt = r.transpose();
        for p in y.iter_mut() {
            *p = rt * (*p - c) + self.rest_centroid;
        }
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
        Isometry3::from_parts(Translation3::from(c - r * self.rest_centroid), rotation)
    }

    /// ((tr S) I − S)⁻¹ at the canonical `x` (S the symmetric part of A(x)).
    fn sylvester_inverse(&self, x: &[Vector3<f64>]) -> Matrix3<f64> {
        let (_, a) = self.centroid_covariance(x);
        let s = 0.5 * (a + a.transpose());
        (Matrix3::identity() * s.trace() - s)
            .try_inverse()
            .unwrap_or_else(Matrix3::zeros)
    }

    /// D v at the canonical `x` (module docs), in place.
    pub fn project(&self, x: &[Vector3<f64>], v: &mut [Vector3<f64>]) {
        let w = 1.0 / self.nodes.len().max(1) as f64;
        let minv = self.sylvester_inverse(x);
        let mut shift = Vector3::zeros();
        let mut torque = Vector3::zeros();
        for (&node, d) in self.nodes.iter().zip(&self.rest_offsets) {
            shift += v[node] * w;
            torque += d.cross(&v[node]) * w;
        }
        let omega = minv * torque;
        for (p, vp) in x.iter().zip(v.iter_mut()) {
            *vp -= shift + omega.cross(&(p - self.rest_centroid));
        }
    }

    /// Dᵀ applied to every column of `m` (3·nodes rows) at the canonical `x`, in place:
    /// v ↦ v − Qᵀ(Tᵀ v) with Tᵀ v = (Σ_j v_j, Σ_j (x_j − X̄) × v_j) and
    /// Qᵀ(a, b) = w̃ (a + (M⁻¹b) × d_i) on each node i of P.
    pub fn project_transposed_columns(&self, x: &[Vector3<f64>], m: &mut Mat<f64>) {
        let w = 1.0 / self.nodes.len().max(1) as f64;
        let minv = self.sylvester_inverse(x);
        for c in 0..m.ncols() {
            let mut col = m.col_mut(c);
            let mut a = Vector3::zeros();
            let mut b = Vector3::zeros();
            for (j, p) in x.iter().enumerate() {
                let vj = Vector3::new(col[3 * j], col[3 * j + 1], col[3 * j + 2]);
                a += vj;
                b += (p - self.rest_centroid).cross(&vj);
            }
            let mb = minv * b;
            for (&node, d) in self.nodes.iter().zip(&self.rest_offsets) {
                let q = (a + mb.cross(d)) * w;
                for i in 0..3 {
                    col[3 * node + i] -= q[i];
                }
            }
        }
    }
}

/// Orthonormal basis of the rigid motions at `x` (three translations, three infinitesimal
/// rotations about the centroid), Gram–Schmidt orthonormalized: the known null space of the
/// equilibrium tangent of a free-flying object at equilibrium (Nullspace Lemma, §3.6).
pub fn rigid_modes(x: &[Vector3<f64>]) -> Vec<Vec<f64>> {
    let n = x.len();
    let c = x.iter().sum::<Vector3<f64>>() / n.max(1) as f64;
    let mut modes: Vec<Vec<f64>> = Vec::with_capacity(6);
    for axis in 0..3 {
        let mut m = vec![0.0; 3 * n];
        for j in 0..n {
            m[3 * j + axis] = 1.0;
        }
        modes.push(m);
    }
    for axis in 0..3 {
        let e = Vector3::ith(axis, 1.0);
        let mut m = vec![0.0; 3 * n];
        for (j, p) in x.iter().enumerate() {
            let v = e.cross(&(p - c));
            m[3 * j..3 * j + 3].copy_from_slice(v.as_slice());
        }
        modes.push(m);
    }
    let mut basis: Vec<Vec<f64>> = Vec::with_capacity(6);
    for mut m in modes {
        for b in &basis {
            let d: f64 = m.iter().zip(b).map(|(u, v)| u * v).sum();
            for (u, v) in m.iter_mut().zip(b) {
                *u -= d * v;
            }
        }
        let norm = m.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm > 0.0 {
            for u in &mut m {
                *u /= norm;
            }
            basis.push(m);
        }
    }
    basis
}

/// Removes the components along the orthonormal `modes` from every column of `m` (the solution
/// of the singular system orthogonal to the null space, singular lemma (ii)).
pub fn project_out_modes(modes: &[Vec<f64>], m: &mut Mat<f64>) {
    for c in 0..m.ncols() {
        let mut col = m.col_mut(c);
        for b in modes {
            let d: f64 = (0..b.len()).map(|i| col[i] * b[i]).sum();
            for i in 0..b.len() {
                col[i] -= d * b[i];
            }
        }
    }
}

/// 3-2-1 pinned dofs that remove the rigid motions of the node cloud `x`: node a (farthest from
/// the centroid) fully, node b (farthest from a) in the two axes most orthogonal to b − a, node c
/// (farthest from the line ab) in the axis along which a rotation about ab moves it most.
pub fn three_two_one_pins(x: &[Vector3<f64>]) -> Vec<usize> {
    let c = x.iter().sum::<Vector3<f64>>() / x.len().max(1) as f64;
    let farthest = |score: &dyn Fn(&Vector3<f64>) -> f64| {
        (0..x.len())
            .max_by(|&i, &j| score(&x[i]).total_cmp(&score(&x[j])))
            .unwrap_or(0)
    };
    let a = farthest(&|p| (p - c).norm_squared());
    let b = farthest(&|p| (p - x[a]).norm_squared());
    let u = (x[b] - x[a]).normalize();
    let cn = farthest(&|p| (p - x[a]).cross(&u).norm_squared());
    let along = u.iamax();
    let mut pins = vec![3 * a, 3 * a + 1, 3 * a + 2];
    pins.extend((0..3).filter(|&i| i != along).map(|i| 3 * b + i));
    let swing = u.cross(&(x[cn] - x[a]));
    pins.push(3 * cn + swing.iamax());
    pins.sort_unstable();
    pins
}

/// The optimal rigid transform of the block-coordinate step (§3.6): T minimizing
/// Σ wᵢ ‖T(qᵢ) − pᵢ‖² (Horn 1987); `None` with fewer than three points.
pub fn best_rigid(q: &[Vector3<f64>], p: &[Vector3<f64>], w: &[f64]) -> Option<Isometry3<f64>> {
    let src: Vec<Point3<f64>> = q.iter().map(|v| Point3::from(*v)).collect();
    let dst: Vec<Point3<f64>> = p.iter().map(|v| Point3::from(*v)).collect();
    softcap_core::horn_weighted(&src, &dst, w)
}

/// One linearized point-to-plane rigid step (Chen and Medioni 1992): the small motion
/// y ↦ exp(\[ω\]×)(y − c) + c + t (c the centroid of the points) minimizing
/// Σ wᵢ (dᵢ·(yᵢ + ω × (yᵢ − c) + t − pᵢ))² over (ω, t), applied after `frame`; the scalar rows
/// are (point yᵢ, unit direction dᵢ, target pᵢ, weight wᵢ) in world coordinates. `None` when the
/// rows do not determine all six motions.
pub fn plane_rigid_step(
    rows: &[(Vector3<f64>, Vector3<f64>, Vector3<f64>, f64)],
    frame: &Isometry3<f64>,
) -> Option<Isometry3<f64>> {
    let total: f64 = rows.iter().map(|r| r.3).sum();
    if rows.len() < 6 || total <= 0.0 {
        return None;
    }
    let c = rows.iter().map(|r| r.0 * r.3).sum::<Vector3<f64>>() / total;
    let mut a = nalgebra::Matrix6::<f64>::zeros();
    let mut b = nalgebra::Vector6::<f64>::zeros();
    for (y, d, p, w) in rows {
        let j = nalgebra::Vector6::from_iterator((y - c).cross(d).iter().chain(d.iter()).copied());
        a += j * j.transpose() * *w;
        b += j * (d.dot(&(y - p)) * w);
    }
    let x = a.cholesky()?.solve(&(-b));
    if !x.iter().all(|v| v.is_finite()) {
        return None;
    }
    let rotation = UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2]));
    let translation = c - rotation * c + Vector3::new(x[3], x[4], x[5]);
    Some(Isometry3::from_parts(Translation3::from(translation), rotation) * frame)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> Vec<Vector3<f64>> {
        (0..40)
            .map(|i| {
                let t = i as f64;
                Vector3::new(
                    (0.7 * t).sin() * 2.0,
                    (1.3 * t).cos(),
                    (0.4 * t).sin() * 0.5 + 0.1 * t,
                )
            })
            .collect()
    }

    #[test]
    fn canonical_derivative_matches_finite_differences() {
        let rest = cloud();
        let gauge = Gauge::new((0..rest.len()).step_by(2).collect(), &rest);
        // A deformed, rotated, shifted shape, canonicalized.
        let rot = Rotation3::from_euler_angles(0.4, -0.2, 0.9);
        let mut y: Vec<Vector3<f64>> = rest
            .iter()
            .map(|p| {
                rot * Vector3::new(1.3 * p.x, 0.8 * p.y + 0.1 * p.x, p.z)
                    + Vector3::new(1.0, 2.0, 3.0)
            })
            .collect();
        let t = gauge.canonicalize(&mut y);
        assert!(t.rotation.angle() > 0.1);
        let (c, a) = gauge.centroid_covariance(&y);
        assert!((c - gauge.rest_centroid()).norm() < 1e-12);
        assert!((a - a.transpose()).norm() < 1e-12 * a.norm());
        // Direction δy; D δy vs (canon(y + h δy) − canon(y − h δy)) / 2h.
        let dy: Vec<Vector3<f64>> = (0..y.len())
            .map(|i| Vector3::new((2.1 * i as f64).sin(), (0.3 * i as f64).cos(), 0.5))
            .collect();
        let h = 1e-6;
        let shifted = |s: f64| {
            let mut v: Vec<Vector3<f64>> = y.iter().zip(&dy).map(|(a, b)| a + b * s).collect();
            gauge.canonicalize(&mut v);
            v
        };
        let (p, m) = (shifted(h), shifted(-h));
        let mut an = dy.clone();
        gauge.project(&y, &mut an);
        for i in 0..y.len() {
            let fd = (p[i] - m[i]) / (2.0 * h);
            assert!((fd - an[i]).norm() < 1e-6, "node {i}: {fd} vs {}", an[i]);
        }
        // Dᵀ is the adjoint of D.
        let n = y.len();
        let mut col = Mat::<f64>::zeros(3 * n, 1);
        for i in 0..3 * n {
            col[(i, 0)] = (0.9 * i as f64).cos();
        }
        let lhs: f64 = (0..n)
            .map(|j| (0..3).map(|k| an[j][k] * col[(3 * j + k, 0)]).sum::<f64>())
            .sum();
        gauge.project_transposed_columns(&y, &mut col);
        let rhs: f64 = (0..n)
            .map(|j| (0..3).map(|k| dy[j][k] * col[(3 * j + k, 0)]).sum::<f64>())
            .sum();
        assert!(
            (lhs - rhs).abs() < 1e-10 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
        // D annihilates the rigid modes.
        for mode in rigid_modes(&y) {
            let mut v: Vec<Vector3<f64>> = mode
                .chunks(3)
                .map(|c| Vector3::new(c[0], c[1], c[2]))
                .collect();
            gauge.project(&y, &mut v);
            assert!(v.iter().map(|p| p.norm()).fold(0.0, f64::max) < 1e-10);
        }
    }

    #[test]
    fn pins_remove_every_rigid_mode() {
        let x = cloud();
        let pins = three_two_one_pins(&x);
        assert_eq!(pins.len(), 6);
        // The 6 × 6 restriction of the rigid modes to the pinned dofs is invertible.
        let modes = rigid_modes(&x);
        let m = nalgebra::DMatrix::from_fn(6, 6, |i, j| modes[j][pins[i]]);
        assert!(m.determinant().abs() > 1e-6, "{}", m.determinant());
    }

    /// A point cloud moved by a small rigid motion, written as scalar rows along x, y and z:
    /// iterated linearized steps recover the motion (the error falls quadratically).
    #[test]
    fn plane_rigid_steps_recover_a_small_rigid_motion() {
        let truth = Isometry3::new(
            Vector3::new(0.02, -0.01, 0.03),
            Vector3::new(0.05, -0.03, 0.04),
        );
        let pts = cloud();
        let mut frame = Isometry3::identity();
        for _ in 0..4 {
            let rows: Vec<_> = pts
                .iter()
                .flat_map(|q| {
                    let y = frame.transform_point(&Point3::from(*q)).coords;
                    let p = truth.transform_point(&Point3::from(*q)).coords;
                    [Vector3::x(), Vector3::y(), Vector3::z()].map(|d| (y, d, p, 1.0))
                })
                .collect();
            frame = plane_rigid_step(&rows, &frame).unwrap();
        }
        let err = pts
            .iter()
            .map(|q| {
                (frame.transform_point(&Point3::from(*q))
                    - truth.transform_point(&Point3::from(*q)))
                .norm()
            })
            .fold(0.0, f64::max);
        assert!(err < 1e-10, "{err}");
    }
}
