//! 3D wrinkle synthesis (thesis §3.3.1): the image-space wrinkles of §4.3 (valley spline and
//! per-cross-section (d, w)) are projected through the camera onto the large-scale (linearly
//! deformed) face, the valley vertices are offset along smoothed normals by the cross-section
//! profile S(w, d, p), and the remaining vertices of each automatically segmented wrinkle
//! region are found by minimising the non-linear discrete-shell energy (thesis eq. 3.6,
//! Grinspun et al. 2003)
//!
//! ```text
//! E = Σ_e k_e (‖e‖ − ‖ē‖)²/‖ē‖ + Σ_e k_b ‖ē‖ (θ_e − θ̄_e)²/h̄_e + Σ_t k_a (‖t‖ − ‖t̄‖)²/‖t̄‖
//! ```
//!
//! by Gauss–Newton (sparse normal equations, faer sparse Cholesky, backtracking line search).
//! Barred quantities are taken on the rest scan F; h̄_e is a third of the mean height of the
//! two triangles at e (Grinspun et al. 2003), θ the signed dihedral angle between the normals.
//!
//! The thesis maps the deformed face into mocap space with c⁻¹ before projecting and back with c
//! afterwards; here the camera is given directly in face space (`world_from_camera`), which is
//! the same thing once the camera has been expressed in face coordinates.

use std::collections::BTreeMap;

use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};
use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};
use softcap_mesh::TriMesh;

use crate::cross_section::wrinkle_profile;
use crate::error::{FaceError, Result};
use crate::raster::vertex_normals;
use crate::track::TrackedWrinkle;

/// A pinhole camera (OpenCV convention: x right, y down, z forward in the camera frame).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PinholeCamera {
    /// Pose: camera frame → face (world) frame.
    pub world_from_camera: Isometry3<f64>,
    /// Focal length in pixels.
    pub focal_px: f64,
    /// Principal point in pixels.
    pub principal_px: [f64; 2],
}

impl PinholeCamera {
    /// Camera centre and unit ray direction (world frame) through pixel `px`.
    pub fn ray(&self, px: [f64; 2]) -> (Vector3<f64>, Vector3<f64>) {
        let d_cam = Vector3::new(
            (px[0] - self.principal_px[0]) / self.focal_px,
            (px[1] - self.principal_px[1]) / self.focal_px,
            1.0,
        );
        let origin = self.world_from_camera.translation.vector;
        (
            origin,
            (self.world_from_camera.rotation * d_cam).normalize(),
        )
    }

    /// Pixel of a world point, `None` behind the camera.
    pub fn project(&self, x_world: &Vector3<f64>) -> Option<[f64; 2]> {
        let x = self
            .world_from_camera
            .inverse_transform_point(&Point3::from(*x_world));
        (x.z > 0.0).then(|| {
            [
                self.focal_px * x.x / x.z + self.principal_px[0],
                self.focal_px * x.y / x.z + self.principal_px[1],
            ]
        })
    }

    /// World length of one pixel at the depth of `x_world` (fronto-parallel footprint).
    pub fn world_per_px(&self, x_world: &Vector3<f64>) -> f64 {
        let x = self
            .world_from_camera
            .inverse_transform_point(&Point3::from(*x_world));
        x.z / self.focal_px
    }
}

/// One cross-section of an image-space wrinkle.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WrinkleSample {
    /// Valley point (pixels).
    pub valley_px: [f64; 2],
    /// Depth d (pixels).
    pub depth_px: f64,
    /// Width w (pixels).
    pub width_px: f64,
}

/// An image-space wrinkle: cross-sections ordered along the valley.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct WrinkleCurve {
    /// Cross-sections in valley order.
    pub samples: Vec<WrinkleSample>,
}

impl WrinkleCurve {
    /// The converged cross-sections of a tracked wrinkle (thesis §4.3).
    pub fn from_tracked(t: &TrackedWrinkle) -> Self {
        Self {
            samples: t
                .sections
                .iter()
                .filter(|s| s.converged)
                .map(|s| WrinkleSample {
                    valley_px: s.valley_px,
                    depth_px: s.depth_px,
                    width_px: s.width_px,
                })
                .collect(),
        }
    }
}

/// A wrinkle projected onto the deformed face: valley polyline with world-unit (d, w).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ProjectedWrinkle {
    /// Valley points on the surface (world).
    pub points: Vec<Vector3<f64>>,
    /// Depth d at each point (world units).
    pub depth: Vec<f64>,
    /// Width w at each point (world units).
    pub width: Vec<f64>,
}

