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
        let rings = patch.rings.max(1);
        let per_ring = patch.samples_per_ring.max(1);
        let mut acc: std::collections::BTreeMap<usize, f64> = std::collections::BTreeMap::new();
        let mut hit_samples = 0usize;
        for k in 0..rings {
            let r = radius
                * patch
                    .load
                    .ring_radius_fraction((k as f64 + 0.5) / rings as f64);
            let turn = if k % 2 == 1 { 0.5 } else { 0.0 };
            for j in 0..per_ring {
                let phi = std::f64::consts::TAU * (j as f64 + turn) / per_ring as f64;
                let origin = example.tip_m + (e1 * phi.cos() + e2 * phi.sin()) * r;
                let best = candidates
                    .iter()
                    .filter_map(|f| {
                        softcap_mesh::line_triangle(&origin, &axis, &f.map(|i| v[i])).map(
                            |(t, w)| {
                                // Clamp the edge tolerance away; keep Σw = 1.
                                let w = w.map(|c| c.clamp(0.0, 1.0));
                                let sum: f64 = w.iter().sum();
                                (t, w.map(|c| c / sum), f)
                            },
                        )
                    })
                    .min_by(|a, b| a.0.abs().total_cmp(&b.0.abs()));
                if let Some((_, w, f)) = best {
                    hit_samples += 1;
                    for (n, wn) in f.iter().zip(w) {
                        *acc.entry(*n).or_insert(0.0) += wn;
                    }
                }
            }
        }
        if hit_samples == 0 {
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
        let scale = 1.0 / hit_samples as f64;
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
