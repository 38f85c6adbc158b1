//! The hypothesis catalog and its refits.
//!
//! Every hypothesis is a model extension with few parameters. Around the baseline simulation
//! x₀(t) (bickel2009 elastostatics driven by the measured force) an extension predicts
//!
//!   x(t; φ, θ) = x₀(t) + c_φ(t) + Σ_j θ_j B_{φ,j}(t),
//!
//! with a handful of nonlinear parameters φ searched on a grid and linear parameters θ (some
//! bounded below by 0). Load-type extensions act through the tangent response T(t) = ∂x/∂f of the
//! converged baseline state, i.e. B = T(t)·δf(t) is the linearised response to the extra load
//! δf(t) the extension adds (residual Jacobian w.r.t. the extension parameters computed once);
//! the winner is confirmed by re-simulating the effective loads with the full model.
//!
//! | name | extra load / field | parameters |
//! |---|---|---|
//! | viscoelasticity | creep (standard linear solid): f_eff = f + a f + g·LP_τ(f) | τ (grid), a, g ≥ 0 |
//! | plasticity | permanent set ∝ elastic response at each location's peak, above a yield force | f_y (grid), β ≥ 0 |
//! | gravity-preload | gravity body-force response of density ρ (wang2015 eq. 7) | ρ ≥ 0 |
//! | probe-friction | tangential traction μ‖f‖ŝ at the contact patch, ŝ = tangential tip travel; or sliding along the travel, reversing when the tip slides back (`crate::friction`) | μ |
//! | support-slip | rigid translation c·P_t f (elastic) + c_p·P_t f at the running max (stick-slip) | c, c_p ≥ 0 |
//! | clock-offset | force trace shifted in time: f_eff(t) = f(t + δ) | δ (grid) |
//! | sensor-lag | FSR chain, first order: f_true = f + τ ḟ + h sgn(ḟ) f | τ, h ≥ 0 |
//! | anisotropy | displacement along a fibre direction a scaled: −κ a (a·u₀) | a (13 directions), κ |
//! | inertia-damping | M ü + C u̇: x = x₀ − c u̇₀ − m ü₀ | c ≥ 0, m ≥ 0 |

use crate::recording::Recording;
use crate::segment::Segmentation;
use crate::signal::{derivative, low_pass, sample};
use nalgebra::{DMatrix, DVector, Vector3};
use serde::{Deserialize, Serialize};

/// A catalog entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum Hypothesis {
    /// Rate dependence and creep (generalized Maxwell / Prony).
    Viscoelasticity,
    /// Plastic set.
    Plasticity,
    /// Gravity pre-load: rest shape ≠ observed shape.
    GravityPreload,
    /// Tangential traction under the probe.
    ProbeFriction,
    /// The object slides on its support.
    SupportSlip,
    /// Camera–force clock offset.
    ClockOffset,
    /// Force sensor lag.
    SensorLag,
    /// Anisotropy (transversely isotropic stiffening).
    Anisotropy,
    /// Inertia and damping.
    InertiaDamping,
}

impl Hypothesis {
    /// The catalog, in issue order.
    pub const ALL: [Hypothesis; 9] = [
        Hypothesis::Viscoelasticity,
        Hypothesis::Plasticity,
        Hypothesis::GravityPreload,
        Hypothesis::ProbeFriction,
        Hypothesis::SupportSlip,
        Hypothesis::ClockOffset,
        Hypothesis::SensorLag,
        Hypothesis::Anisotropy,
        Hypothesis::InertiaDamping,
    ];

