//! Sparse bundle adjustment: joint refinement of camera poses, optionally intrinsics and
//! distortion, and 3D points, minimizing the robustified pixel reprojection error through the
//! Brown–Conrady model of [`softcap_core::camera`] (one projection implementation).
//!
//! **Cost.** `F = ½ Σ_ij ρ(‖π_c(X_j) − u_ij‖²)` over the observations given, with ρ the squared,
//! Huber or Cauchy loss of scale δ ([`RobustLoss`]). Each Gauss–Newton linearization weights an
//! observation by `w = ρ'(s)` (iteratively reweighted least squares: the Triggs correction of
//! Triggs et al. 2000, "Bundle adjustment — a modern synthesis", §3.4, with its curvature term
//! dropped, which keeps the normal matrix positive semi-definite); steps are rated on `F` itself.
//!
//! **Parameters.** Camera `c` is `Xc = R_c (X − C_c)`: rotation `R_c` (world → camera), centre
//! `C_c` (world, m), intrinsics `fx, fy, cx, cy` and distortion `k1, k2, p1, p2, k3`. Each camera
//! has [`CAMERA_SLOTS`] update slots: rotation `ω` (rad, left perturbation `R ← exp([ω]×) R`),
//! centre step (m), focal scale `s` (`fx, fy ← (1 + s)·(fx, fy)`, aspect kept), principal point
//! (px) and the five distortion coefficients. Which slots are free is set by [`Refine`] and the
//! gauge; points have 3 free coordinates each.
//!
//! **Gauge.** Reprojection error is invariant under a similarity of the world. [`Gauge`] fixes it
//! explicitly: the pose of one camera is held (with its principal point: shifting it would undo a
//! small rotation of the whole scene about that camera to first order, leaving the rotation gauge
//! barely determined), and the centre of a second camera moves only
//! perpendicular to the baseline between them; after every step the whole scene (centres and
//! points) is scaled about the fixed camera's centre so the baseline keeps its length exactly (the
//! cost does not change under that scaling). With the gauge removed the normal matrix is
//! non-singular for a well-posed rig; its conditioning is reported ([`BundleReport`]).
//!
//! **Solver.** Levenberg–Marquardt with Marquardt's diagonal damping `(H + λ diag H) h = −g` and
//! Nielsen's update of λ (Madsen, Nielsen & Tingleff 2004, Alg. 3.16). The 3×3 point blocks are
//! eliminated per point (Triggs et al. §6.1; Ceres' `DENSE_SCHUR`): with `H = [U W; Wᵀ V]` the
//! reduced camera system `(U − W V⁻¹ Wᵀ) h_c = −g_c + W V⁻¹ g_p` (at most 14 parameters per camera)
//! is assembled in parallel over chunks of points, summed in a fixed order (deterministic for any
//! thread count) and solved densely by faer's Cholesky; then `h_p = V⁻¹ (−g_p − Wᵀ h_c)` per point.
//! Jacobian blocks are recomputed in each pass instead of stored (≈ 45 doubles per observation).
//! Not `softcap_core::levenberg_marquardt`: that solver forms the dense normal equations over a
//! flat parameter vector, which here would be 3 × points + 14 × cameras wide; the per-point
//! elimination, the manifold update of the rotations and the gauge rescaling live only here.

use nalgebra::{
    DMatrix, Matrix2x3, Matrix3, Point3, Rotation3, SMatrix, SVector, Vector2, Vector3,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;

/// Update slots per camera: rotation (3), centre (3), focal scale (1), principal point (2),
/// distortion k1, k2, p1, p2, k3 (5).
pub const CAMERA_SLOTS: usize = 14;
/// Names of the slots, in order.
pub const SLOT_NAMES: [&str; CAMERA_SLOTS] = [
    "rx", "ry", "rz", "Cx", "Cy", "Cz", "f", "cx", "cy", "k1", "k2", "p1", "p2", "k3",
];
const FOCAL: usize = 6;
const PRINCIPAL: usize = 7;
const DISTORTION: usize = 9;

type CamVec = SVector<f64, CAMERA_SLOTS>;
type CamJac = SMatrix<f64, 2, CAMERA_SLOTS>;
type CamPoint = SMatrix<f64, CAMERA_SLOTS, 3>;
type CamBlock = SMatrix<f64, CAMERA_SLOTS, CAMERA_SLOTS>;

/// One 2D observation of point `point` by camera `camera` at pixel `uv`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Index into the cameras.
    pub camera: usize,
    /// Index into the points.
    pub point: usize,
    /// Pixel position `(u, v)`.
    pub uv: Vector2<f64>,
}

/// Which intrinsics are refined (per camera; extrinsics always are, except the gauge's).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Refine {
    /// One focal scale per camera (`fx` and `fy` together, aspect ratio kept).
    pub focal: bool,
    /// Principal point `cx, cy`.
    pub principal_point: bool,
    /// Distortion coefficients `k1, k2, p1, p2, k3` (OpenCV order).
    pub distortion: [bool; 5],
}

/// The default, aniposelib's own parameter set (one focal length and k1 per camera): sparse,
/// noisy labels rarely determine the principal point or higher distortion terms, and freeing them
/// lets an adjustment trade them against the pose (on the aniposelib rig, with `principal,k2` also
/// free, one camera's focal length collapses toward zero).
impl Default for Refine {
    fn default() -> Self {
        Refine {
            focal: true,
            principal_point: false,
            distortion: [true, false, false, false, false],
        }
    }
}

impl Refine {
    /// Extrinsics only.
    pub fn extrinsics_only() -> Self {
        Refine {
            focal: false,
            principal_point: false,
            distortion: [false; 5],
        }
    }

