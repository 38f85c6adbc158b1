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

/// Cells of [`Grid`] at most (8 MB of offsets); a larger box gets larger cells.
const MAX_GRID_CELLS: usize = 1 << 21;

/// Work per block of the parallel E-step, in points at stride 1. Each block computes its points'
/// responsibilities and sums them into its own per-sample partial sums; the blocks' sums are
/// then added in block order. A point at stride s meets about s times the candidates of a point
/// at stride 1 (its grid cells are √s times wider), so a block holds `POINT_BLOCK / s` used
/// points: the large-σ E-steps, with few points, still split into several blocks. The blocks
/// are fixed by the point count and the stride alone, so the result does not depend on the number
/// of threads.
const POINT_BLOCK: usize = 2048;

/// Samples per task of the blocks' reduction (each sample adds its blocks' sums in block order).
const SAMPLE_CHUNK: usize = 1024;

/// A dense uniform grid over the visible samples with cells of at least the cutoff radius, in
/// compressed rows: the samples of cell c are `items[start[c]..start[c + 1]]`, ascending, cells
/// ordered with z fastest, so the three cells along z around a point are one contiguous run.
/// (A hash map of cells cost a tenth of the tracker's time in hashing 27 keys per point.)
struct Grid {
    origin: Vector3<f64>,
    cell: f64,
    dims: [usize; 3],
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Grid {
    fn new(samples: &[Vector3<f64>], visible: &[bool], radius: f64) -> Self {
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for (s, _) in samples.iter().zip(visible).filter(|(_, v)| **v) {
            lo = lo.inf(s);
            hi = hi.sup(s);
        }
        // cell boundaries on multiples of the cell size (the same cells wherever the box is)
        let origin_at = |c: f64| (lo / c).map(f64::floor) * c;
        let cells_at = |c: f64| (hi - origin_at(c)).map(|v| (v / c).floor().max(0.0) as usize + 1);
        let mut cell = radius;
        while cells_at(cell).iter().product::<usize>() > MAX_GRID_CELLS {
            cell *= 1.25;
        }
        let d = cells_at(cell);
        let dims = [d.x, d.y, d.z];
        let mut grid = Self {
            origin: origin_at(cell),
            cell,
            dims,
            start: vec![0; dims.iter().product::<usize>() + 1],
            items: Vec::new(),
        };
        // counting sort of the visible samples by cell (stable: ascending within a cell)
        let cell_of: Vec<Option<usize>> = samples
            .iter()
            .zip(visible)
            .map(|(s, &v)| v.then(|| grid.index(grid.coords(s))).flatten())
            .collect();
        for c in cell_of.iter().flatten() {
            grid.start[c + 1] += 1;
        }
        for c in 0..grid.start.len() - 1 {
            grid.start[c + 1] += grid.start[c];
        }
        let mut fill = grid.start.clone();
        grid.items = vec![0; grid.start[grid.start.len() - 1] as usize];
        for (k, c) in cell_of.iter().enumerate() {
            if let Some(c) = c {
                grid.items[fill[*c] as usize] = k as u32;
                fill[*c] += 1;
            }
        }
        grid
    }

    fn coords(&self, p: &Vector3<f64>) -> [i64; 3] {
        let q = (p - self.origin) / self.cell;
        [q.x, q.y, q.z].map(|v| v.floor() as i64)
    }

    fn index(&self, c: [i64; 3]) -> Option<usize> {
        let [nx, ny, nz] = self.dims;
        let inside = |v: i64, n: usize| v >= 0 && (v as usize) < n;
        (inside(c[0], nx) && inside(c[1], ny) && inside(c[2], nz))
            .then(|| (c[0] as usize * ny + c[1] as usize) * nz + c[2] as usize)
    }

    /// Candidates around `p`, in a fixed order (neighbour cells in lexicographic offset order,
    /// samples ascending within a cell).
    fn around(&self, p: &Vector3<f64>, mut f: impl FnMut(usize)) {
        let c = self.coords(p);
        let nz = self.dims[2] as i64;
        let (z0, z1) = ((c[2] - 1).max(0), (c[2] + 1).min(nz - 1));
        if z0 > z1 {
            return;
        }
        for dx in -1..=1 {
            for dy in -1..=1 {
                let Some(first) = self.index([c[0] + dx, c[1] + dy, z0]) else {
                    continue;
                };
                let last = first + (z1 - z0) as usize;
                let run = self.start[first] as usize..self.start[last + 1] as usize;
                for &k in &self.items[run] {
                    f(k as usize);
                }
            }
        }
    }
}

/// The partial sums of one block of points: per sample W_k and Σ_n p(z_kn) c_n, the
/// numerator and denominator of σ²_ML, and the block's per-point outlier posteriors.
struct BlockSums {
    weight: Vec<f64>,
    sum_c: Vec<Vector3<f64>>,
    num: f64,
    den: f64,
    outlier: Vec<f64>,
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
    let pi_k: Vec<f64> = (0..samples.len())
        .map(|k| pi_per_area * area(k) * gauss_norm)
        .collect();
    let weight = stride as f64;
    // per block of points, in parallel: responsibilities and their partial sums
    let block_len = POINT_BLOCK.div_ceil(stride).max(1);
    let blocks: Vec<BlockSums> = used
        .par_chunks(block_len)
        .map(|block| {
            let mut b = BlockSums {
                weight: vec![0.0; samples.len()],
                sum_c: vec![Vector3::zeros(); samples.len()],
                num: 0.0,
                den: 0.0,
                outlier: Vec::with_capacity(block.len()),
            };
            let mut comps: Vec<(u32, f64, f64)> = Vec::with_capacity(64);
            for &n in block {
                let c = &points[n];
                comps.clear();
                grid.around(c, |k| {
                    let d2 = (c - samples[k]).norm_squared();
                    if d2 > radius * radius {
                        return;
                    }
                    if gate && point_normals[n].dot(&sample_normals[k]) < GATE_COS {
                        return;
                    }
                    comps.push((k as u32, pi_k[k] * (-0.5 * d2 / s2).exp(), d2));
                });
                let denom: f64 = comps.iter().map(|c| c.1).sum::<f64>() + outlier_density;
                let scale = weight / denom;
                for &(k, g, d2) in &comps {
                    let w = g * scale;
                    b.weight[k as usize] += w;
                    b.sum_c[k as usize] += c * w;
                    b.num += w * d2;
                    b.den += w;
                }
                b.outlier.push(outlier_density / denom);
            }
            b
        })
        .collect();
    // the blocks' sums in block order, per sample (in parallel over samples): deterministic
    out.weight
        .par_chunks_mut(SAMPLE_CHUNK)
        .zip(out.target.par_chunks_mut(SAMPLE_CHUNK))
        .enumerate()
        .for_each(|(chunk, (weight, target))| {
            for (i, (w, t)) in weight.iter_mut().zip(target.iter_mut()).enumerate() {
                let k = chunk * SAMPLE_CHUNK + i;
                let mut sum_c = Vector3::zeros();
                for b in &blocks {
                    *w += b.weight[k];
                    sum_c += b.sum_c[k];
                }
                if *w > 0.0 {
                    *t = sum_c / *w;
                }
            }
        });
    let (mut num, mut den, mut outlier) = (0.0, 0.0, 0.0);
    let mut point_outlier = Vec::with_capacity(used.len());
    for b in &blocks {
        num += b.num;
        den += b.den;
        outlier += b.outlier.iter().sum::<f64>();
        point_outlier.extend_from_slice(&b.outlier);
    }
    if den > 0.0 {
        out.sigma2_ml = num / (3.0 * den);
    }
    out.outlier_fraction = outlier / used.len() as f64;
    out.point_outlier = point_outlier;
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