/// Settings of the synthesis (thesis §3.3.1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SynthesisSettings {
    /// Edge-length stiffness k_e (thesis: 300).
    pub k_e: f64,
    /// Bending stiffness k_b (thesis: 2).
    pub k_b: f64,
    /// Area stiffness k_a (thesis: 30 000).
    pub k_a: f64,
    /// Maximum influence distance of a wrinkle, in multiples of its local width w.
    pub influence_widths: f64,
    /// Umbrella smoothing passes applied to the vertex normals.
    pub normal_smoothing_passes: usize,
    /// Gauss–Newton iteration cap per region.
    pub max_iterations: usize,
    /// Stop when the relative energy decrease of an iteration falls below this. Gauss–Newton
    /// on eq. 3.6 converges linearly here (the residuals do not vanish at the minimum: the
    /// valley is imposed, so the shell stays stretched; on the face scene the decrease shrinks
    /// by ≈ 0.85 per iteration), so the energy left to gain is ≈ 6× the last decrease.
    pub relative_tolerance: f64,
}

impl Default for SynthesisSettings {
    fn default() -> Self {
        Self {
            k_e: 300.0,
            k_b: 2.0,
            k_a: 30_000.0,
            influence_widths: 4.0,
            normal_smoothing_passes: 3,
            max_iterations: 60,
            relative_tolerance: 1e-5,
        }
    }
}

/// Outcome of the Gauss–Newton minimisation on one wrinkle region.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegionReport {
    /// Free (optimised) vertices.
    pub free_vertices: usize,
    /// Valley (constrained) vertices.
    pub valley_vertices: usize,
    /// Shell energy after the valley offset, before minimisation.
    pub initial_energy: f64,
    /// Shell energy at the end.
    pub final_energy: f64,
    /// Gauss–Newton iterations used.
    pub iterations: usize,
    /// Whether the relative-decrease criterion was met.
    pub converged: bool,
}

/// Result of [`synthesize_wrinkles`].
#[derive(Clone, Debug, PartialEq)]
pub struct SynthesisResult {
    /// Final vertex positions.
    pub vertices: Vec<Vector3<f64>>,
    /// Per-vertex signed offset S applied to valley vertices (0 elsewhere).
    pub valley_offset: Vec<f64>,
    /// One report per segmented region.
    pub regions: Vec<RegionReport>,
    /// The projected wrinkles.
    pub projected: Vec<ProjectedWrinkle>,
}

/// Ray–triangle intersection (Möller–Trumbore, two-sided, [`softcap_mesh::line_triangle`]):
/// ray parameter of a hit in front of the origin.
fn ray_triangle(o: &Vector3<f64>, d: &Vector3<f64>, tri: [Vector3<f64>; 3]) -> Option<f64> {
    softcap_mesh::line_triangle(o, d, &tri)
        .map(|(t, _)| t)
        .filter(|&t| t > 0.0)
}

/// First surface point hit by the ray through pixel `px`.
pub fn cast_pixel(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    camera: &PinholeCamera,
    px: [f64; 2],
) -> Option<Vector3<f64>> {
    let (o, d) = camera.ray(px);
    triangles
        .iter()
        .filter_map(|t| ray_triangle(&o, &d, t.map(|i| vertices[i])))
        .min_by(|a, b| a.total_cmp(b))
        .map(|t| o + d * t)
}