    /// Parses a comma list of `focal`, `principal`, `k1`, `k2`, `p1`, `p2`, `k3`, `tangential`
    /// (p1, p2), `radial` (k1, k2, k3), `distortion` (all five), or `none` (extrinsics only).
    pub fn parse(list: &str) -> Result<Self, String> {
        let mut r = Refine::extrinsics_only();
        for item in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            match item {
                "none" => {}
                "focal" => r.focal = true,
                "principal" => r.principal_point = true,
                "k1" => r.distortion[0] = true,
                "k2" => r.distortion[1] = true,
                "p1" => r.distortion[2] = true,
                "p2" => r.distortion[3] = true,
                "k3" => r.distortion[4] = true,
                "tangential" => (r.distortion[2], r.distortion[3]) = (true, true),
                "radial" => {
                    (r.distortion[0], r.distortion[1], r.distortion[4]) = (true, true, true)
                }
                "distortion" => r.distortion = [true; 5],
                other => {
                    return Err(format!(
                        "unknown parameter `{other}` (expected focal, principal, k1, k2, p1, p2, k3, \
                         radial, tangential, distortion or none)"
                    ));
                }
            }
        }
        Ok(r)
    }

    /// The refined intrinsics as the comma list [`Refine::parse`] reads.
    pub fn describe(&self) -> String {
        let mut v: Vec<&str> = Vec::new();
        if self.focal {
            v.push("focal");
        }
        if self.principal_point {
            v.push("principal");
        }
        for (k, name) in ["k1", "k2", "p1", "p2", "k3"].into_iter().enumerate() {
            if self.distortion[k] {
                v.push(name);
            }
        }
        if v.is_empty() {
            "none".into()
        } else {
            v.join(",")
        }
    }

    fn intrinsic_slots(&self) -> [bool; CAMERA_SLOTS] {
        let mut m = [false; CAMERA_SLOTS];
        m[FOCAL] = self.focal;
        m[PRINCIPAL] = self.principal_point;
        m[PRINCIPAL + 1] = self.principal_point;
        m[DISTORTION..DISTORTION + 5].copy_from_slice(&self.distortion);
        m
    }
}

/// Robust loss ρ(s) of the squared residual norm `s = ‖r‖²` with scale δ (px).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum RobustLoss {
    /// ρ(s) = s.
    Squared,
    /// ρ(s) = s for s ≤ δ², 2δ√s − δ² beyond (quadratic core, linear tails).
    #[default]
    Huber,
    /// ρ(s) = δ² ln(1 + s/δ²) (redescending).
    Cauchy,
}

impl RobustLoss {
    /// `(ρ(s), ρ'(s))`.
    pub fn evaluate(self, s: f64, delta: f64) -> (f64, f64) {
        let d2 = delta * delta;
        match self {
            RobustLoss::Squared => (s, 1.0),
            RobustLoss::Huber if s <= d2 => (s, 1.0),
            RobustLoss::Huber => {
                let r = s.sqrt();
                (2.0 * delta * r - d2, delta / r)
            }
            RobustLoss::Cauchy => ((d2 * (s / d2).ln_1p()), 1.0 / (1.0 + s / d2)),
        }
    }
}

/// The gauge: camera `fixed_camera` keeps its pose; the distance between its centre and
/// `scale_camera`'s stays `distance_m`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Gauge {
    /// Index of the camera whose pose is held.
    pub fixed_camera: usize,
    /// Index of the camera whose distance to the fixed one sets the scale.
    pub scale_camera: usize,
    /// That distance, m.
    pub distance_m: f64,
}

/// Settings of [`bundle_adjust`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BundleSettings {
    /// Intrinsics refined per camera.
    pub refine: Refine,
    /// Loss.
    pub loss: RobustLoss,
    /// Iteration cap (rejected steps count).
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub function_tolerance: f64,
    /// Stop when the largest gradient entry is at most this (cost units per parameter unit).
    pub gradient_tolerance: f64,
    /// Initial damping λ.
    pub initial_damping: f64,
    /// Embedded point iterations after each step (0: plain joint steps).
    pub point_iterations: usize,
    /// Points per parallel chunk of the reduced-system assembly.
    pub chunk_points: usize,
}

impl Default for BundleSettings {
    fn default() -> Self {
        BundleSettings {
            refine: Refine::default(),
            loss: RobustLoss::Huber,
            max_iterations: 100,
            function_tolerance: 1e-6,
            gradient_tolerance: 1e-10,
            initial_damping: 1e-4,
            point_iterations: 2,
            chunk_points: 1024,
        }
    }
}

/// One Levenberg–Marquardt iteration, for progress reporting.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Iteration {
    /// 1-based iteration count.
    pub iteration: usize,
    /// Cost `F` after the iteration (unchanged when the step was rejected).
    pub cost: f64,
    /// Damping λ used for the step.
    pub damping: f64,
    /// Whether the step was accepted.
    pub accepted: bool,
    /// Gain ratio of the step (actual / predicted decrease).
    pub gain_ratio: f64,
}

/// How [`bundle_adjust`] ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BundleStatus {
    /// The relative cost decrease or the gradient fell below its tolerance.
    Converged,
    /// The iteration cap was reached first.
    MaxIterations,
    /// No step lowered the cost even at very large damping (a stationary point or a numerically
    /// singular system).
    DampingOverflow,
}

