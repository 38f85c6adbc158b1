//! Footprint loads: the measured probe force spread over the contact patch as nodal forces
//! (bickel2009 §4.1 force boundary condition, Fig. 7 "distribute it uniformly"), lumped on the
//! patch nodes or as the consistent loads of a uniform, flat-punch (Sneddon) or Hertz pressure.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::{ProbeExample, ProbingSetup};

/// How the measured probe force is spread over the footprint (bickel2009 §4.1, Fig. 7:
/// "distribute it uniformly" over the contact area).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FootprintLoad {
    /// On the boundary nodes inside the footprint ([`ProbingSetup::patch_nodes`]), in
    /// proportion to their lumped boundary areas.
    #[default]
    Lumped,
    /// The consistent nodal loads of a uniform pressure over the footprint disk
    /// ([`ProbingSetup::load_weights`]): centred on the probe axis whatever the mesh.
    Consistent,
    /// The consistent nodal loads of the contact pressure of a rigid flat punch of radius a
    /// (a disk tip) on an elastic half-space, p(r) = F / (2πa·√(a² − r²)) (Boussinesq; Sneddon
    /// 1946; Johnson, *Contact Mechanics* 1985, ch. 3, axisymmetric pressures): rim-concentrated,
    /// the pressure under which the surface displacement is uniform over the footprint — the
    /// flat dent a rigid disk makes. Sampled with rings of equal load
    /// ([`Self::load_fraction_inside`]).
    FlatPunch,
    /// The consistent nodal loads of the Hertz pressure of a rigid sphere with contact radius a,
    /// p(r) = 3F / (2πa²) · √(1 − r²/a²) (Hertz 1882; Johnson, *Contact Mechanics* 1985, §4.2):
    /// centre-concentrated, vanishing at the rim — the sphere tip's
    /// analogue of [`Self::FlatPunch`].
    Hertz,
}

impl FootprintLoad {
    /// Every load, in declaration order.
    pub const ALL: [Self; 4] = [Self::Lumped, Self::Consistent, Self::FlatPunch, Self::Hertz];

    /// The name of the load in settings files (serde's kebab-case name) and reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Lumped => "lumped",
            Self::Consistent => "consistent",
            Self::FlatPunch => "flat-punch",
            Self::Hertz => "hertz",
        }
    }

    /// The load named `name` ([`Self::name`]), `None` for an unknown name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|l| l.name() == name)
    }

    /// Share of the probe force inside radius ρ·a of the footprint centre, ρ ∈ [0, 1], for the
    /// pressure distributions over a disk (`Lumped` counts as uniform pressure):
    /// uniform ρ²; flat punch 1 − √(1 − ρ²); Hertz 1 − (1 − ρ²)^{3/2} (the integrals
    /// ∫₀^{ρa} p(r) 2πr dr / F of the pressures of [`Self::Consistent`], [`Self::FlatPunch`],
    /// [`Self::Hertz`]).
    pub fn load_fraction_inside(self, rho: f64) -> f64 {
        let rho2 = rho.clamp(0.0, 1.0).powi(2);
        match self {
            Self::Lumped | Self::Consistent => rho2,
            Self::FlatPunch => 1.0 - (1.0 - rho2).sqrt(),
            Self::Hertz => 1.0 - (1.0 - rho2).powf(1.5),
        }
    }

    /// The radius fraction ρ ∈ [0, 1] inside which the share `u` ∈ [0, 1] of the force lies:
    /// the inverse of [`Self::load_fraction_inside`] — uniform √u; flat punch √(u(2 − u));
    /// Hertz √(1 − (1 − u)^{2/3}). Ring k of R sits at ρ(u = (k + ½)/R), the midpoint in load
    /// of its share 1/R, so every sample carries the same load.
    pub fn ring_radius_fraction(self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        match self {
            Self::Lumped | Self::Consistent => u.sqrt(),
            Self::FlatPunch => (u * (2.0 - u)).sqrt(),
            Self::Hertz => (1.0 - (1.0 - u).powf(2.0 / 3.0)).max(0.0).sqrt(),
        }
    }
}