/// Project an image-space wrinkle onto the deformed surface through the camera (thesis §3.3.1);
/// pixel (d, w) become world lengths with the camera's footprint at the hit point.
/// Cross-sections whose ray misses the surface are dropped.
///
/// Only triangles whose image-space bounding box contains a sample's pixel can be hit by its
/// ray, so the triangles are first binned into 16-pixel cells around the samples (triangles
/// with a vertex behind the camera are always tested): one pass over the mesh per wrinkle
/// instead of one per sample.
pub fn project_wrinkle(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    camera: &PinholeCamera,
    curve: &WrinkleCurve,
) -> ProjectedWrinkle {
    const CELL_PX: f64 = 16.0;
    let cell = |px: [f64; 2]| {
        (
            (px[0] / CELL_PX).floor() as i64,
            (px[1] / CELL_PX).floor() as i64,
        )
    };
    let mut bins: BTreeMap<(i64, i64), Vec<usize>> = BTreeMap::new();
    for s in &curve.samples {
        if s.valley_px.iter().all(|v| v.is_finite()) {
            bins.entry(cell(s.valley_px)).or_default();
        }
    }
    let mut always = Vec::new();
    if let (Some((&(cx0, _), _)), Some((&(cx1, _), _))) =
        (bins.first_key_value(), bins.last_key_value())
    {
        let (cy0, cy1) = bins
            .keys()
            .fold((i64::MAX, i64::MIN), |(a, b), &(_, y)| (a.min(y), b.max(y)));
        let projected: Vec<Option<[f64; 2]>> = vertices.iter().map(|v| camera.project(v)).collect();
        for (ti, t) in triangles.iter().enumerate() {
            let (Some(a), Some(b), Some(c)) = (projected[t[0]], projected[t[1]], projected[t[2]])
            else {
                always.push(ti);
                continue;
            };
            let lo = cell([a[0].min(b[0]).min(c[0]), a[1].min(b[1]).min(c[1])]);
            let hi = cell([a[0].max(b[0]).max(c[0]), a[1].max(b[1]).max(c[1])]);
            for x in lo.0.max(cx0)..=hi.0.min(cx1) {
                for y in lo.1.max(cy0)..=hi.1.min(cy1) {
                    if let Some(list) = bins.get_mut(&(x, y)) {
                        list.push(ti);
                    }
                }
            }
        }
    }
    let mut out = ProjectedWrinkle::default();
    for s in &curve.samples {
        if !s.valley_px.iter().all(|v| v.is_finite()) {
            continue;
        }
        let (o, d) = camera.ray(s.valley_px);
        let candidates = bins
            .get(&cell(s.valley_px))
            .into_iter()
            .flatten()
            .chain(&always);
        let hit = candidates
            .filter_map(|&ti| ray_triangle(&o, &d, triangles[ti].map(|i| vertices[i])))
            .min_by(|a, b| a.total_cmp(b))
            .map(|t| o + d * t);
        if let Some(x) = hit {
            let k = camera.world_per_px(&x);
            out.points.push(x);
            out.depth.push(s.depth_px * k);
            out.width.push(s.width_px * k);
        }
    }
    out
}

/// Closest point of a projected valley polyline to `x`: (distance p, depth d, width w, inside),
/// `inside` false when the foot lies beyond either end of the polyline.
fn closest_on_wrinkle(w: &ProjectedWrinkle, x: &Vector3<f64>) -> Option<(f64, f64, f64, bool)> {
    let n = w.points.len();
    if n < 2 {
        return None;
    }
    let mut best: Option<(f64, f64, f64, bool)> = None;
    for k in 0..n - 1 {
        let (a, b) = (w.points[k], w.points[k + 1]);
        let ab = b - a;
        let l2 = ab.norm_squared();
        if l2 == 0.0 {
            continue;
        }
        let t_raw = (x - a).dot(&ab) / l2;
        let inside = !((k == 0 && t_raw < 0.0) || (k == n - 2 && t_raw > 1.0));
        let t = t_raw.clamp(0.0, 1.0);
        let p = (x - (a + ab * t)).norm();
        let d = w.depth[k] * (1.0 - t) + w.depth[k + 1] * t;
        let wd = w.width[k] * (1.0 - t) + w.width[k + 1] * t;
        if best.is_none_or(|b| p < b.0) {
            best = Some((p, d, wd, inside));
        }
    }
    best
}

/// One-ring adjacency (sorted, deduplicated).
fn one_rings(n: usize, triangles: &[[usize; 3]]) -> Vec<Vec<usize>> {
    let mut r = vec![Vec::new(); n];
    for t in triangles {
        for k in 0..3 {
            r[t[k]].push(t[(k + 1) % 3]);
            r[t[k]].push(t[(k + 2) % 3]);
        }
    }
    for v in &mut r {
        v.sort_unstable();
        v.dedup();
    }
    r
}

/// Area-weighted vertex normals smoothed by `passes` umbrella averages (thesis §3.3.1
/// "smoothed normals").
pub fn smoothed_normals(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    passes: usize,
) -> Vec<Vector3<f64>> {
    let rings = one_rings(vertices.len(), triangles);
    let mut n = vertex_normals(vertices, triangles);
    for _ in 0..passes {
        let next: Vec<Vector3<f64>> = (0..n.len())
            .map(|v| {
                let s = rings[v].iter().fold(n[v], |acc, &j| acc + n[j]);
                let l = s.norm();
                if l > 0.0 { s / l } else { n[v] }
            })
            .collect();
        n = next;
    }
    n
}