    /// The catalog name (issue 8, exact).
    pub fn name(self) -> &'static str {
        match self {
            Hypothesis::Viscoelasticity => "viscoelasticity",
            Hypothesis::Plasticity => "plasticity",
            Hypothesis::GravityPreload => "gravity-preload",
            Hypothesis::ProbeFriction => "probe-friction",
            Hypothesis::SupportSlip => "support-slip",
            Hypothesis::ClockOffset => "clock-offset",
            Hypothesis::SensorLag => "sensor-lag",
            Hypothesis::Anisotropy => "anisotropy",
            Hypothesis::InertiaDamping => "inertia-damping",
        }
    }

    /// Parses a catalog name.
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|h| h.name() == s)
    }

    /// The term the extension adds, for reports and the extended model.
    pub fn term(self) -> &'static str {
        match self {
            Hypothesis::Viscoelasticity => {
                "creep: f_eff = (1 + instant_scale) f + creep_g LP_tau(f) (standard linear solid)"
            }
            Hypothesis::Plasticity => {
                "plastic set = plastic_fraction * T_peak (max(0, |f|_max - yield_force_n)) f_hat"
            }
            Hypothesis::GravityPreload => "body force rho g (wang2015 eq. 7)",
            Hypothesis::ProbeFriction => "tangential traction mu |f| s_hat at the contact patch",
            Hypothesis::SupportSlip => {
                "rigid support translation slip_compliance P_t f + stick_slip_compliance P_t f_max"
            }
            Hypothesis::ClockOffset => "force time base shifted: f_eff(t) = f(t + offset_s)",
            Hypothesis::SensorLag => {
                "FSR chain: first-order lag tau_s then play hysteresis of half-width hysteresis * f (f_true = f + tau_s df/dt + hysteresis sgn(df/dt) f to first order)"
            }
            Hypothesis::Anisotropy => "displacement along fibre a scaled by (1 - kappa)",
            Hypothesis::InertiaDamping => "x = x0 - damping_s dx0/dt - mass_s2 d2x0/dt2",
        }
    }

    /// True if the extension is an extra load the full simulator can re-simulate exactly.
    pub fn is_load_extension(self) -> bool {
        matches!(
            self,
            Hypothesis::Viscoelasticity
                | Hypothesis::GravityPreload
                | Hypothesis::ProbeFriction
                | Hypothesis::ClockOffset
                | Hypothesis::SensorLag
        )
    }
}

/// Field over frames × markers.
pub type Field = Vec<Vec<Vector3<f64>>>;

/// One linear parameter with its basis field.
#[derive(Clone, Debug)]
pub struct Basis {
    /// Parameter name.
    pub name: &'static str,
    /// True if θ ≥ 0 is required.
    pub nonneg: bool,
    /// ∂x/∂θ for every frame and marker.
    pub field: Field,
}

/// One point of a hypothesis' nonlinear grid.
#[derive(Clone, Debug)]
pub struct Variant {
    /// Nonlinear parameters (name, value).
    pub fixed: Vec<(&'static str, f64)>,
    /// Fixed offset field c_φ (None = zero).
    pub offset: Option<Field>,
    /// Linear parameters.
    pub bases: Vec<Basis>,
}

/// The baseline simulation and everything the extensions are built from.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// Frame times, s.
    pub times_s: Vec<f64>,
    /// Measured force per frame, N.
    pub force_n: Vec<Vector3<f64>>,
    /// Baseline marker prediction per frame, m.
    pub baseline_m: Field,
    /// Tangent response ∂x/∂f per frame (3 columns), m/N.
    pub response: Vec<[Vec<Vector3<f64>>; 3]>,
    /// Marker positions of the unloaded model, m.
    pub rest_model_m: Vec<Vector3<f64>>,
    /// Marker displacement under gravity at ρ = 1000 kg/m³, m (zeros without gravity).
    pub gravity_field_m: Vec<Vector3<f64>>,
    /// Tangential direction of the extra traction per location (unit or zero).
    pub friction_dir: Vec<Vector3<f64>>,
}

impl Prepared {
    fn apply(&self, t: usize, v: &Vector3<f64>) -> Vec<Vector3<f64>> {
        let r = &self.response[t];
        (0..r[0].len())
            .map(|m| r[0][m] * v.x + r[1][m] * v.y + r[2][m] * v.z)
            .collect()
    }