/// Settings of the contact patch of a force boundary condition.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PatchSettings {
    /// Radius of the probe footprint, m (disk radius, or the contact radius of a sphere).
    pub radius_m: f64,
    /// Boundary nodes up to this far (along the axis) behind the first surface met by the probe
    /// belong to the patch, as a fraction of `radius_m` ([`FootprintLoad::Lumped`]).
    pub depth_window: f64,
    /// The load distribution.
    pub load: FootprintLoad,
    /// Rings of equal load the footprint disk is sampled with (every load but
    /// [`FootprintLoad::Lumped`]; of equal area under the uniform pressure of
    /// [`FootprintLoad::Consistent`]).
    pub rings: usize,
    /// Samples per ring (equally spaced in angle, every other ring turned by half a step).
    pub samples_per_ring: usize,
    /// [`FootprintLoad::FlatPunch`] with the disk tilted against the surface beyond full
    /// contact: square cells across the footprint's diameter of the half-space contact solve
    /// ([`ProbingSetup::load_weights`], "a tilted disk").
    pub tilt_cells: usize,
}

impl Default for PatchSettings {
    fn default() -> Self {
        Self {
            radius_m: 0.005,
            depth_window: 0.5,
            load: FootprintLoad::Lumped,
            // 192 samples: the load's first moment is exact for any count (symmetric rings);
            // 8 × 24 resolves the footprint's partition among triangles of a mesh whose surface
            // spacing is about the tip radius to ≈ 1/192 of the force.
            rings: 8,
            samples_per_ring: 24,
            // 16 across: ≈ 200 cells of a/8 (0.6 mm for a 5 mm disk), several per surface
            // triangle of a mesh whose spacing is about the tip radius; the contact solve of
            // ≈ 200 unknowns takes well under a millisecond.
            tilt_cells: 16,
        }
    }
}

impl ProbingSetup {
    /// The probed region of an example (bickel2009 §4.1 region (i)): boundary nodes whose rest
    /// position lies within `radius_m` of the probe axis line and at most
    /// `depth_window · radius_m` behind the first boundary node the probe meets. When no node
    /// lies inside the footprint (coarse mesh) the boundary node closest to the axis is used.
    pub fn patch_nodes(&self, example: &ProbeExample, patch: &PatchSettings) -> Vec<usize> {
        let axis = example.axis.normalize();
        let coords: Vec<(usize, f64, f64)> = self
            .boundary_nodes
            .iter()
            .filter(|n| self.attached_nodes.binary_search(n).is_err())
            .map(|&n| {
                let d = self.mesh.vertices[n] - example.tip_m;
                let along = d.dot(&axis);
                (n, along, (d - axis * along).norm())
            })
            .collect();
        let inside: Vec<&(usize, f64, f64)> =
            coords.iter().filter(|c| c.2 <= patch.radius_m).collect();
        if inside.is_empty() {
            return coords
                .iter()
                .min_by(|a, b| a.2.total_cmp(&b.2).then(a.0.cmp(&b.0)))
                .map(|c| vec![c.0])
                .unwrap_or_default();
        }
        let first = inside.iter().map(|c| c.1).fold(f64::INFINITY, f64::min);
        let window = patch.depth_window * patch.radius_m;
        inside
            .iter()
            .filter(|c| c.1 <= first + window)
            .map(|c| c.0)
            .collect()
    }

