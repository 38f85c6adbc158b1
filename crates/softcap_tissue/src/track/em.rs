//! The E-step of wang2015 §5 (after Schulman et al. 2013): soft correspondences between the
//! frame's points c_n and the visible surface samples s_k under a Gaussian mixture with isotropic
//! variance σ² and a uniform outlier component of weight w,
//!
//! p(z_kn) = π_k N(c_n; s_k, σ²I) / (Σ_j π_j N(c_n; s_j, σ²I) + w / V),
//!
//! over the visible samples, V the volume of the cloud's bounding box (the outlier density is
//! uniform there). The mixture weights π_k = (1 − w) a_k / Σ_visible a_j follow the surface area
//! a_k each sample stands for, so the mixture is a uniform density on the visible surface
//! (wang2015 uses the vertices of a fine, even surface mesh; π = (1 − w)/K is the same there). Components further than `cutoff` σ from a point are left out (their
//! responsibility is below e^{−cutoff²/2}); a point whose normal is more than 60° from a sample's
//! normal cannot belong to it (the front and back of a thin part, the faces that meet at an
//! edge). At large σ only every `stride`-th point
//! takes part and counts `stride` times (its responsibilities are the same in expectation, the
//! cost stays that of the final σ).
//!
//! The M-step's inputs per sample are the responsibility mass W_k = Σ_n p(z_kn) and the weighted
//! mean ĉ_k = Σ_n p(z_kn) c_n / W_k: the virtual force of wang2015 eq. 5,
//! f_k = η Σ_n p(z_kn) σ⁻² (c_n − s_k) = (η W_k / σ²)(ĉ_k − s_k), is a spring of stiffness
//! η W_k/σ² towards ĉ_k ([`super::forces::VirtualForces`]). The maximum-likelihood variance of
//! the same responsibilities, σ²_ML = Σ p(z_kn) ‖c_n − s_k‖² / (3 Σ p(z_kn)), drives the
//! annealing.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use nalgebra::Vector3;
use rayon::prelude::*;

/// cos 60°: the normal gate's threshold.
const GATE_COS: f64 = 0.5;

/// The E-step's inputs besides the points and samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EStepParams {
    /// σ, m.
    pub sigma_m: f64,
    /// Outlier weight w ∈ [0, 1).
    pub outlier_weight: f64,
    /// Components beyond this many σ are left out.
    pub cutoff_sigmas: f64,
    /// Use every `stride`-th point (≥ 1), counted `stride` times.
    pub stride: usize,
    /// Exclude components whose normal is more than 60° from the point's normal.
    pub normal_gate: bool,
}

/// The E-step's result.
#[derive(Clone, Debug, PartialEq)]
pub struct EStep {
    /// W_k = Σ_n p(z_kn) per sample (0 for invisible samples).
    pub weight: Vec<f64>,
    /// ĉ_k = Σ_n p(z_kn) c_n / W_k (the sample's own position where W_k = 0).
    pub target: Vec<Vector3<f64>>,
    /// σ²_ML of these responsibilities, m² (NaN when no point has a component).
    pub sigma2_ml: f64,
    /// Mean posterior of the outlier component over the points used.
    pub outlier_fraction: f64,
    /// Per used point: posterior of the outlier component (points in index order, stride
    /// applied).
    pub point_outlier: Vec<f64>,
    /// Points used (after the stride).
    pub points_used: usize,
}

/// Hashes a grid cell's integer coordinates by multiply-rotate mixing (the FxHash scheme). The
/// E-step looks up 27 cells per point and std's SipHash took a tenth of the tracker's time; the
/// keys are the tracker's own, so SipHash's resistance to chosen keys buys nothing here.
#[derive(Default)]
struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut b = [0u8; 8];
            b[..chunk.len()].copy_from_slice(chunk);
            self.write_u64(u64::from_le_bytes(b));
        }
    }

    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }

    fn write_i64(&mut self, v: i64) {
        self.write_u64(v as u64);
    }
}

/// A uniform grid over the visible samples with cells of the cutoff radius.
struct Grid {
    cell: f64,
    cells: HashMap<[i64; 3], Vec<u32>, BuildHasherDefault<CellHasher>>,
}

impl Grid {
    fn new(samples: &[Vector3<f64>], visible: &[bool], cell: f64) -> Self {
        let mut cells: HashMap<[i64; 3], Vec<u32>, BuildHasherDefault<CellHasher>> =
            HashMap::default();
        for (k, s) in samples.iter().enumerate() {
            if visible[k] {
                cells.entry(Self::key(s, cell)).or_default().push(k as u32);
            }
        }
        Self { cell, cells }
    }

    fn key(p: &Vector3<f64>, cell: f64) -> [i64; 3] {
        [p.x, p.y, p.z].map(|v| (v / cell).floor() as i64)
    }

    /// Candidates around `p`, in a fixed order (neighbour cells in lexicographic offset order,
    /// samples ascending within a cell).
    fn around(&self, p: &Vector3<f64>, mut f: impl FnMut(usize)) {
        let c = Self::key(p, self.cell);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(list) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                        for &k in list {
                            f(k as usize);
                        }
                    }
                }
            }
        }
    }
}

/// Volume of the points' bounding box, m³ (at least a 1 cm cube).
pub fn bounding_volume(points: &[Vector3<f64>]) -> f64 {
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let d = (hi - lo).map(|v| v.max(0.01));
    if d.iter().all(|v| v.is_finite()) {
        d.x * d.y * d.z
    } else {
        1e-6
    }
}