    fn load_field(&self, df: &[Vector3<f64>]) -> Field {
        (0..df.len()).map(|t| self.apply(t, &df[t])).collect()
    }

    fn num_markers(&self) -> usize {
        self.rest_model_m.len()
    }

    /// The effective per-frame probe force of a load extension with full-data parameters
    /// `params` (names as in the bases / grid), or None for a non-load extension; `axes` are the
    /// probe axes per frame (the FSR reads along them).
    pub fn effective_forces(
        &self,
        h: Hypothesis,
        params: &[(String, f64)],
        fold_of_frame: &[Option<usize>],
        axes: &[Vector3<f64>],
    ) -> Option<Vec<Vector3<f64>>> {
        let p = |n: &str| {
            params
                .iter()
                .find(|(k, _)| k == n)
                .map(|x| x.1)
                .unwrap_or(0.0)
        };
        let f = &self.force_n;
        let t = &self.times_s;
        Some(match h {
            Hypothesis::Viscoelasticity => {
                let lp = low_pass(t, f, p("tau_s").max(1e-6));
                (0..f.len())
                    .map(|k| f[k] * (1.0 + p("instant_scale")) + lp[k] * p("creep_g"))
                    .collect()
            }
            Hypothesis::SensorLag => {
                crate::sensor::true_forces(t, f, axes, p("tau_s"), p("hysteresis"))
            }
            Hypothesis::ClockOffset => t
                .iter()
                .map(|&tk| sample(t, f, tk + p("offset_s")))
                .collect(),
            Hypothesis::ProbeFriction => (0..f.len())
                .map(|k| match fold_of_frame[k] {
                    Some(l) => f[k] + self.friction_dir[l] * (p("mu") * f[k].norm()),
                    None => f[k],
                })
                .collect(),
            Hypothesis::GravityPreload => f.clone(),
            _ => return None,
        })
    }
}

fn constant_field(n_frames: usize, v: &[Vector3<f64>]) -> Field {
    vec![v.to_vec(); n_frames]
}

/// Thirteen directions covering the hemisphere (axes, face and space diagonals).
pub fn fibre_directions() -> Vec<Vector3<f64>> {
    let mut d = vec![Vector3::x(), Vector3::y(), Vector3::z()];
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        for s in [1.0, -1.0] {
            let mut v = Vector3::zeros();
            v[a] = 1.0;
            v[b] = s;
            d.push(v.normalize());
        }
    }
    for (sy, sz) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
        d.push(Vector3::new(1.0, sy, sz).normalize());
    }
    d
}

/// The nuisance model "global stiffness scale" x = x₀ + s T f: a material mismatch the default
/// (heterogeneous, strain-dependent) material already covers. A hypothesis must beat it, so that a
/// slightly mis-fitted stiffness is not named as missing physics.
pub fn stiffness_scale_variant(p: &Prepared) -> Variant {
    Variant {
        fixed: vec![],
        offset: None,
        bases: vec![Basis {
            name: "stiffness_scale",
            nonneg: false,
            field: p.load_field(&p.force_n),
        }],
    }
}