/// The discrete shell of thesis eq. 3.6 over a rest mesh: edges with their flaps and the rest
/// quantities ‖ē‖, θ̄, h̄, ‖t̄‖.
#[derive(Clone, Debug)]
pub struct DiscreteShell {
    /// Triangles (shared with the deformed mesh).
    pub triangles: Vec<[usize; 3]>,
    /// Edges (a, b) with a < b.
    pub edges: Vec<[usize; 2]>,
    /// Interior edges as (x0, x1, x2, x3): edge x0→x1 as oriented in the triangle with
    /// opposite vertex x2; x3 is the other opposite vertex.
    pub hinges: Vec<[usize; 4]>,
    rest_len: Vec<f64>,
    rest_theta: Vec<f64>,
    rest_hinge_weight: Vec<f64>,
    rest_area: Vec<f64>,
    k: [f64; 3],
}

/// Sparse symmetric matrix (lower triangle) from triplets (duplicates summed) and, for every
/// triplet, the index of its value in the matrix's column-major value array.
fn assemble_with_slots(
    n: usize,
    trip: &[(usize, usize, f64)],
) -> Result<(SparseColMat<usize, f64>, Vec<usize>)> {
    let mut order: Vec<usize> = (0..trip.len()).collect();
    order.sort_unstable_by_key(|&k| (trip[k].1, trip[k].0));
    let mut slots = vec![0usize; trip.len()];
    let mut merged: Vec<Triplet<usize, usize, f64>> = Vec::with_capacity(trip.len());
    for &k in &order {
        let (r, c, v) = trip[k];
        match merged.last_mut() {
            Some(t) if t.row == r && t.col == c => t.val += v,
            _ => merged.push(Triplet::new(r, c, v)),
        }
        slots[k] = merged.len() - 1;
    }
    // unique (column, row)-sorted triplets: the value array keeps their order
    let mat = SparseColMat::try_new_from_triplets(n, n, &merged).map_err(|e| {
        FaceError::Factorization {
            what: "shell Gauss–Newton normal equations",
            reason: format!("{e:?}"),
        }
    })?;
    Ok((mat, slots))
}

/// Indices of the eq. 3.6 terms that involve a free vertex.
#[derive(Clone, Debug, Default)]
struct ActiveTerms {
    edges: Vec<usize>,
    hinges: Vec<usize>,
    triangles: Vec<usize>,
}

/// Signed dihedral angle of a hinge and its gradient w.r.t. (x0, x1, x2, x3)
/// (Bridson et al. 2003 form).
pub fn dihedral_angle(x: [Vector3<f64>; 4]) -> (f64, [Vector3<f64>; 4]) {
    let [x0, x1, x2, x3] = x;
    let e = x1 - x0;
    let el = e.norm();
    let n1 = e.cross(&(x2 - x0));
    let n2 = (x0 - x1).cross(&(x3 - x1));
    let (m1, m2) = (n1.norm_squared(), n2.norm_squared());
    let (u1, u2) = (n1 / m1.sqrt(), n2 / m2.sqrt());
    let theta = u1.cross(&u2).dot(&(e / el)).atan2(u1.dot(&u2));
    let eh = e / el;
    let g2 = n1 * (el / m1);
    let g3 = n2 * (el / m2);
    let g0 = n1 * ((x2 - x1).dot(&eh) / m1) + n2 * ((x3 - x1).dot(&eh) / m2);
    let g1 = -(n1 * ((x2 - x0).dot(&eh) / m1) + n2 * ((x3 - x0).dot(&eh) / m2));
    (theta, [-g0, -g1, -g2, -g3])
}

fn triangle_area(x: [Vector3<f64>; 3]) -> (f64, [Vector3<f64>; 3]) {
    let n = (x[1] - x[0]).cross(&(x[2] - x[0]));
    let a2 = n.norm();
    let nh = n / a2;
    (
        0.5 * a2,
        [
            0.5 * nh.cross(&(x[2] - x[1])),
            0.5 * nh.cross(&(x[0] - x[2])),
            0.5 * nh.cross(&(x[1] - x[0])),
        ],
    )
}