/// Result of [`bundle_adjust`].
#[derive(Debug, Clone, PartialEq)]
pub struct BundleReport {
    /// Refined cameras.
    pub cameras: Vec<Camera>,
    /// Refined points (points without observations are returned unchanged).
    pub points: Vec<Point3<f64>>,
    /// Cost `F` before and after.
    pub initial_cost: f64,
    /// Final cost.
    pub final_cost: f64,
    /// Iterations run.
    pub iterations: usize,
    /// Status.
    pub status: BundleStatus,
    /// Free camera parameters (rows of the reduced camera system).
    pub free_camera_parameters: usize,
    /// Condition number of the reduced camera system at the solution, Jacobi-scaled (its diagonal
    /// scaled to 1): large means some combination of camera parameters is barely determined.
    pub condition_number: f64,
    /// The camera parameter with the largest weight in the least-determined direction:
    /// `(camera index, slot name)`; `None` when the reduced system could not be formed at the
    /// solution (a point behind a camera or a singular point block).
    pub weakest_parameter: Option<(usize, &'static str)>,
    /// Residual noise estimate `√(Σ w ‖r‖² / (residuals − unknowns))`, px per component.
    pub residual_sigma_px: f64,
    /// Per camera, standard deviations of the refined parameters.
    pub parameter_std: Vec<ParameterStd>,
}

/// Mutable scene: cameras and points.
#[derive(Clone)]
struct Scene {
    cameras: Vec<Camera>,
    points: Vec<Point3<f64>>,
}

/// The observations grouped per point (CSR over `obs`) and the free-slot layout.
struct Layout<'a> {
    obs: &'a [Observation],
    /// Points with observations and the range of `obs` (sorted by point) for each.
    point_ranges: Vec<(usize, std::ops::Range<usize>)>,
    /// Free slots per camera.
    free: Vec<[bool; CAMERA_SLOTS]>,
    n_free: usize,
}

impl<'a> Layout<'a> {
    fn new(obs: &'a [Observation], n_cameras: usize, gauge: &Gauge, refine: &Refine) -> Self {
        let mut point_ranges = Vec::new();
        let mut start = 0;
        while start < obs.len() {
            let p = obs[start].point;
            let mut end = start + 1;
            while end < obs.len() && obs[end].point == p {
                end += 1;
            }
            point_ranges.push((p, start..end));
            start = end;
        }
        let intrinsic = refine.intrinsic_slots();
        let free: Vec<[bool; CAMERA_SLOTS]> = (0..n_cameras)
            .map(|c| {
                let mut m = intrinsic;
                let extrinsic = c != gauge.fixed_camera;
                m[..6].fill(extrinsic);
                if !extrinsic {
                    // The fixed camera keeps its principal point: shifting it undoes a small
                    // rotation of the whole scene about that camera to first order, which would
                    // leave the pose gauge barely determined.
                    m[PRINCIPAL] = false;
                    m[PRINCIPAL + 1] = false;
                }
                if c == gauge.scale_camera {
                    // Centre slots are (b⊥₁, b⊥₂, b) in the baseline frame; b is the scale.
                    m[5] = false;
                }
                m
            })
            .collect();
        let n_free = free.iter().flatten().filter(|f| **f).count();
        Layout {
            obs,
            point_ranges,
            free,
            n_free,
        }
    }
}

/// Linearization of one observation.
struct ObsLin {
    camera: usize,
    r: Vector2<f64>,
    jc: CamJac,
    jp: Matrix2x3<f64>,
    w: f64,
}

/// The solver: fixed data of one bundle-adjustment problem.
struct Problem<'a> {
    layout: Layout<'a>,
    gauge: Gauge,
    loss: RobustLoss,
    delta: f64,
    chunk_points: usize,
}

/// Assembled reduced camera system at one damping.
struct Reduced {
    /// `U − W V⁻¹ Wᵀ` (damped), full 14n × 14n.
    s: DMatrix<f64>,
    /// `−g_c + W V⁻¹ g_p`.
    rhs: DVecF,
    /// Camera gradient `g_c` and Marquardt diagonal `diag U`.
    g_cam: DVecF,
    d_cam: DVecF,
    /// Largest |gradient| over free camera parameters and points.
    g_max: f64,
}

type DVecF = nalgebra::DVector<f64>;

/// Chunk-local accumulator of the reduced system.
struct Partial {
    s: DMatrix<f64>,
    rhs: DVecF,
    g_cam: DVecF,
    d_cam: DVecF,
    g_max: f64,
}

impl<'a> Problem<'a> {
    fn n_cam(&self) -> usize {
        self.layout.free.len()
    }

    /// Rotation from the centre slots to world-frame centre steps: identity except for the scale
    /// camera, whose third slot is the (fixed) baseline direction.
    fn centre_basis(&self, scene: &Scene, c: usize) -> Matrix3<f64> {
        if c != self.gauge.scale_camera {
            return Matrix3::identity();
        }
        let f = &scene.cameras[self.gauge.fixed_camera];
        let b = (scene.cameras[c].centre_world() - f.centre_world()).normalize();
        let helper = if b.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = b.cross(&helper).normalize();
        let e2 = b.cross(&e1);
        Matrix3::from_columns(&[e1, e2, b])
    }

    /// Residual, camera-slot Jacobian and point Jacobian of one observation; `None` when the point
    /// is behind the camera.
    fn linearize_one(
        &self,
        scene: &Scene,
        bases: &[Matrix3<f64>],
        o: &Observation,
    ) -> Option<ObsLin> {
        let cam = &scene.cameras[o.camera];
        let xc = cam.to_camera(&scene.points[o.point]);
        let p = cam.project_camera_point(&xc)?;
        let r = p.uv - o.uv;
        let jp = p.d_camera_point * cam.rotation;
        let mut jc = CamJac::zeros();
        let free = &self.layout.free[o.camera];
        if free[0] {
            // ∂Xc/∂ω = −[Xc]×.
            let jw = -p.d_camera_point * xc.cross_matrix();
            jc.fixed_view_mut::<2, 3>(0, 0).copy_from(&jw);
        }
        if free[3] || free[4] {
            // Xc = R (X − C): ∂/∂C = −∂/∂X, in the centre slots' basis.
            let jcen = -jp * bases[o.camera];
            jc.fixed_view_mut::<2, 3>(0, 3).copy_from(&jcen);
        }
        let di = &p.d_intrinsics;
        if free[FOCAL] {
            let [fx, fy, _, _] = cam.intrinsics;
            jc.set_column(FOCAL, &(di.column(0) * fx + di.column(1) * fy));
        }
        for k in 0..7 {
            if free[PRINCIPAL + k] {
                jc.set_column(PRINCIPAL + k, &di.column(2 + k));
            }
        }
        let (_, w) = self.loss.evaluate(r.norm_squared(), self.delta);
        Some(ObsLin {
            camera: o.camera,
            r,
            jc,
            jp,
            w,
        })
    }