/// The grid of variants of hypothesis `h`.
pub fn variants(h: Hypothesis, rec: &Recording, seg: &Segmentation, p: &Prepared) -> Vec<Variant> {
    let nt = p.times_s.len();
    let nm = p.num_markers();
    let f = &p.force_n;
    let t = &p.times_s;
    match h {
        Hypothesis::Viscoelasticity => {
            let scale = p.load_field(f);
            (0..13)
                .map(|i| 0.03 * 10f64.powf(i as f64 * 2.5 / 12.0))
                .map(|tau| Variant {
                    fixed: vec![("tau_s", tau)],
                    offset: None,
                    bases: vec![
                        Basis {
                            name: "instant_scale",
                            nonneg: false,
                            field: scale.clone(),
                        },
                        Basis {
                            name: "creep_g",
                            nonneg: true,
                            field: p.load_field(&low_pass(t, f, tau)),
                        },
                    ],
                })
                .collect()
        }
        Hypothesis::SensorLag => {
            // The FSR chain of crate::sensor to first order in (τ, h): the reading r lags the
            // force by τ ṙ and its play reads low by h r while the force rises, high while it
            // falls, so f_true ≈ f + τ ḟ + h sgn(ḟ) f (ḟ along the force).
            let d = derivative(t, f);
            let play: Vec<Vector3<f64>> = f
                .iter()
                .zip(&d)
                .map(|(f, d)| f * d.dot(f).signum())
                .collect();
            vec![Variant {
                fixed: vec![],
                offset: None,
                bases: vec![
                    Basis {
                        name: "tau_s",
                        nonneg: true,
                        field: p.load_field(&d),
                    },
                    Basis {
                        name: "hysteresis",
                        nonneg: true,
                        field: p.load_field(&play),
                    },
                ],
            }]
        }
        Hypothesis::ClockOffset => {
            let dt_med = {
                let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
                d.sort_by(f64::total_cmp);
                d.get(d.len() / 2).copied().unwrap_or(0.03)
            };
            let step = (dt_med / 4.0).clamp(1e-3, 0.01);
            let nsteps = (0.3 / step).round() as i64;
            (-nsteps..=nsteps)
                .filter(|&i| i != 0)
                .map(|i| i as f64 * step)
                .map(|delta| {
                    let df: Vec<_> = (0..nt).map(|k| sample(t, f, t[k] + delta) - f[k]).collect();
                    Variant {
                        fixed: vec![("offset_s", delta)],
                        offset: Some(p.load_field(&df)),
                        bases: vec![],
                    }
                })
                .collect()
        }
        Hypothesis::Plasticity => {
            let peak = seg.peak_force_n();
            (0..8)
                .map(|i| i as f64 * 0.1 * peak)
                .map(|fy| {
                    let mut field = vec![vec![Vector3::zeros(); nm]; nt];
                    for l in &seg.locations {
                        let pk = l.peak_frame;
                        let dir = f[pk].try_normalize(1e-12).unwrap_or_else(Vector3::zeros);
                        let unit = p.apply(pk, &dir);
                        let mut run_max = 0.0f64;
                        for k in 0..nt {
                            if seg.fold_of_frame[k] == Some(l.index) && seg.phases[k].in_contact() {
                                run_max = run_max.max(f[k].norm());
                            }
                            let excess = (run_max - fy).max(0.0);
                            if excess > 0.0 {
                                for m in 0..nm {
                                    field[k][m] += unit[m] * excess;
                                }
                            }
                        }
                    }
                    Variant {
                        fixed: vec![("yield_force_n", fy)],
                        offset: None,
                        bases: vec![Basis {
                            name: "plastic_fraction",
                            nonneg: true,
                            field,
                        }],
                    }
                })
                .collect()
        }
        Hypothesis::GravityPreload => {
            if p.gravity_field_m.iter().all(|v| *v == Vector3::zeros()) {
                return vec![];
            }
            vec![Variant {
                fixed: vec![],
                offset: None,
                bases: vec![Basis {
                    name: "density_per_1000_kg_m3",
                    nonneg: true,
                    field: constant_field(nt, &p.gravity_field_m),
                }],
            }]
        }
        Hypothesis::ProbeFriction => {
            let df: Vec<_> = (0..nt)
                .map(|k| match seg.fold_of_frame[k] {
                    Some(l) if seg.phases[k].in_contact() => p.friction_dir[l] * f[k].norm(),
                    _ => Vector3::zeros(),
                })
                .collect();
            if df.iter().all(|v| *v == Vector3::zeros()) {
                return vec![];
            }
            let mut out = vec![Variant {
                fixed: vec![],
                offset: None,
                bases: vec![Basis {
                    name: "mu",
                    nonneg: false,
                    field: p.load_field(&df),
                }],
            }];
            // Sliding Coulomb traction μ f_n along the tip's travel, reversing when the tip
            // slides back (crate::friction::sliding_direction), where the tip travels.
            let k_ind = crate::friction::indentation_stiffness_n_per_m(seg);
            let dir = crate::friction::sliding_direction(rec, seg, f, k_ind);
            let slide: Vec<_> = (0..nt)
                .map(|k| match seg.fold_of_frame[k] {
                    Some(_) if seg.phases[k].in_contact() => dir[k] * f[k].norm(),
                    _ => Vector3::zeros(),
                })
                .collect();
            if slide.iter().any(|v| *v != Vector3::zeros()) {
                out.push(Variant {
                    fixed: vec![("sliding_reverses", 1.0)],
                    offset: None,
                    bases: vec![Basis {
                        name: "mu",
                        nonneg: false,
                        field: p.load_field(&slide),
                    }],
                });
            }
            out
        }
        Hypothesis::SupportSlip => {
            let n = match (&rec.support, rec.gravity_dir()) {
                (Some(s), _) => s.normal,
                (None, g) if g != Vector3::zeros() => g,
                _ => return vec![],
            };
            let pt = |v: &Vector3<f64>| v - n * n.dot(v);
            let mut elastic = Vec::with_capacity(nt);
            let mut stick = Vec::with_capacity(nt);
            let mut best = Vector3::zeros();
            for k in 0..nt {
                let ft = pt(&f[k]);
                if ft.norm() > best.norm() {
                    best = ft;
                }
                elastic.push(vec![ft; nm]);
                stick.push(vec![best; nm]);
            }
            vec![Variant {
                fixed: vec![],
                offset: None,
                bases: vec![
                    Basis {
                        name: "slip_compliance_m_per_n",
                        nonneg: true,
                        field: elastic,
                    },
                    Basis {
                        name: "stick_slip_compliance_m_per_n",
                        nonneg: true,
                        field: stick,
                    },
                ],
            }]
        }
        Hypothesis::Anisotropy => fibre_directions()
            .into_iter()
            .map(|a| {
                let field = (0..nt)
                    .map(|k| {
                        (0..nm)
                            .map(|m| -a * a.dot(&(p.baseline_m[k][m] - p.rest_model_m[m])))
                            .collect()
                    })
                    .collect();
                Variant {
                    fixed: vec![("fibre_x", a.x), ("fibre_y", a.y), ("fibre_z", a.z)],
                    offset: None,
                    bases: vec![Basis {
                        name: "kappa",
                        nonneg: false,
                        field,
                    }],
                }
            })
            .collect(),
        Hypothesis::InertiaDamping => {
            let per_marker: Vec<Vec<Vector3<f64>>> = (0..nm)
                .map(|m| (0..nt).map(|k| p.baseline_m[k][m]).collect())
                .collect();
            let v: Vec<Vec<Vector3<f64>>> = per_marker.iter().map(|x| derivative(t, x)).collect();
            let a: Vec<Vec<Vector3<f64>>> = v.iter().map(|x| derivative(t, x)).collect();
            let tr = |g: &Vec<Vec<Vector3<f64>>>| -> Field {
                (0..nt)
                    .map(|k| (0..nm).map(|m| -g[m][k]).collect())
                    .collect()
            };
            vec![Variant {
                fixed: vec![],
                offset: None,
                bases: vec![
                    Basis {
                        name: "damping_s",
                        nonneg: true,
                        field: tr(&v),
                    },
                    Basis {
                        name: "mass_s2",
                        nonneg: true,
                        field: tr(&a),
                    },
                ],
            }]
        }
    }
}