impl DiscreteShell {
    /// Rest quantities of `rest` with stiffnesses from `settings`.
    pub fn new(rest: &TriMesh, settings: &SynthesisSettings) -> Result<Self> {
        let mut flaps: BTreeMap<(usize, usize), Vec<(usize, usize, usize)>> = BTreeMap::new();
        for t in &rest.triangles {
            for k in 0..3 {
                let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
                flaps
                    .entry((a.min(b), a.max(b)))
                    .or_default()
                    .push((a, b, c));
            }
        }
        let mut edges = Vec::with_capacity(flaps.len());
        let mut hinges = Vec::new();
        for (&(a, b), f) in &flaps {
            edges.push([a, b]);
            if let [(a0, b0, c0), (_, _, c1)] = f.as_slice() {
                hinges.push([*a0, *b0, *c0, *c1]);
            }
        }
        let x = &rest.vertices;
        let rest_len: Vec<f64> = edges.iter().map(|e| (x[e[1]] - x[e[0]]).norm()).collect();
        let rest_area: Vec<f64> = rest
            .triangles
            .iter()
            .map(|t| triangle_area(t.map(|i| x[i])).0)
            .collect();
        if let Some(k) = rest_area.iter().position(|&a| a.is_nan() || a <= 0.0) {
            return Err(FaceError::InvalidInput {
                what: "rest mesh",
                reason: format!("triangle {k} is degenerate"),
            });
        }
        let mut rest_theta = Vec::with_capacity(hinges.len());
        let mut rest_hinge_weight = Vec::with_capacity(hinges.len());
        for h in &hinges {
            let p = h.map(|i| x[i]);
            rest_theta.push(dihedral_angle(p).0);
            let el = (p[1] - p[0]).norm();
            let a1 = triangle_area([p[0], p[1], p[2]]).0;
            let a2 = triangle_area([p[1], p[0], p[3]]).0;
            // h̄ = ⅓ of the mean height of the two flaps (Grinspun et al. 2003)
            let h_bar = (a1 + a2) / (3.0 * el);
            rest_hinge_weight.push(el / h_bar);
        }
        Ok(Self {
            triangles: rest.triangles.clone(),
            edges,
            hinges,
            rest_len,
            rest_theta,
            rest_hinge_weight,
            rest_area,
            k: [settings.k_e, settings.k_b, settings.k_a],
        })
    }

    /// Shell energy (thesis eq. 3.6) of positions `x`, restricted to the terms for which
    /// `active` is true of some involved vertex (all terms when `active` is `None`).
    pub fn energy(&self, x: &[Vector3<f64>], active: Option<&[bool]>) -> f64 {
        let terms = self.active_terms(active);
        self.terms_energy(x, &terms)
    }

    fn terms_energy(&self, x: &[Vector3<f64>], terms: &ActiveTerms) -> f64 {
        let mut e = 0.0;
        self.for_each_residual(x, terms, false, |r, _| e += r * r);
        e
    }

    /// The edges, hinges and triangles of eq. 3.6 with at least one vertex flagged in `active`
    /// (all of them for `None`), so a region's iterations touch only its own terms.
    fn active_terms(&self, active: Option<&[bool]>) -> ActiveTerms {
        let on = |vs: &[usize]| active.is_none_or(|a| vs.iter().any(|&v| a[v]));
        ActiveTerms {
            edges: (0..self.edges.len())
                .filter(|&i| on(&self.edges[i]))
                .collect(),
            hinges: (0..self.hinges.len())
                .filter(|&i| on(&self.hinges[i]))
                .collect(),
            triangles: (0..self.triangles.len())
                .filter(|&i| on(&self.triangles[i]))
                .collect(),
        }
    }

    /// Visit every residual r (E = Σ r²) of `terms` with its gradient entries (vertex, ∂r/∂x_v).
    fn for_each_residual(
        &self,
        x: &[Vector3<f64>],
        terms: &ActiveTerms,
        with_grad: bool,
        mut f: impl FnMut(f64, &[(usize, Vector3<f64>)]),
    ) {
        let [k_e, k_b, k_a] = self.k;
        let mut g: Vec<(usize, Vector3<f64>)> = Vec::with_capacity(4);
        for &i in &terms.edges {
            let e = &self.edges[i];
            let d = x[e[1]] - x[e[0]];
            let l = d.norm();
            let s = (k_e / self.rest_len[i]).sqrt();
            g.clear();
            if with_grad {
                let u = d / l * s;
                g.push((e[0], -u));
                g.push((e[1], u));
            }
            f(s * (l - self.rest_len[i]), &g);
        }
        for &i in &terms.hinges {
            let h = &self.hinges[i];
            let (theta, grad) = dihedral_angle(h.map(|v| x[v]));
            let s = (k_b * self.rest_hinge_weight[i]).sqrt();
            g.clear();
            if with_grad {
                for k in 0..4 {
                    g.push((h[k], grad[k] * s));
                }
            }
            f(s * (theta - self.rest_theta[i]), &g);
        }
        for &i in &terms.triangles {
            let t = &self.triangles[i];
            let (a, grad) = triangle_area(t.map(|v| x[v]));
            let s = (k_a / self.rest_area[i]).sqrt();
            g.clear();
            if with_grad {
                for k in 0..3 {
                    g.push((t[k], grad[k] * s));
                }
            }
            f(s * (a - self.rest_area[i]), &g);
        }
    }

