//! The screen: every hypothesis refitted linearised around the baseline, leave-one-location-out.
//!
//! Every hypothesis is a model extension with few parameters. Around the baseline simulation
//! x₀(t) (bickel2009 elastostatics driven by the measured force) an extension predicts
//!
//!   x(t; φ, θ) = x₀(t) + c_φ(t) + Σ_j θ_j B_{φ,j}(t),
//!
//! with a handful of nonlinear parameters φ searched on a grid ([`Variant`]s) and linear
//! parameters θ (some bounded below by 0, [`Basis`]). Load-type extensions act through the tangent
//! response T(t) = ∂x/∂f of the converged baseline state, i.e. B = T(t)·δf(t) is the linearised
//! response to the extra load δf(t) the extension adds (residual Jacobian w.r.t. the extension
//! parameters computed once, [`Prepared::load_field`]). [`refit`] fits θ on all data and in every
//! leave-one-location-out fold from per-frame normal equations ([`FrameStats`]); each hypothesis
//! builds its own grid (`crate::hypotheses`).

use crate::baseline::Prepared;
use crate::recording::Recording;
use crate::segment::Segmentation;
use crate::sim::Field;
use nalgebra::{DMatrix, DVector};

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

/// Outcome of refitting one hypothesis' variants.
#[derive(Clone, Debug)]
pub struct Refit {
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
    /// Held-out RSS per fold (location), m².
    pub fold_rss_m2: Vec<f64>,
    /// Held-out scored observations per fold.
    pub fold_n: Vec<usize>,
}

impl Refit {
    /// Held-out RMS over the scored observations, m.
    pub fn heldout_rmse_m(&self) -> f64 {
        (self.heldout_rss_m2 / self.heldout_n.max(1) as f64).sqrt()
    }
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

/// Refits the variants `vars` of one extension (linearised; see the module docs): the variant and
/// its linear parameters with the least RSS on every observed marker, on all data and in every
/// leave-one-location-out fold (fitted on the training locations), each fold scored on the
/// held-out location's observations with `score(k, m)` (the affected cells the locate step found,
/// or the hypothesis's effect cells). `None` without variants (the extension cannot act on this
/// recording, e.g. no gravity, no tangential load).
pub fn refit(
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
    let (mut fold_rss_m2, mut fold_n) = (Vec::new(), Vec::new());
    for l in 0..seg.num_folds() {
        let (fi, ft, _) = fit_variants(&stats, vars, &|k| seg.fold_of_frame[k] != Some(l));
        let (g, hh, e, n) = scored[fi].sum(|k| seg.fold_of_frame[k] == Some(l));
        let r = rss(&g, &hh, e, &ft);
        heldout_rss_m2 += r;
        heldout_n += n;
        fold_rss_m2.push(r);
        fold_n.push(n);
        fold_params.push(named_params(&vars[fi], &ft));
    }
    Some(Refit {
        num_params: vars[vi].fixed.len() + vars[vi].bases.len(),
        params: named_params(&vars[vi], &theta),
        variant: vi,
        theta,
        rss_m2,
        heldout_rss_m2,
        heldout_n,
        fold_params,
        fold_rss_m2,
        fold_n,
    })
}

/// The full-data linearised prediction of a refit of `vars`.
pub fn predict(vars: &[Variant], p: &Prepared, r: &Refit) -> Field {
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
}