    /// Robust cost `½ Σ ρ(‖r‖²)`; infinite if a point falls behind a camera.
    fn cost(&self, scene: &Scene) -> f64 {
        let chunks: Vec<f64> = self
            .layout
            .point_ranges
            .par_chunks(self.chunk_points)
            .map(|chunk| {
                let mut sum = 0.0;
                for (_, range) in chunk {
                    for o in &self.layout.obs[range.clone()] {
                        let cam = &scene.cameras[o.camera];
                        match cam.project(&scene.points[o.point]) {
                            Some(uv) => {
                                sum += self.loss.evaluate((uv - o.uv).norm_squared(), self.delta).0
                            }
                            None => return f64::INFINITY,
                        }
                    }
                }
                sum
            })
            .collect();
        0.5 * chunks.into_iter().sum::<f64>()
    }

    /// Damped point block `V + λ diag V` and its inverse, and `g_p`.
    fn point_block(
        lins: &[ObsLin],
        lambda: f64,
    ) -> Option<(Matrix3<f64>, Matrix3<f64>, Vector3<f64>)> {
        let mut v = Matrix3::zeros();
        let mut g = Vector3::zeros();
        for l in lins {
            v += l.w * l.jp.transpose() * l.jp;
            g += l.w * l.jp.transpose() * l.r;
        }
        let mut vd = v;
        for k in 0..3 {
            vd[(k, k)] += lambda * v[(k, k)].max(1e-12);
        }
        Some((v, vd.try_inverse()?, g))
    }

    fn linearize_point(
        &self,
        scene: &Scene,
        bases: &[Matrix3<f64>],
        range: &std::ops::Range<usize>,
        lins: &mut Vec<ObsLin>,
    ) -> bool {
        lins.clear();
        for o in &self.layout.obs[range.clone()] {
            match self.linearize_one(scene, bases, o) {
                Some(l) => lins.push(l),
                None => return false,
            }
        }
        true
    }

    /// Assembles the reduced camera system at damping λ (see module docs).
    fn reduce(&self, scene: &Scene, lambda: f64) -> Option<Reduced> {
        let n = CAMERA_SLOTS * self.n_cam();
        let bases: Vec<Matrix3<f64>> = (0..self.n_cam())
            .map(|c| self.centre_basis(scene, c))
            .collect();
        let partials: Vec<Option<Partial>> = self
            .layout
            .point_ranges
            .par_chunks(self.chunk_points)
            .map(|chunk| {
                let mut part = Partial {
                    s: DMatrix::zeros(n, n),
                    rhs: DVecF::zeros(n),
                    g_cam: DVecF::zeros(n),
                    d_cam: DVecF::zeros(n),
                    g_max: 0.0,
                };
                let mut lins = Vec::new();
                let mut wy: Vec<(CamPoint, CamPoint)> = Vec::new();
                for (_, range) in chunk {
                    if !self.linearize_point(scene, &bases, range, &mut lins) {
                        return None;
                    }
                    let (_, vinv, gp) = Self::point_block(&lins, lambda)?;
                    part.g_max = part.g_max.max(gp.amax());
                    wy.clear();
                    for l in &lins {
                        let o = CAMERA_SLOTS * l.camera;
                        let jtj: CamBlock = l.w * l.jc.transpose() * l.jc;
                        let mut block = part.s.fixed_view_mut::<CAMERA_SLOTS, CAMERA_SLOTS>(o, o);
                        block += jtj;
                        let g: CamVec = l.w * l.jc.transpose() * l.r;
                        let mut gv = part.g_cam.fixed_rows_mut::<CAMERA_SLOTS>(o);
                        gv += g;
                        let mut dv = part.d_cam.fixed_rows_mut::<CAMERA_SLOTS>(o);
                        dv += jtj.diagonal();
                        let w: CamPoint = l.w * l.jc.transpose() * l.jp;
                        let y: CamPoint = w * vinv;
                        let mut rv = part.rhs.fixed_rows_mut::<CAMERA_SLOTS>(o);
                        rv += y * gp;
                        wy.push((w, y));
                    }
                    for a in 0..lins.len() {
                        for b in a..lins.len() {
                            let (ca, cb) = (lins[a].camera, lins[b].camera);
                            let m: CamBlock = wy[a].1 * wy[b].0.transpose();
                            let (oa, ob) = (CAMERA_SLOTS * ca, CAMERA_SLOTS * cb);
                            if ca < cb {
                                let mut blk =
                                    part.s.fixed_view_mut::<CAMERA_SLOTS, CAMERA_SLOTS>(oa, ob);
                                blk -= m;
                            } else if ca > cb {
                                let mut blk =
                                    part.s.fixed_view_mut::<CAMERA_SLOTS, CAMERA_SLOTS>(ob, oa);
                                blk -= m.transpose();
                            } else {
                                let mut blk =
                                    part.s.fixed_view_mut::<CAMERA_SLOTS, CAMERA_SLOTS>(oa, oa);
                                if a == b {
                                    blk -= m;
                                } else {
                                    blk -= m + m.transpose();
                                }
                            }
                        }
                    }
                }
                Some(part)
            })
            .collect();
        let mut total = Partial {
            s: DMatrix::zeros(n, n),
            rhs: DVecF::zeros(n),
            g_cam: DVecF::zeros(n),
            d_cam: DVecF::zeros(n),
            g_max: 0.0,
        };
        for p in partials {
            let p = p?;
            total.s += p.s;
            total.rhs += p.rhs;
            total.g_cam += p.g_cam;
            total.d_cam += p.d_cam;
            total.g_max = total.g_max.max(p.g_max);
        }
        // Mirror the upper block triangle; damp the camera diagonal; rhs = −g_c + W V⁻¹ g_p.
        for i in 0..n {
            for j in 0..i {
                let (bi, bj) = (i / CAMERA_SLOTS, j / CAMERA_SLOTS);
                if bi != bj {
                    total.s[(i, j)] = total.s[(j, i)];
                }
            }
        }
        for c in 0..self.n_cam() {
            for k in 0..CAMERA_SLOTS {
                let i = CAMERA_SLOTS * c + k;
                if self.layout.free[c][k] {
                    total.g_max = total.g_max.max(total.g_cam[i].abs());
                }
                total.d_cam[i] = total.d_cam[i].max(1e-12);
                total.s[(i, i)] += lambda * total.d_cam[i];
            }
        }
        total.rhs -= &total.g_cam;
        Some(Reduced {
            s: total.s,
            rhs: total.rhs,
            g_cam: total.g_cam,
            d_cam: total.d_cam,
            g_max: total.g_max,
        })
    }