    /// Minimise the shell energy over the vertices flagged `free` (others fixed) by
    /// Gauss–Newton: (JᵀJ + μI) δ = −Jᵀr with sparse Cholesky, then a backtracking line search.
    pub fn minimize(
        &self,
        x: &mut [Vector3<f64>],
        free: &[bool],
        settings: &SynthesisSettings,
    ) -> Result<(f64, f64, usize, bool)> {
        let free_index: Vec<usize> = {
            let mut c = 0;
            free.iter()
                .map(|&f| {
                    if f {
                        c += 1;
                        c - 1
                    } else {
                        usize::MAX
                    }
                })
                .collect()
        };
        let nf = free.iter().filter(|&&f| f).count();
        let terms = self.active_terms(Some(free));
        let e0 = self.terms_energy(x, &terms);
        if nf == 0 {
            return Ok((e0, e0, 0, true));
        }
        let mut e = e0;
        let mut iterations = 0;
        let mut converged = false;
        let mut symbolic: Option<SymbolicLlt<usize>> = None;
        let mut pattern: Option<(SparseColMat<usize, f64>, Vec<usize>)> = None;
        while iterations < settings.max_iterations {
            iterations += 1;
            let mut trip: Vec<(usize, usize, f64)> = Vec::new();
            let mut grad = vec![0.0; 3 * nf];
            let mut diag_max: f64 = 0.0;
            self.for_each_residual(x, &terms, true, |r, g| {
                for &(vi, gi) in g {
                    let fi = free_index[vi];
                    if fi == usize::MAX {
                        continue;
                    }
                    for a in 0..3 {
                        grad[3 * fi + a] += r * gi[a];
                    }
                    for &(vj, gj) in g {
                        let fj = free_index[vj];
                        if fj == usize::MAX || fj > fi {
                            continue;
                        }
                        for a in 0..3 {
                            for b in 0..3 {
                                let (row, col) = (3 * fi + a, 3 * fj + b);
                                if row >= col {
                                    trip.push((row, col, gi[a] * gj[b]));
                                }
                            }
                        }
                    }
                }
            });
            for &(r, c, v) in &trip {
                if r == c {
                    diag_max = diag_max.max(v);
                }
            }
            let mu = 1e-10 * diag_max.max(1e-300);
            for i in 0..3 * nf {
                trip.push((i, i, mu));
            }
            // JᵀJ keeps its sparsity pattern (and the order of its triplets) across iterations:
            // sort and merge once per region, then scatter the values into the stored slots
            if pattern
                .as_ref()
                .is_none_or(|(_, slots)| slots.len() != trip.len())
            {
                pattern = Some(assemble_with_slots(3 * nf, &trip)?);
            }
            let Some((h, slots)) = pattern.as_mut() else {
                unreachable!("pattern assembled above")
            };
            {
                let vals = h.val_mut();
                vals.fill(0.0);
                for (&slot, &(_, _, v)) in slots.iter().zip(&trip) {
                    vals[slot] += v;
                }
            }
            let factor_err = |err: String| FaceError::Factorization {
                what: "shell Gauss–Newton normal equations",
                reason: err,
            };
            // JᵀJ keeps its sparsity pattern across iterations: one symbolic analysis per region
            let sym = match &symbolic {
                Some(sym) => SymbolicLlt::clone(sym),
                None => {
                    let sym = SymbolicLlt::try_new(h.symbolic(), Side::Lower)
                        .map_err(|e| factor_err(format!("{e:?}")))?;
                    symbolic = Some(sym.clone());
                    sym
                }
            };
            let llt = Llt::try_new_with_symbolic(sym, h.as_ref(), Side::Lower)
                .map_err(|e| factor_err(format!("{e:?}")))?;
            let mut rhs = Mat::<f64>::from_fn(3 * nf, 1, |i, _| -grad[i]);
            llt.solve_in_place(rhs.as_mut());
            let x_old: Vec<Vector3<f64>> = x.to_vec();
            let mut alpha = 1.0;
            let mut e_new = f64::INFINITY;
            for _ in 0..30 {
                for (v, xv) in x.iter_mut().enumerate() {
                    let fi = free_index[v];
                    if fi != usize::MAX {
                        *xv = x_old[v]
                            + Vector3::new(
                                rhs[(3 * fi, 0)],
                                rhs[(3 * fi + 1, 0)],
                                rhs[(3 * fi + 2, 0)],
                            ) * alpha;
                    }
                }
                e_new = self.terms_energy(x, &terms);
                if e_new.is_finite() && e_new <= e {
                    break;
                }
                alpha *= 0.5;
            }
            if !(e_new.is_finite() && e_new <= e) {
                x.copy_from_slice(&x_old);
                converged = true; // no descent possible along the GN direction: stationary
                break;
            }
            let decrease = e - e_new;
            e = e_new;
            if decrease <= settings.relative_tolerance * e.max(1e-300) {
                converged = true;
                break;
            }
        }
        Ok((e0, e, iterations, converged))
    }
}