/// Per-frame normal-equation pieces of one variant: G_t = B_tᵀB_t, h_t = B_tᵀr_t, e_t = r_tᵀr_t
/// with r_t = y_t − x₀_t − c_t over the observed markers.
pub struct FrameStats {
    /// G_t per frame.
    pub g: Vec<DMatrix<f64>>,
    /// h_t per frame.
    pub h: Vec<DVector<f64>>,
    /// e_t per frame.
    pub e: Vec<f64>,
    /// Observed markers per frame.
    pub n: Vec<usize>,
}

impl FrameStats {
    /// Builds the pieces over every observed marker.
    pub fn new(rec: &Recording, p: &Prepared, v: &Variant) -> Self {
        Self::masked(rec, p, v, &|_, _| true)
    }

    /// Builds the pieces over the observed markers (frame k, marker m) with `mask(k, m)`.
    pub fn masked(
        rec: &Recording,
        p: &Prepared,
        v: &Variant,
        mask: &dyn Fn(usize, usize) -> bool,
    ) -> Self {
        let nb = v.bases.len();
        let nt = rec.frames.len();
        let mut out = FrameStats {
            g: Vec::with_capacity(nt),
            h: Vec::with_capacity(nt),
            e: Vec::with_capacity(nt),
            n: Vec::with_capacity(nt),
        };
        for k in 0..nt {
            let mut g = DMatrix::zeros(nb, nb);
            let mut h = DVector::zeros(nb);
            let mut e = 0.0;
            let mut n = 0;
            for (m, y) in rec.frames[k].markers_m.iter().enumerate() {
                let Some(y) = y else { continue };
                if !mask(k, m) {
                    continue;
                }
                let mut r = y - p.baseline_m[k][m];
                if let Some(c) = &v.offset {
                    r -= c[k][m];
                }
                e += r.norm_squared();
                n += 1;
                for i in 0..nb {
                    let bi = v.bases[i].field[k][m];
                    h[i] += bi.dot(&r);
                    for j in 0..=i {
                        let gij = bi.dot(&v.bases[j].field[k][m]);
                        g[(i, j)] += gij;
                        if i != j {
                            g[(j, i)] += gij;
                        }
                    }
                }
            }
            out.g.push(g);
            out.h.push(h);
            out.e.push(e);
            out.n.push(n);
        }
        out
    }