    /// The share of the probe force each surface node carries (node, weight; increasing
    /// nodes, weights sum to 1) under `patch.load`: [`FootprintLoad::Lumped`] — the patch
    /// nodes ([`Self::patch_nodes`]) in proportion to their lumped boundary areas (uniform
    /// pressure, bickel2009 §4.1 / Fig. 7); [`FootprintLoad::Consistent`],
    /// [`FootprintLoad::FlatPunch`], [`FootprintLoad::Hertz`] — below.
    ///
    /// Consistent: the nodal loads of a uniform pressure over the probe's footprint disk, the
    /// probed region of bickel2009 §4.1 (Fig. 7: the measured force "distributed uniformly"
    /// over the contact area). FlatPunch / Hertz: the same with the rigid flat punch's
    /// (Sneddon) or the rigid sphere's (Hertz) axisymmetric pressure in place of the uniform
    /// one; only the ring radii differ.
    ///
    /// For a pressure p over the footprint D on the surface S the consistent load of node i is
    /// f_i = ∫_D N_i p dA (N_i the linear surface shape functions), so Σ_i f_i = F and
    /// Σ_i f_i x_i = ∫_D x p dA: the load has the tip's resultant AND its first moment, centred
    /// on the probe axis whatever the mesh. The lumped load puts it on the 1–3 nodes that fall
    /// inside the footprint of a mesh whose spacing is about the tip radius, off the axis by up
    /// to half a spacing — a dent of the wrong shape in the wrong place, which the material fit
    /// then compensates; against a rigid-tip truth (the e2e suite) it is most of the elastic
    /// default model's error near the probe (docs/diagnose.md, "footprint loads").
    ///
    /// Quadrature: `rings` × `samples_per_ring` points of equal load on the disk of radius
    /// `radius_m` around the tip in the plane normal to the axis: ring k of R at radius
    /// a·ρ((k + ½)/R), ρ the inverse cumulative load of the pressure
    /// ([`FootprintLoad::ring_radius_fraction`]; a·√((k + ½)/R), equal area, for the uniform
    /// pressure). Each is cast along the probe axis onto the outward-facing
    /// (n·axis < 0) load triangle whose hit lies nearest the tip (the surface the tip presses,
    /// also on a curved or folded surface), and its share 1/(R·S) goes to that triangle's three
    /// vertices by the hit's barycentric weights. Samples that miss the surface (a footprint
    /// over the object's edge) carry nothing and the rest is rescaled to the whole force (the
    /// measured force is carried by the part in contact). When every sample misses, the force
    /// goes to the closest surface point to the tip. Shares on attached vertices are taken up
    /// by the support.
    ///
    /// **A tilted disk** ([`FootprintLoad::FlatPunch`] only: the disk tip's load). The face of
    /// a flat disk whose axis is tilted against the surface normal does not press evenly: its
    /// low side goes deeper, and when the tilt is large against the depth only the low side
    /// touches. The samples' signed distances t along the axis to the rest surface give the
    /// face's penetration δ = −t, fitted as a plane over the disk, δ(x) = δ₀ + g·x (x in the
    /// disk's plane from its centre; [`FaceTilt`]). When g = 0 (an axis along the surface
    /// normal of a flat face, to 10⁻⁹ rad) nothing changes: the rings above, weights for
    /// weights. Otherwise, on an elastic half-space (E* = E/(1 − ν²)):
    ///
    /// - full contact, δ₀ ≥ 2|g|a: a rigid circular punch pressed δ₀ and turned by the slope g
    ///   has the pressure p(x) = E*(δ₀ + 2g·x) / (π√(a² − r²)) (Johnson, *Contact Mechanics*
    ///   1985, ch. 3 axisymmetric pressures and §5 the flat punch: the rim-singular pressure of
    ///   Sneddon's translation plus that of a rotation, whose moment is the rigid footing's
    ///   (4/3)E*a³|g|), non-negative at the high rim while δ₀ ≥ 2|g|a. Its resultant is Sneddon's
    ///   2E*aδ₀ and its centre lies (2/3)|g|a²/δ₀ from the axis toward the low side (at most
    ///   a/3): each equal-load ring sample is scaled by 1 + 2g·x/δ₀.
    /// - incomplete contact, δ₀ < 2|g|a (the high rim would pull): the contact region and
    ///   pressure of the rigid tilted face are solved on the half-space by influence
    ///   coefficients (Johnson 1985, ch. 5, non-Hertzian normal contact solved numerically on a
    ///   grid of uniformly loaded cells; Boussinesq's point load, ch. 3, between cells): square
    ///   cells of side 2a/[`PatchSettings::tilt_cells`] on the disk, cast along the axis onto the
    ///   rest surface, their loads P ≥ 0 such that the surface sinks exactly by the face's
    ///   penetration where P > 0 and at least by it elsewhere (a linear complementarity problem
    ///   solved by active sets). Each cell's share goes to its
    ///   triangle's vertices by the barycentric weights of its hit. At small depth the load sits
    ///   on the low rim; it spreads across the disk as the depth grows.
    ///
    /// Approximated: the body is an elastic half-space under the footprint (a block a few radii
    /// deep is stiffer; the pressure's shape, not its magnitude, is used); the face's
    /// penetration is measured from the rest surface (the tip pose of the example, the mesh at
    /// rest); the surface under the disk is the disk itself cast along the axis (an ellipse
    /// 1/cos θ longer across the tilt on a flat surface: 6 % at 20°) and, for the full-contact
    /// factors, flat (the fitted plane); the contact is frictionless (normal pressure only; the
    /// measured force vector, whatever its direction, is spread by these shares).
    pub fn load_weights(&self, example: &ProbeExample, patch: &PatchSettings) -> Vec<(usize, f64)> {
        if patch.load == FootprintLoad::Lumped {
            let mut nodes = self.patch_nodes(example, patch);
            nodes.sort_unstable();
            let total: f64 = nodes.iter().map(|&n| self.node_areas_m2[n]).sum();
            let count = nodes.len() as f64;
            return nodes
                .into_iter()
                .map(|n| {
                    let w = if total > 0.0 {
                        self.node_areas_m2[n] / total
                    } else {
                        1.0 / count
                    };
                    (n, w)
                })
                .collect();
        }
        let axis = example.axis.try_normalize(1e-12).unwrap_or(-Vector3::z());
        let radius = patch.radius_m.max(0.0);
        let v = &self.mesh.vertices;
        // Front-facing load triangles that can meet a line parallel to the axis within the
        // footprint: lateral distance of the centroid ≤ radius + the triangle's extent.
        let lateral = |x: &Vector3<f64>| {
            let d = x - example.tip_m;
            d - axis * d.dot(&axis)
        };
        let candidates: Vec<[usize; 3]> = self
            .load_faces
            .iter()
            .filter(|f| {
                let [a, b, c] = f.map(|i| v[i]);
                if (b - a).cross(&(c - a)).dot(&axis) >= 0.0 {
                    return false;
                }
                let g = (a + b + c) / 3.0;
                let extent = [a, b, c].iter().map(|x| (x - g).norm()).fold(0.0, f64::max);
                lateral(&g).norm() <= radius + extent
            })
            .copied()
            .collect();
        let (e1, e2) = {
            let t = if axis.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let e1 = (t - axis * t.dot(&axis)).normalize();
            (e1, axis.cross(&e1))
        };
        let cast = |origin: &Vector3<f64>| {
            candidates
                .iter()
                .filter_map(|f| {
                    softcap_mesh::line_triangle(origin, &axis, &f.map(|i| v[i])).map(|(t, w)| {
                        // Clamp the edge tolerance away; keep Σw = 1.
                        let w = w.map(|c| c.clamp(0.0, 1.0));
                        let sum: f64 = w.iter().sum();
                        (t, w.map(|c| c / sum), f)
                    })
                })
                .min_by(|a, b| a.0.abs().total_cmp(&b.0.abs()))
        };
        let rings = patch.rings.max(1);
        let per_ring = patch.samples_per_ring.max(1);
        // Every hit: its position (u, v) in the disk's plane, the signed distance t along the
        // axis from the disk point to the rest surface (t < 0: the point is below it), its
        // barycentric weights and triangle.
        let mut hits: Vec<([f64; 2], f64, [f64; 3], &[usize; 3])> = Vec::new();
        for k in 0..rings {
            let r = radius
                * patch
                    .load
                    .ring_radius_fraction((k as f64 + 0.5) / rings as f64);
            let turn = if k % 2 == 1 { 0.5 } else { 0.0 };
            for j in 0..per_ring {
                let phi = std::f64::consts::TAU * (j as f64 + turn) / per_ring as f64;
                let (u, w2) = (r * phi.cos(), r * phi.sin());
                let origin = example.tip_m + e1 * u + e2 * w2;
                if let Some((t, w, f)) = cast(&origin) {
                    hits.push(([u, w2], t, w, f));
                }
            }
        }
        if hits.is_empty() {
            let closest = self
                .load_faces
                .iter()
                .map(|f| {
                    let x = f.map(|i| v[i]);
                    let w = softcap_mesh::closest_point_on_triangle(
                        &example.tip_m,
                        &x[0],
                        &x[1],
                        &x[2],
                    );
                    let q = x[0] * w[0] + x[1] * w[1] + x[2] * w[2];
                    ((q - example.tip_m).norm(), f, w)
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            return match closest {
                Some((_, f, w)) => {
                    let mut m = std::collections::BTreeMap::new();
                    for (n, wn) in f.iter().zip(w) {
                        *m.entry(*n).or_insert(0.0) += wn;
                    }
                    m.into_iter().filter(|e| e.1 != 0.0).collect()
                }
                None => Vec::new(),
            };
        }
        // A flat disk tilted against the surface under it presses with its low side.
        let mut factors = vec![1.0; hits.len()];
        if patch.load == FootprintLoad::FlatPunch
            && let Some(tilt) = FaceTilt::fit(&hits, radius)
        {
            if tilt.full_contact(radius) {
                for (f, h) in factors.iter_mut().zip(&hits) {
                    *f = tilt.full_contact_factor(h.0);
                }
            } else {
                let cells = tilted_punch_cells(
                    patch.tilt_cells,
                    radius,
                    &|u: f64, w2: f64| cast(&(example.tip_m + e1 * u + e2 * w2)),
                    &axis,
                    &|f: &[usize; 3]| {
                        let [a, b, c] = f.map(|i| v[i]);
                        (b - a).cross(&(c - a)).normalize()
                    },
                    &|f: &[usize; 3], w: &[f64; 3]| {
                        v[f[0]] * w[0] + v[f[1]] * w[1] + v[f[2]] * w[2]
                    },
                );
                if let Some(weights) = incomplete_contact_weights(&cells) {
                    return weights;
                }
            }
        }
        let mut acc: std::collections::BTreeMap<usize, f64> = std::collections::BTreeMap::new();
        for ((_, _, w, f), factor) in hits.iter().zip(&factors) {
            for (n, wn) in f.iter().zip(w) {
                *acc.entry(*n).or_insert(0.0) += wn * factor;
            }
        }
        let scale = 1.0 / factors.iter().sum::<f64>();
        acc.into_iter()
            .filter(|e| e.1 != 0.0)
            .map(|(n, w)| (n, w * scale))
            .collect()
    }

    /// Nodal forces of an example: the measured force spread over the footprint by
    /// [`Self::load_weights`] (bickel2009 §4.1 / Fig. 7).
    pub fn nodal_forces(&self, example: &ProbeExample, patch: &PatchSettings) -> Vec<Vector3<f64>> {
        let mut f = vec![Vector3::zeros(); self.mesh.vertices.len()];
        for (n, w) in self.load_weights(example, patch) {
            f[n] += example.force_n * w;
        }
        f
    }
}

/// The penetration of a flat disk's face into the rest surface fitted as a plane over the disk,
/// δ(x) = δ₀ + g·x (x = (u, v) in the disk's plane from its centre; δ = −t, t the signed
/// distance along the axis from a face point to the surface: positive below it), least squares
/// over the footprint's samples ([`ProbingSetup::load_weights`], "a tilted disk").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceTilt {
    /// δ₀, m: the penetration at the disk's centre (negative: above the surface).
    pub depth_m: f64,
    /// g: the penetration's slope across the disk (tan of the tilt), pointing to the low side.
    pub slope: [f64; 2],
}

impl FaceTilt {
    /// The fitted plane of the samples `hits` (position in the disk plane, signed distance t
    /// along the axis, …); `None` when the face is parallel to the surface (|g| ≤ 10⁻⁹: an
    /// axis along the normal of a flat face, to rounding) or fewer than three samples fix the
    /// plane.
    fn fit<T, F>(hits: &[([f64; 2], f64, T, F)], radius_m: f64) -> Option<Self> {
        if hits.len() < 3 || radius_m <= 0.0 {
            return None;
        }
        // Normal equations of δ ≈ c₀ + c₁ u + c₂ v, with u, v in units of the radius.
        let mut m = nalgebra::Matrix3::<f64>::zeros();
        let mut r = Vector3::<f64>::zeros();
        for (x, t, _, _) in hits {
            let row = Vector3::new(1.0, x[0] / radius_m, x[1] / radius_m);
            m += row * row.transpose();
            r += row * -t;
        }
        let c = m.lu().solve(&r)?;
        let slope = [c.y / radius_m, c.z / radius_m];
        if slope[0].hypot(slope[1]) <= 1e-9 {
            return None;
        }
        Some(Self {
            depth_m: c.x,
            slope,
        })
    }