    /// Solves the reduced system for the free camera slots (faer Cholesky); `None` if not
    /// positive definite.
    fn solve_cameras(&self, red: &Reduced) -> Option<DVecF> {
        let free: Vec<usize> = self.free_rows();
        let m = free.len();
        let a = faer::Mat::<f64>::from_fn(m, m, |i, j| red.s[(free[i], free[j])]);
        let b = faer::Mat::<f64>::from_fn(m, 1, |i, _| red.rhs[free[i]]);
        let llt = a.llt(faer::Side::Lower).ok()?;
        let x = faer::linalg::solvers::Solve::solve(&llt, &b);
        let mut h = DVecF::zeros(red.s.nrows());
        for (i, &row) in free.iter().enumerate() {
            h[row] = x[(i, 0)];
        }
        h.iter().all(|v| v.is_finite()).then_some(h)
    }

    fn free_rows(&self) -> Vec<usize> {
        (0..self.n_cam())
            .flat_map(|c| {
                (0..CAMERA_SLOTS)
                    .filter(move |&k| self.layout.free[c][k])
                    .map(move |k| CAMERA_SLOTS * c + k)
            })
            .collect()
    }

    /// Point steps `h_p = V⁻¹(−g_p − Wᵀ h_c)` and the point parts of `hᵀg` and `hᵀ D h`.
    fn back_substitute(
        &self,
        scene: &Scene,
        lambda: f64,
        h_cam: &DVecF,
    ) -> Option<(Vec<Vector3<f64>>, f64, f64)> {
        let bases: Vec<Matrix3<f64>> = (0..self.n_cam())
            .map(|c| self.centre_basis(scene, c))
            .collect();
        let chunks: Vec<Option<(Vec<Vector3<f64>>, f64, f64)>> = self
            .layout
            .point_ranges
            .par_chunks(self.chunk_points)
            .map(|chunk| {
                let mut lins = Vec::new();
                let mut steps = Vec::with_capacity(chunk.len());
                let (mut hg, mut hdh) = (0.0, 0.0);
                for (_, range) in chunk {
                    if !self.linearize_point(scene, &bases, range, &mut lins) {
                        return None;
                    }
                    let (v, vinv, gp) = Self::point_block(&lins, lambda)?;
                    let mut b = -gp;
                    for l in &lins {
                        let hc = h_cam.fixed_rows::<CAMERA_SLOTS>(CAMERA_SLOTS * l.camera);
                        b -= l.w * l.jp.transpose() * (l.jc * hc);
                    }
                    let hp = vinv * b;
                    hg += hp.dot(&gp);
                    for k in 0..3 {
                        hdh += v[(k, k)].max(1e-12) * hp[k] * hp[k];
                    }
                    steps.push(hp);
                }
                Some((steps, hg, hdh))
            })
            .collect();
        let mut steps = Vec::with_capacity(self.layout.point_ranges.len());
        let (mut hg, mut hdh) = (0.0, 0.0);
        for c in chunks {
            let (s, a, b) = c?;
            steps.extend(s);
            hg += a;
            hdh += b;
        }
        Some((steps, hg, hdh))
    }

    /// The scene after the step, with the gauge's scale restored exactly.
    fn apply(&self, scene: &Scene, h_cam: &DVecF, h_points: &[Vector3<f64>]) -> Scene {
        let mut out = self.apply_without_gauge(scene, h_cam, h_points);
        rescale_to_gauge(&mut out, &self.gauge);
        out
    }

    /// The manifold update the Jacobians differentiate: `R ← exp([ω]×) R`, `C ← C + B h_C`,
    /// `f ← (1 + s) f`, additive principal point, distortion and points.
    fn apply_without_gauge(
        &self,
        scene: &Scene,
        h_cam: &DVecF,
        h_points: &[Vector3<f64>],
    ) -> Scene {
        let mut out = scene.clone();
        for c in 0..self.n_cam() {
            let h = h_cam.fixed_rows::<CAMERA_SLOTS>(CAMERA_SLOTS * c);
            let cam = &mut out.cameras[c];
            let centre =
                cam.centre_world().coords + self.centre_basis(scene, c) * h.fixed_rows::<3>(3);
            let omega = Vector3::new(h[0], h[1], h[2]);
            cam.rotation = Rotation3::new(omega).into_inner() * cam.rotation;
            cam.translation_m = -(cam.rotation * centre);
            let scale = 1.0 + h[FOCAL];
            cam.intrinsics[0] *= scale;
            cam.intrinsics[1] *= scale;
            cam.intrinsics[2] += h[PRINCIPAL];
            cam.intrinsics[3] += h[PRINCIPAL + 1];
            for k in 0..5 {
                cam.distortion[k] += h[DISTORTION + k];
            }
        }
        for ((p, _), hp) in self.layout.point_ranges.iter().zip(h_points) {
            out.points[*p] += hp;
        }
        out
    }