/// The camera and the wrinkle samples come from the user's `--wrinkles` file: a non-finite or
/// non-positive focal length, a non-finite pose or sample, a non-positive width or a negative
/// depth is bad input.
pub fn validate_wrinkles(camera: &PinholeCamera, wrinkles: &[WrinkleCurve]) -> Result<()> {
    let iso = &camera.world_from_camera;
    let pose_ok = iso.translation.vector.iter().all(|v| v.is_finite())
        && iso.rotation.coords.iter().all(|v| v.is_finite());
    if !(camera.focal_px > 0.0
        && camera.focal_px.is_finite()
        && camera.principal_px.iter().all(|v| v.is_finite())
        && pose_ok)
    {
        return Err(FaceError::InvalidInput {
            what: "camera",
            reason: format!(
                "focal {} px, principal point {:?}, pose finite: {pose_ok}",
                camera.focal_px, camera.principal_px
            ),
        });
    }
    for (k, w) in wrinkles.iter().enumerate() {
        for (j, s) in w.samples.iter().enumerate() {
            if !(s.valley_px.iter().all(|v| v.is_finite())
                && s.width_px > 0.0
                && s.width_px.is_finite()
                && s.depth_px >= 0.0
                && s.depth_px.is_finite())
            {
                return Err(FaceError::InvalidInput {
                    what: "wrinkle sample",
                    reason: format!(
                        "wrinkle {k} sample {j}: valley {:?} px, d {} px, w {} px (need finite, w > 0, d ≥ 0)",
                        s.valley_px, s.depth_px, s.width_px
                    ),
                });
            }
        }
    }
    Ok(())
}