    /// Summed pieces over the frames selected by `keep`.
    pub fn sum(&self, keep: impl Fn(usize) -> bool) -> (DMatrix<f64>, DVector<f64>, f64, usize) {
        let nb = self.h.first().map(|h| h.len()).unwrap_or(0);
        let mut g = DMatrix::zeros(nb, nb);
        let mut h = DVector::zeros(nb);
        let (mut e, mut n) = (0.0, 0);
        for k in 0..self.e.len() {
            if keep(k) {
                g += &self.g[k];
                h += &self.h[k];
                e += self.e[k];
                n += self.n[k];
            }
        }
        (g, h, e, n)
    }
}

/// RSS(θ) = e − 2θᵀh + θᵀGθ.
pub fn rss(g: &DMatrix<f64>, h: &DVector<f64>, e: f64, theta: &DVector<f64>) -> f64 {
    (e - 2.0 * theta.dot(h) + theta.dot(&(g * theta))).max(0.0)
}

/// Least squares min_θ RSS(θ) subject to θ_j ≥ 0 for `nonneg[j]`, by enumerating the active sets
/// (a handful of parameters: 2^p reduced solves). A tiny relative ridge keeps rank-deficient bases
/// (e.g. a field that vanishes on the training frames) solvable.
pub fn bounded_least_squares(g: &DMatrix<f64>, h: &DVector<f64>, nonneg: &[bool]) -> DVector<f64> {
    let p = h.len();
    let bounded: Vec<usize> = (0..p).filter(|&j| nonneg[j]).collect();
    let mut best: Option<(f64, DVector<f64>)> = None;
    for mask in 0..(1usize << bounded.len()) {
        let fixed: Vec<usize> = bounded
            .iter()
            .enumerate()
            .filter(|(b, _)| mask & (1 << b) != 0)
            .map(|(_, &j)| j)
            .collect();
        let free: Vec<usize> = (0..p).filter(|j| !fixed.contains(j)).collect();
        let mut theta = DVector::zeros(p);
        if !free.is_empty() {
            let gf = DMatrix::from_fn(free.len(), free.len(), |a, b| g[(free[a], free[b])]);
            let hf = DVector::from_fn(free.len(), |a, _| h[free[a]]);
            let ridge = 1e-12 * (0..free.len()).map(|a| gf[(a, a)]).fold(0.0, f64::max) + 1e-300;
            let gr = gf + DMatrix::identity(free.len(), free.len()) * ridge;
            let Some(sol) = gr.cholesky().map(|c| c.solve(&hf)) else {
                continue;
            };
            for (a, &j) in free.iter().enumerate() {
                theta[j] = sol[a];
            }
        }
        if bounded.iter().any(|&j| theta[j] < 0.0) {
            continue;
        }
        let obj = theta.dot(&(g * &theta)) - 2.0 * theta.dot(h);
        if best.as_ref().is_none_or(|(b, _)| obj < *b) {
            best = Some((obj, theta));
        }
    }
    best.map(|b| b.1).unwrap_or_else(|| DVector::zeros(p))
}