    /// At the solution: the Jacobi-scaled condition number of the undamped reduced system, the
    /// parameter dominating its weakest direction, and the per-camera standard deviations
    /// `σ² diag(S⁻¹)` (S⁻¹ is the camera block of the inverse normal matrix; σ² the
    /// weighted residual sum of squares over its degrees of freedom).
    fn uncertainty(&self, scene: &Scene) -> Uncertainty {
        let n_cam = self.n_cam();
        let unknown = Uncertainty {
            condition_number: f64::INFINITY,
            weakest: None,
            residual_sigma_px: f64::NAN,
            std: vec![ParameterStd::default(); n_cam],
        };
        // Undamped: any damping would bound the condition number by about m/λ and hide a
        // singular direction. Points are well triangulated (the caller drops narrow ones), so
        // their 3×3 blocks are normally invertible; if one is exactly singular, a 1e-12 relative
        // damping (a bound of ≈ 1e12 on the condition number, the ill-conditioning threshold)
        // keeps the report about the cameras.
        let Some(red) = self
            .reduce(scene, 0.0)
            .or_else(|| self.reduce(scene, 1e-12))
        else {
            return unknown;
        };
        let free = self.free_rows();
        let m = free.len();
        let residuals = 2 * self.layout.obs.len();
        let unknowns = m + 3 * self.layout.point_ranges.len();
        let residual_sigma_px =
            (self.weighted_rss(scene) / residuals.saturating_sub(unknowns).max(1) as f64).sqrt();
        if m == 0 {
            return Uncertainty {
                condition_number: 1.0,
                residual_sigma_px,
                ..unknown
            };
        }
        // A parameter whose Schur-complement diagonal is not positive is determined by nothing
        // the points leave after their own elimination.
        if let Some(&row) = free
            .iter()
            .find(|&&i| !red.s[(i, i)].is_finite() || red.s[(i, i)] <= 0.0)
        {
            return Uncertainty {
                weakest: Some((row / CAMERA_SLOTS, SLOT_NAMES[row % CAMERA_SLOTS])),
                residual_sigma_px,
                ..unknown
            };
        }
        let scale: Vec<f64> = free.iter().map(|&i| 1.0 / red.s[(i, i)].sqrt()).collect();
        let a = DMatrix::from_fn(m, m, |i, j| red.s[(free[i], free[j])] * scale[i] * scale[j]);
        let eig = a.symmetric_eigen();
        let (kmin, &lmin) = eig
            .eigenvalues
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))
            .unwrap_or((0, &0.0));
        let lmax = eig.eigenvalues.iter().copied().fold(0.0, f64::max);
        let row = free[eig.eigenvectors.column(kmin).iamax()];
        if lmin.is_nan() || lmin <= 0.0 {
            return Uncertainty {
                weakest: Some((row / CAMERA_SLOTS, SLOT_NAMES[row % CAMERA_SLOTS])),
                residual_sigma_px,
                ..unknown
            };
        }
        // diag(S⁻¹)_i = scale_i² Σ_k V_ik² / λ_k.
        let mut variance = vec![0.0; CAMERA_SLOTS * n_cam];
        for (i, &r) in free.iter().enumerate() {
            let v: f64 = (0..m)
                .map(|k| eig.eigenvectors[(i, k)].powi(2) / eig.eigenvalues[k])
                .sum();
            variance[r] = residual_sigma_px.powi(2) * scale[i] * scale[i] * v;
        }
        let std = (0..n_cam)
            .map(|c| {
                let sum = |r: std::ops::Range<usize>| {
                    r.map(|k| variance[CAMERA_SLOTS * c + k])
                        .sum::<f64>()
                        .sqrt()
                };
                ParameterStd {
                    rotation_rad: sum(0..3),
                    centre_m: sum(3..6),
                    focal_relative: sum(FOCAL..FOCAL + 1),
                    principal_px: sum(PRINCIPAL..PRINCIPAL + 2),
                }
            })
            .collect();
        Uncertainty {
            condition_number: lmax / lmin,
            weakest: Some((row / CAMERA_SLOTS, SLOT_NAMES[row % CAMERA_SLOTS])),
            residual_sigma_px,
            std,
        }
    }

    /// Embedded point iterations (Jeong, Nistér, Steedly, Szeliski & Kweon 2012, "Pushing the
    /// envelope of modern methods for bundle adjustment", §4.2): after a step, every point is
    /// re-optimized alone for the trial cameras by up to `iterations` Gauss–Newton steps on its
    /// robust cost (each kept only if it lowers that cost). The trial cost is then nearly that of
    /// the cameras with their best points, so steps along badly conditioned point directions (two
    /// nearly parallel rays) are not rejected for the points' nonlinearity; the decrease predicted
    /// by the joint model stays a lower bound of the actual one.
    fn refine_points(&self, scene: &mut Scene, iterations: usize) {
        if iterations == 0 {
            return;
        }
        let cameras = &scene.cameras;
        let points = &scene.points;
        let refined: Vec<Vec<Point3<f64>>> = self
            .layout
            .point_ranges
            .par_chunks(self.chunk_points)
            .map(|chunk| {
                chunk
                    .iter()
                    .map(|(p, range)| {
                        self.refine_point(
                            cameras,
                            &self.layout.obs[range.clone()],
                            points[*p],
                            iterations,
                        )
                    })
                    .collect()
            })
            .collect();
        for ((p, _), x) in self
            .layout
            .point_ranges
            .iter()
            .zip(refined.into_iter().flatten())
        {
            scene.points[*p] = x;
        }
    }

    fn refine_point(
        &self,
        cameras: &[Camera],
        obs: &[Observation],
        start: Point3<f64>,
        iterations: usize,
    ) -> Point3<f64> {
        let cost = |x: &Point3<f64>| -> f64 {
            obs.iter()
                .map(|o| {
                    cameras[o.camera].project(x).map_or(f64::INFINITY, |uv| {
                        self.loss.evaluate((uv - o.uv).norm_squared(), self.delta).0
                    })
                })
                .sum()
        };
        let mut x = start;
        let mut fx = cost(&x);
        for _ in 0..iterations {
            let mut v = Matrix3::zeros();
            let mut g = Vector3::zeros();
            for o in obs {
                let Some((uv, j)) = cameras[o.camera].project_with_jacobian(&x) else {
                    return x;
                };
                let r = uv - o.uv;
                let w = self.loss.evaluate(r.norm_squared(), self.delta).1;
                v += w * j.transpose() * j;
                g += w * j.transpose() * r;
            }
            for k in 0..3 {
                v[(k, k)] *= 1.0 + 1e-9;
            }
            let Some(step) = v.try_inverse().map(|vi| -(vi * g)) else {
                return x;
            };
            let trial = x + step;
            let ft = cost(&trial);
            if ft.is_nan() || ft >= fx {
                return x;
            }
            (x, fx) = (trial, ft);
        }
        x
    }

    /// `Σ w ‖r‖²` at `scene` (the IRLS-weighted residual sum of squares).
    fn weighted_rss(&self, scene: &Scene) -> f64 {
        let mut sum = 0.0;
        for o in self.layout.obs {
            if let Some(uv) = scene.cameras[o.camera].project(&scene.points[o.point]) {
                let s = (uv - o.uv).norm_squared();
                sum += self.loss.evaluate(s, self.delta).1 * s;
            }
        }
        sum
    }
}