    /// |g|: the tangent of the face's tilt against the surface.
    pub fn tilt(&self) -> f64 {
        self.slope[0].hypot(self.slope[1])
    }

    /// Whether the whole face of radius a presses on an elastic half-space: δ₀ ≥ 2|g|a, where
    /// the full-contact pressure E*(δ₀ + 2g·x)/(π√(a² − r²)) is non-negative at the high rim.
    pub fn full_contact(&self, radius_m: f64) -> bool {
        self.depth_m >= 2.0 * self.tilt() * radius_m
    }

    /// The full-contact pressure over Sneddon's at x: 1 + 2g·x/δ₀.
    pub fn full_contact_factor(&self, x: [f64; 2]) -> f64 {
        1.0 + 2.0 * (self.slope[0] * x[0] + self.slope[1] * x[1]) / self.depth_m
    }

    /// The centre of the full-contact pressure, in the disk's plane: (2/3)a²g/δ₀ (toward the
    /// low side, |·| ≤ a/3 in full contact).
    pub fn full_contact_centre(&self, radius_m: f64) -> [f64; 2] {
        let s = 2.0 / 3.0 * radius_m * radius_m / self.depth_m;
        [s * self.slope[0], s * self.slope[1]]
    }
}

/// One cell of the tilted disk's contact solve: where it meets the rest surface and how far the
/// face presses there.
#[derive(Clone, Debug)]
struct ContactCell<'a> {
    /// The hit on the rest surface, m.
    point: Vector3<f64>,
    /// The cell's area on the surface, m².
    area_m2: f64,
    /// The face's penetration along the surface normal, m (negative: a gap).
    penetration_m: f64,
    /// Barycentric weights of the hit on `face`.
    bary: [f64; 3],
    face: &'a [usize; 3],
}