/// Outcome of refitting one hypothesis.
#[derive(Clone, Debug)]
pub struct Refit {
    /// Which hypothesis.
    pub hypothesis: Hypothesis,
    /// Number of parameters (nonlinear + linear).
    pub num_params: usize,
    /// Full-data parameters (nonlinear grid values, then linear).
    pub params: Vec<(String, f64)>,
    /// Index of the full-data variant.
    pub variant: usize,
    /// Full-data linear parameters.
    pub theta: DVector<f64>,
    /// Full-data RSS, m².
    pub rss_m2: f64,
    /// Held-out RSS over all folds (leave one location out), m².
    pub heldout_rss_m2: f64,
    /// Number of held-out marker observations.
    pub heldout_n: usize,
    /// Parameters fitted in each fold.
    pub fold_params: Vec<Vec<(String, f64)>>,
}

fn fit_variants(
    stats: &[FrameStats],
    vars: &[Variant],
    keep: &dyn Fn(usize) -> bool,
) -> (usize, DVector<f64>, f64) {
    let mut best: Option<(usize, DVector<f64>, f64)> = None;
    for (i, (s, v)) in stats.iter().zip(vars).enumerate() {
        let (g, h, e, _) = s.sum(keep);
        let nonneg: Vec<bool> = v.bases.iter().map(|b| b.nonneg).collect();
        let theta = bounded_least_squares(&g, &h, &nonneg);
        let r = rss(&g, &h, e, &theta);
        if best.as_ref().is_none_or(|b| r < b.2) {
            best = Some((i, theta, r));
        }
    }
    best.unwrap_or((0, DVector::zeros(0), f64::INFINITY))
}

fn named_params(v: &Variant, theta: &DVector<f64>) -> Vec<(String, f64)> {
    v.fixed
        .iter()
        .map(|(n, x)| (n.to_string(), *x))
        .chain(
            v.bases
                .iter()
                .zip(theta.iter())
                .map(|(b, x)| (b.name.to_string(), *x)),
        )
        .collect()
}

/// Refits `h` on all data and in every leave-one-location-out fold (linearised; see module docs).
/// `None` when the hypothesis cannot act on this recording (e.g. no gravity, no tangential load).
pub fn refit(h: Hypothesis, rec: &Recording, seg: &Segmentation, p: &Prepared) -> Option<Refit> {
    refit_variants(h, &variants(h, rec, seg, p), rec, seg, p)
}