/// [`Problem::uncertainty`].
struct Uncertainty {
    condition_number: f64,
    weakest: Option<(usize, &'static str)>,
    residual_sigma_px: f64,
    std: Vec<ParameterStd>,
}

/// Standard deviations of one camera's refined parameters, from the inverse of the reduced
/// camera system scaled by the residual variance (zero for held parameters; a linearization:
/// meaningful when the condition number is moderate).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct ParameterStd {
    /// Rotation, rad (root of the summed variances of the three rotation slots).
    pub rotation_rad: f64,
    /// Centre, m (root of the summed variances of the three centre slots).
    pub centre_m: f64,
    /// Focal length, relative.
    pub focal_relative: f64,
    /// Principal point, px (root of the summed variances of cx and cy).
    pub principal_px: f64,
}

/// Scales centres and points about the fixed camera's centre so the gauge distance holds.
fn rescale_to_gauge(scene: &mut Scene, gauge: &Gauge) {
    let origin = scene.cameras[gauge.fixed_camera].centre_world().coords;
    let current = (scene.cameras[gauge.scale_camera].centre_world().coords - origin).norm();
    if !(current > 0.0 && current.is_finite()) {
        return;
    }
    let k = gauge.distance_m / current;
    for cam in scene.cameras.iter_mut() {
        let c = origin + k * (cam.centre_world().coords - origin);
        cam.translation_m = -(cam.rotation * c);
    }
    for p in scene.points.iter_mut() {
        p.coords = origin + k * (p.coords - origin);
    }
}