/// Wrinkle synthesis (thesis §3.3.1) on the deformed face `deformed` (same topology as `rest`):
/// project each wrinkle through `camera`, offset valley vertices (p ≤ w) along smoothed normals by
/// S(w, d, p), segment the influence regions (p ≤ `influence_widths`·w, merged when they touch),
/// and minimise eq. 3.6 on each region with every other vertex fixed.
pub fn synthesize_wrinkles(
    rest: &TriMesh,
    deformed: &[Vector3<f64>],
    camera: &PinholeCamera,
    wrinkles: &[WrinkleCurve],
    settings: &SynthesisSettings,
) -> Result<SynthesisResult> {
    let n = rest.vertices.len();
    if deformed.len() != n {
        return Err(FaceError::InvalidInput {
            what: "deformed vertices",
            reason: format!("{} positions for a {n}-vertex rest mesh", deformed.len()),
        });
    }
    validate_wrinkles(camera, wrinkles)?;
    if let Some(t) = rest
        .triangles
        .iter()
        .position(|t| t.iter().any(|&v| v >= n))
    {
        return Err(FaceError::InvalidInput {
            what: "rest mesh",
            reason: format!("triangle {t} references a vertex ≥ {n}"),
        });
    }
    let projected: Vec<ProjectedWrinkle> = wrinkles
        .iter()
        .map(|c| project_wrinkle(deformed, &rest.triangles, camera, c))
        .collect();
    let normals = smoothed_normals(deformed, &rest.triangles, settings.normal_smoothing_passes);
    let mut x = deformed.to_vec();
    let mut valley = vec![false; n];
    let mut region = vec![false; n];
    let mut offset = vec![0.0; n];
    for (v, xv) in deformed.iter().enumerate() {
        for w in &projected {
            if let Some((p, d, wd, inside)) = closest_on_wrinkle(w, xv) {
                if !inside || wd <= 0.0 {
                    continue;
                }
                if p <= settings.influence_widths * wd {
                    region[v] = true;
                }
                if p <= wd {
                    let s = wrinkle_profile(wd, d, p);
                    // overlapping valleys: keep the deeper offset
                    if !valley[v] || s < offset[v] {
                        offset[v] = s;
                    }
                    valley[v] = true;
                }
            }
        }
    }
    for v in 0..n {
        if valley[v] {
            x[v] = deformed[v] + normals[v] * offset[v];
        }
    }
    // Automatic segmentation: connected components of the influence region.
    let rings = one_rings(n, &rest.triangles);
    let mut comp = vec![usize::MAX; n];
    let mut comps: Vec<Vec<usize>> = Vec::new();
    for s in 0..n {
        if !region[s] || comp[s] != usize::MAX {
            continue;
        }
        let id = comps.len();
        let mut stack = vec![s];
        comp[s] = id;
        let mut members = Vec::new();
        while let Some(v) = stack.pop() {
            members.push(v);
            for &j in &rings[v] {
                if region[j] && comp[j] == usize::MAX {
                    comp[j] = id;
                    stack.push(j);
                }
            }
        }
        members.sort_unstable();
        comps.push(members);
    }
    let shell = DiscreteShell::new(rest, settings)?;
    let mut reports = Vec::with_capacity(comps.len());
    let mut free = vec![false; n];
    for members in &comps {
        for &v in members {
            free[v] = !valley[v];
        }
        let (e0, e1, iterations, converged) = shell.minimize(&mut x, &free, settings)?;
        reports.push(RegionReport {
            free_vertices: members.iter().filter(|&&v| free[v]).count(),
            valley_vertices: members.iter().filter(|&&v| valley[v]).count(),
            initial_energy: e0,
            final_energy: e1,
            iterations,
            converged,
        });
        for &v in members {
            free[v] = false;
        }
    }
    Ok(SynthesisResult {
        vertices: x,
        valley_offset: offset,
        regions: reports,
        projected,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dihedral_gradient_matches_central_differences() {
        let x = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.1, 0.05),
            Vector3::new(0.4, 0.9, 0.2),
            Vector3::new(0.6, -0.8, 0.35),
        ];
        let (_, g) = dihedral_angle(x);
        let h = 1e-6;
        for k in 0..4 {
            for a in 0..3 {
                let (mut p, mut m) = (x, x);
                p[k][a] += h;
                m[k][a] -= h;
                let fd = (dihedral_angle(p).0 - dihedral_angle(m).0) / (2.0 * h);
                assert!(
                    (fd - g[k][a]).abs() < 1e-7,
                    "vertex {k} axis {a}: {fd} vs {}",
                    g[k][a]
                );
            }
        }
        // a flat hinge has θ = 0; folding x3 up by +z on a +z-normal sheet gives θ of known sign
        let flat = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.5, 1.0, 0.0),
            Vector3::new(0.5, -1.0, 0.0),
        ];
        assert!(dihedral_angle(flat).0.abs() < 1e-15);
    }

    #[test]
    fn area_gradient_matches_central_differences() {
        let x = [
            Vector3::new(0.1, 0.0, 0.3),
            Vector3::new(1.0, 0.2, -0.1),
            Vector3::new(0.3, 0.8, 0.4),
        ];
        let (_, g) = triangle_area(x);
        let h = 1e-6;
        for k in 0..3 {
            for a in 0..3 {
                let (mut p, mut m) = (x, x);
                p[k][a] += h;
                m[k][a] -= h;
                let fd = (triangle_area(p).0 - triangle_area(m).0) / (2.0 * h);
                assert!((fd - g[k][a]).abs() < 1e-8);
            }
        }
    }

    #[test]
    fn camera_ray_and_projection_are_inverse() {
        let cam = PinholeCamera {
            world_from_camera: Isometry3::new(
                Vector3::new(0.3, -0.2, 8.0),
                Vector3::new(2.9, 0.2, 0.1),
            ),
            focal_px: 900.0,
            principal_px: [320.0, 240.0],
        };
        let (o, d) = cam.ray([100.0, 400.0]);
        let back = cam.project(&(o + d * 5.0)).unwrap();
        assert!((back[0] - 100.0).abs() < 1e-9 && (back[1] - 400.0).abs() < 1e-9);
    }
}