/// [`refit`] fitted on every observed marker of the training locations and scored on the
/// held-out location's observations with `score(k, m)` (the affected cells the locate step
/// found, see `DiagnoseSettings::focus_noise_factor`).
pub fn refit_scored(
    h: Hypothesis,
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    score: &dyn Fn(usize, usize) -> bool,
) -> Option<Refit> {
    refit_variants_scored(h, &variants(h, rec, seg, p), rec, seg, p, score)
}

/// [`refit`] over an explicit variant list (also used for the nuisance models of the verdict).
pub fn refit_variants(
    h: Hypothesis,
    vars: &[Variant],
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
) -> Option<Refit> {
    refit_variants_scored(h, vars, rec, seg, p, &|_, _| true)
}

/// [`refit_variants`] scored on the held-out observations with `score(k, m)`.
pub fn refit_variants_scored(
    h: Hypothesis,
    vars: &[Variant],
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    score: &dyn Fn(usize, usize) -> bool,
) -> Option<Refit> {
    if vars.is_empty() {
        return None;
    }
    let stats: Vec<FrameStats> = vars.iter().map(|v| FrameStats::new(rec, p, v)).collect();
    let scored: Vec<FrameStats> = vars
        .iter()
        .map(|v| FrameStats::masked(rec, p, v, score))
        .collect();
    let (vi, theta, rss_m2) = fit_variants(&stats, vars, &|_| true);
    let mut heldout_rss_m2 = 0.0;
    let mut heldout_n = 0;
    let mut fold_params = Vec::new();
    for l in 0..seg.num_folds() {
        let (fi, ft, _) = fit_variants(&stats, vars, &|k| seg.fold_of_frame[k] != Some(l));
        let (g, hh, e, n) = scored[fi].sum(|k| seg.fold_of_frame[k] == Some(l));
        heldout_rss_m2 += rss(&g, &hh, e, &ft);
        heldout_n += n;
        fold_params.push(named_params(&vars[fi], &ft));
    }
    Some(Refit {
        hypothesis: h,
        num_params: vars[vi].fixed.len() + vars[vi].bases.len(),
        params: named_params(&vars[vi], &theta),
        variant: vi,
        theta,
        rss_m2,
        heldout_rss_m2,
        heldout_n,
        fold_params,
    })
}

/// The full-data linearised prediction of a refit.
pub fn predict(
    h: Hypothesis,
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    r: &Refit,
) -> Field {
    let vars = variants(h, rec, seg, p);
    let v = &vars[r.variant];
    (0..p.times_s.len())
        .map(|k| {
            (0..p.num_markers())
                .map(|m| {
                    let mut x = p.baseline_m[k][m];
                    if let Some(c) = &v.offset {
                        x += c[k][m];
                    }
                    for (b, th) in v.bases.iter().zip(r.theta.iter()) {
                        x += b.field[k][m] * *th;
                    }
                    x
                })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounded_least_squares_clips_to_the_bound() {
        // min (θ0 − 1)² + (θ1 + 2)² with θ1 ≥ 0 → (1, 0).
        let g = DMatrix::identity(2, 2);
        let h = DVector::from_vec(vec![1.0, -2.0]);
        let t = bounded_least_squares(&g, &h, &[false, true]);
        assert!((t[0] - 1.0).abs() < 1e-9 && t[1] == 0.0);
        let t = bounded_least_squares(&g, &h, &[false, false]);
        assert!((t[1] + 2.0).abs() < 1e-9);
    }

    #[test]
    fn thirteen_distinct_fibre_directions() {
        let d = fibre_directions();
        assert_eq!(d.len(), 13);
        for i in 0..13 {
            assert!((d[i].norm() - 1.0).abs() < 1e-12);
            for j in 0..i {
                assert!(d[i].dot(&d[j]).abs() < 0.999, "{i} {j} parallel");
            }
        }
    }
}