/// Refines `cameras` and `points` from `observations` (each point should have ≥ 2; any order) by
/// robust Levenberg–Marquardt on the Schur complement, in the gauge `gauge` (see module docs).
/// `delta` is the loss scale, px. `progress` is called after every iteration.
///
/// The scene is first scaled to the gauge distance. Non-convergence is a [`BundleStatus`], not
/// an error; the returned cameras are not re-validated (see `Camera::new`).
pub fn bundle_adjust(
    cameras: &[Camera],
    points: &[Point3<f64>],
    observations: &[Observation],
    gauge: &Gauge,
    delta: f64,
    settings: &BundleSettings,
    progress: &mut dyn FnMut(&Iteration),
) -> BundleReport {
    let mut obs = observations.to_vec();
    obs.sort_by_key(|o| (o.point, o.camera));
    let layout = Layout::new(&obs, cameras.len(), gauge, &settings.refine);
    let problem = Problem {
        layout,
        gauge: *gauge,
        loss: settings.loss,
        delta,
        chunk_points: settings.chunk_points.max(1),
    };
    let mut scene = Scene {
        cameras: cameras.to_vec(),
        points: points.to_vec(),
    };
    rescale_to_gauge(&mut scene, gauge);
    let initial_cost = problem.cost(&scene);
    let mut cost = initial_cost;
    let mut lambda = settings.initial_damping;
    let mut nu = 2.0;
    let mut status = BundleStatus::MaxIterations;
    let mut iterations = 0;
    while iterations < settings.max_iterations {
        iterations += 1;
        let step = problem.reduce(&scene, lambda).and_then(|red| {
            if red.g_max <= settings.gradient_tolerance {
                return Some(Err(()));
            }
            let h_cam = problem.solve_cameras(&red)?;
            let (h_points, hg_p, hdh_p) = problem.back_substitute(&scene, lambda, &h_cam)?;
            let hg = h_cam.dot(&red.g_cam) + hg_p;
            let hdh = h_cam.component_mul(&h_cam).dot(&red.d_cam) + hdh_p;
            Some(Ok((h_cam, h_points, 0.5 * (lambda * hdh - hg))))
        });
        let (accepted, gain) = match step {
            Some(Err(())) => {
                status = BundleStatus::Converged;
                break;
            }
            Some(Ok((h_cam, h_points, predicted))) if predicted > 0.0 => {
                let mut trial = problem.apply(&scene, &h_cam, &h_points);
                problem.refine_points(&mut trial, settings.point_iterations);
                let trial_cost = problem.cost(&trial);
                let gain = (cost - trial_cost) / predicted;
                if trial_cost.is_finite() && gain > 0.0 {
                    let relative = (cost - trial_cost) / cost.max(f64::MIN_POSITIVE);
                    scene = trial;
                    cost = trial_cost;
                    progress(&Iteration {
                        iteration: iterations,
                        cost,
                        damping: lambda,
                        accepted: true,
                        gain_ratio: gain,
                    });
                    lambda *= (1.0 - (2.0 * gain - 1.0).powi(3)).max(1.0 / 3.0);
                    nu = 2.0;
                    if relative < settings.function_tolerance {
                        status = BundleStatus::Converged;
                        break;
                    }
                    continue;
                }
                (false, gain)
            }
            _ => (false, f64::NAN),
        };
        progress(&Iteration {
            iteration: iterations,
            cost,
            damping: lambda,
            accepted,
            gain_ratio: gain,
        });
        lambda *= nu;
        nu *= 2.0;
        if lambda > 1e32 {
            status = BundleStatus::DampingOverflow;
            break;
        }
    }
    let u = problem.uncertainty(&scene);
    BundleReport {
        free_camera_parameters: problem.layout.n_free,
        cameras: scene.cameras,
        points: scene.points,
        initial_cost,
        final_cost: cost,
        iterations,
        status,
        condition_number: u.condition_number,
        weakest_parameter: u.weakest,
        residual_sigma_px: u.residual_sigma_px,
        parameter_std: u.std,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera::new(
            "c".into(),
            640,
            480,
            [700.0, 705.0, 322.0, 241.0],
            [-0.2, 0.05, 1e-3, -2e-3, 0.01],
            Rotation3::from_euler_angles(0.2, -0.3, 0.1).into_inner(),
            Vector3::new(0.05, -0.02, 0.6),
        )
        .unwrap()
    }

    /// The analytic camera-slot and point Jacobians against central differences of the projection
    /// under the same manifold update the solver applies — for a plain camera and for the scale
    /// camera, whose centre slots live in the baseline frame.
    #[test]
    fn jacobians_match_finite_differences() {
        let at = |x: f64| {
            Camera::new(
                "f".into(),
                640,
                480,
                [700.0, 700.0, 320.0, 240.0],
                [0.0; 5],
                Matrix3::identity(),
                Vector3::new(x, 0.0, 0.6),
            )
            .unwrap()
        };
        let scene = Scene {
            cameras: vec![at(0.3), camera(), at(-0.3)],
            points: vec![Point3::new(0.04, 0.03, -0.02)],
        };
        let obs = [Observation {
            camera: 1,
            point: 0,
            uv: Vector2::new(300.0, 200.0),
        }];
        let refine = Refine {
            focal: true,
            principal_point: true,
            distortion: [true; 5],
        };
        for scale_camera in [2, 1] {
            let gauge = Gauge {
                fixed_camera: 0,
                scale_camera,
                distance_m: 1.0,
            };
            let problem = Problem {
                layout: Layout::new(&obs, 3, &gauge, &refine),
                gauge,
                loss: RobustLoss::Squared,
                delta: 1.0,
                chunk_points: 16,
            };
            let bases: Vec<Matrix3<f64>> =
                (0..3).map(|c| problem.centre_basis(&scene, c)).collect();
            let lin = problem.linearize_one(&scene, &bases, &obs[0]).unwrap();
            let project = |h_cam: &DVecF, hp: Vector3<f64>| {
                let s = problem.apply_without_gauge(&scene, h_cam, &[hp]);
                s.cameras[1].project(&s.points[0]).unwrap()
            };
            let eps = 1e-6;
            let free = problem.layout.free[1];
            assert_eq!(free[5], scale_camera != 1, "the baseline slot is fixed");
            for k in (0..CAMERA_SLOTS).filter(|&k| free[k]) {
                let step = |sign: f64| {
                    let mut h = DVecF::zeros(3 * CAMERA_SLOTS);
                    h[CAMERA_SLOTS + k] = sign * eps;
                    project(&h, Vector3::zeros())
                };
                let fd = (step(1.0) - step(-1.0)) / (2.0 * eps);
                let col = lin.jc.column(k);
                assert!(
                    (fd - col).norm() <= 1e-5 * fd.norm().max(1.0),
                    "scale camera {scale_camera}, slot {}: fd {fd} vs analytic {col}",
                    SLOT_NAMES[k]
                );
            }
            for k in 0..3 {
                let step = |sign: f64| {
                    let mut hp = Vector3::zeros();
                    hp[k] = sign * eps;
                    project(&DVecF::zeros(3 * CAMERA_SLOTS), hp)
                };
                let fd = (step(1.0) - step(-1.0)) / (2.0 * eps);
                assert!((fd - lin.jp.column(k)).norm() <= 1e-5 * fd.norm().max(1.0));
            }
        }
    }

    #[test]
    fn losses_and_their_derivatives() {
        for loss in [RobustLoss::Squared, RobustLoss::Huber, RobustLoss::Cauchy] {
            for s in [0.25, 1.0, 4.0, 30.0] {
                let (_, d) = loss.evaluate(s, 1.5);
                let h = 1e-6;
                let fd = (loss.evaluate(s + h, 1.5).0 - loss.evaluate(s - h, 1.5).0) / (2.0 * h);
                assert!((fd - d).abs() < 1e-6, "{loss:?} s = {s}: {fd} vs {d}");
            }
        }
        assert_eq!(
            RobustLoss::Huber.evaluate(100.0, 2.0),
            (2.0 * 2.0 * 10.0 - 4.0, 0.2)
        );
    }

    #[test]
    fn refine_lists_round_trip() {
        for list in ["focal,principal,k1,k2", "none", "focal,k1,p1,p2,k3"] {
            assert_eq!(Refine::parse(list).unwrap().describe(), list);
        }
        assert_eq!(
            Refine::parse("radial").unwrap().distortion,
            [true, true, false, false, true]
        );
        assert!(Refine::parse("skew").unwrap_err().contains("skew"));
    }
}