/// Responsibilities of the samples for the points (wang2015 §5, eq. 4–5 with Schulman et al.'s
/// outlier component; see the module docs). `point_normals` may be empty (no gate);
/// `sample_areas` may be empty (equal weights).
#[allow(clippy::too_many_arguments)]
pub fn e_step(
    points: &[Vector3<f64>],
    point_normals: &[Vector3<f64>],
    samples: &[Vector3<f64>],
    sample_normals: &[Vector3<f64>],
    sample_areas: &[f64],
    visible: &[bool],
    outlier_volume_m3: f64,
    p: &EStepParams,
) -> EStep {
    let k_visible = visible.iter().filter(|v| **v).count();
    let mut out = EStep {
        weight: vec![0.0; samples.len()],
        target: samples.to_vec(),
        sigma2_ml: f64::NAN,
        outlier_fraction: 1.0,
        point_outlier: Vec::new(),
        points_used: 0,
    };
    let stride = p.stride.max(1);
    let used: Vec<usize> = (0..points.len()).step_by(stride).collect();
    out.points_used = used.len();
    if k_visible == 0 || used.is_empty() {
        out.point_outlier = vec![1.0; used.len()];
        return out;
    }
    let s2 = p.sigma_m * p.sigma_m;
    let radius = p.cutoff_sigmas * p.sigma_m;
    let grid = Grid::new(samples, visible, radius);
    let gauss_norm = (2.0 * std::f64::consts::PI * s2).powf(-1.5);
    let area = |k: usize| sample_areas.get(k).copied().unwrap_or(1.0);
    let visible_area: f64 = (0..samples.len()).filter(|&k| visible[k]).map(area).sum();
    let pi_per_area = (1.0 - p.outlier_weight) / visible_area;
    let outlier_density = p.outlier_weight / outlier_volume_m3;
    let gate = p.normal_gate && point_normals.len() == points.len();
    // per point: (responsibilities of its components, outlier posterior), in parallel
    let per_point: Vec<(Vec<(u32, f64)>, f64)> = used
        .par_iter()
        .map(|&n| {
            let c = &points[n];
            let mut comps: Vec<(u32, f64)> = Vec::new();
            grid.around(c, |k| {
                let d2 = (c - samples[k]).norm_squared();
                if d2 > radius * radius {
                    return;
                }
                if gate && point_normals[n].dot(&sample_normals[k]) < GATE_COS {
                    return;
                }
                let pi_k = pi_per_area * area(k);
                comps.push((k as u32, pi_k * gauss_norm * (-0.5 * d2 / s2).exp()));
            });
            let denom: f64 = comps.iter().map(|c| c.1).sum::<f64>() + outlier_density;
            for c in &mut comps {
                c.1 /= denom;
            }
            (comps, outlier_density / denom)
        })
        .collect();
    // serial accumulation in point order: deterministic sums
    let mut sum_c = vec![Vector3::zeros(); samples.len()];
    let (mut num, mut den, mut outlier) = (0.0, 0.0, 0.0);
    let weight = stride as f64;
    for (&n, (comps, po)) in used.iter().zip(&per_point) {
        for &(k, r) in comps {
            let k = k as usize;
            out.weight[k] += weight * r;
            sum_c[k] += points[n] * (weight * r);
            num += weight * r * (points[n] - samples[k]).norm_squared();
            den += weight * r;
        }
        outlier += po;
    }
    for k in 0..samples.len() {
        if out.weight[k] > 0.0 {
            out.target[k] = sum_c[k] / out.weight[k];
        }
    }
    if den > 0.0 {
        out.sigma2_ml = num / (3.0 * den);
    }
    out.outlier_fraction = outlier / used.len() as f64;
    out.point_outlier = per_point.iter().map(|p| p.1).collect();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_between_two_samples_splits_its_responsibility_and_a_far_point_is_an_outlier() {
        let samples = vec![Vector3::new(0.0, 0.0, 0.0), Vector3::new(0.002, 0.0, 0.0)];
        let normals = vec![Vector3::z(); 2];
        let points = vec![Vector3::new(0.001, 0.0, 0.0), Vector3::new(0.5, 0.5, 0.5)];
        let p = EStepParams {
            sigma_m: 0.001,
            outlier_weight: 0.1,
            cutoff_sigmas: 4.0,
            stride: 1,
            normal_gate: false,
        };
        let e = e_step(
            &points,
            &[],
            &samples,
            &normals,
            &[],
            &[true, true],
            1.0,
            &p,
        );
        assert!((e.weight[0] - e.weight[1]).abs() < 1e-12);
        assert!(e.point_outlier[1] == 1.0);
        assert!(e.point_outlier[0] < 1e-3, "{}", e.point_outlier[0]);
        assert!((e.target[0] - points[0]).norm() < 1e-15);
        // σ²_ML of one point 1 mm from both samples: (1e-6) / 3
        assert!((e.sigma2_ml - 1e-6 / 3.0).abs() < 1e-12);
        // the normal gate removes a component facing the other way
        let flipped = vec![-Vector3::z()];
        let e = e_step(
            &points[..1],
            &flipped,
            &samples,
            &normals,
            &[],
            &[true, true],
            1.0,
            &EStepParams {
                normal_gate: true,
                ..p
            },
        );
        assert_eq!(e.weight, vec![0.0, 0.0]);
    }
}