/// The cells of the disk (radius a, `n` × `n` squares of side 2a/n whose centres lie on the
/// disk) that meet the rest surface: `cast(u, v)` the cast along the axis of the disk point
/// (u, v) (signed distance t, barycentric weights, triangle), `normal` a triangle's unit normal,
/// `point` the surface point of a hit.
fn tilted_punch_cells<'a>(
    n: usize,
    radius_m: f64,
    cast: &dyn Fn(f64, f64) -> Option<(f64, [f64; 3], &'a [usize; 3])>,
    axis: &Vector3<f64>,
    normal: &dyn Fn(&[usize; 3]) -> Vector3<f64>,
    point: &dyn Fn(&[usize; 3], &[f64; 3]) -> Vector3<f64>,
) -> Vec<ContactCell<'a>> {
    let n = n.max(2);
    let h = 2.0 * radius_m / n as f64;
    let mut cells = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (u, w) = (
                -radius_m + (i as f64 + 0.5) * h,
                -radius_m + (j as f64 + 0.5) * h,
            );
            if u * u + w * w > radius_m * radius_m {
                continue;
            }
            let Some((t, bary, face)) = cast(u, w) else {
                continue;
            };
            // The axis meets front faces only (n·axis < 0): the cast stretches the cell's area
            // by 1/|n·axis| and the normal penetration is |n·axis| of the axial one.
            let c = normal(face).dot(axis).abs().max(1e-6);
            cells.push(ContactCell {
                point: point(face, &bary),
                area_m2: h * h / c,
                penetration_m: -t * c,
                bary,
                face,
            });
        }
    }
    cells
}

/// The nodal shares of the rigid face's contact pressure over `cells` on an elastic half-space
/// (Johnson 1985, ch. 5: non-Hertzian normal contact by influence coefficients). The surface
/// displacement at cell i is w_i = Σ_j K_ij P_j (in units of (1 − ν²)/(πE), which the shares do
/// not depend on): Boussinesq's point load K_ij = 1/|x_i − x_j| between cells and, for a cell's
/// own load, the centre displacement of a uniformly loaded disk of the cell's area A,
/// K_ii = 2√(π/A). Loads P ≥ 0 with w_i = δ_i where P_i > 0 and w_i ≥ δ_i elsewhere (the
/// surface reaches the face exactly where it carries load, nowhere penetrates it): a linear
/// complementarity problem, solved by active sets (start from the cells the face penetrates;
/// drop the cells with tensile load, add the cells the surface would penetrate, until neither
/// happens). When the face penetrates no cell, the deepest carries the whole force.
/// `None` for no cells.
fn incomplete_contact_weights(cells: &[ContactCell<'_>]) -> Option<Vec<(usize, f64)>> {
    let n = cells.len();
    if n == 0 {
        return None;
    }
    let deepest = (0..n)
        .max_by(|&a, &b| cells[a].penetration_m.total_cmp(&cells[b].penetration_m))
        .unwrap_or(0);
    let mut load = vec![0.0; n];
    if cells[deepest].penetration_m <= 0.0 {
        load[deepest] = 1.0;
    } else {
        let k = nalgebra::DMatrix::<f64>::from_fn(n, n, |i, j| {
            if i == j {
                2.0 * (std::f64::consts::PI / cells[i].area_m2).sqrt()
            } else {
                1.0 / (cells[i].point - cells[j].point).norm().max(1e-12)
            }
        });
        let scale = cells[deepest].penetration_m;
        let mut active: Vec<bool> = cells.iter().map(|c| c.penetration_m > 0.0).collect();
        // Each pass either settles or changes the set; a cycle ends at the cap with the last
        // solution's compressive loads.
        for _ in 0..4 * n {
            let idx: Vec<usize> = (0..n).filter(|&i| active[i]).collect();
            if idx.is_empty() {
                active[deepest] = true;
                continue;
            }
            let kaa =
                nalgebra::DMatrix::<f64>::from_fn(idx.len(), idx.len(), |a, b| k[(idx[a], idx[b])]);
            let rhs =
                nalgebra::DVector::<f64>::from_fn(idx.len(), |a, _| cells[idx[a]].penetration_m);
            let p = match kaa.clone().cholesky() {
                Some(ch) => ch.solve(&rhs),
                None => kaa.lu().solve(&rhs)?,
            };
            load.iter_mut().for_each(|l| *l = 0.0);
            for (a, &i) in idx.iter().enumerate() {
                load[i] = p[a];
            }
            let mut changed = false;
            for &i in &idx {
                if load[i] < 0.0 {
                    active[i] = false;
                    changed = true;
                }
            }
            if changed {
                continue;
            }
            for i in 0..n {
                if active[i] {
                    continue;
                }
                let w: f64 = idx.iter().map(|&j| k[(i, j)] * load[j]).sum();
                if w < cells[i].penetration_m - 1e-9 * scale {
                    active[i] = true;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        load.iter_mut().for_each(|l| *l = l.max(0.0));
    }
    let total: f64 = load.iter().sum();
    if total <= 0.0 {
        return None;
    }
    let mut acc = std::collections::BTreeMap::new();
    for (c, l) in cells.iter().zip(&load) {
        if *l > 0.0 {
            for (node, b) in c.face.iter().zip(c.bary) {
                *acc.entry(*node).or_insert(0.0) += b * l / total;
            }
        }
    }
    Some(
        acc.into_iter()
            .filter(|e: &(usize, f64)| e.1 != 0.0)
            .collect(),
    )
}
