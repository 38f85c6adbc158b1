//! Pooled cross-section fit: one wrinkle profile from all cross-sections of a wrinkle in a frame
//! (thesis §4.3.2, eq. 4.3–4.4 summed over the sections).
//!
//! The thesis fits (d, w) of every cross-section alone. For a shallow wrinkle that is noise-bound:
//! the dip of the shading ratio shrinks like (d/w)², and the scale w is held only by the dip's
//! width, so at d/w ≲ 0.3 a section's (d, w) moves with its pixels' noise (d and w err together).
//! The wrinkle's width and depth vary slowly along its valley ("width w(x) and depth d(x) …
//! varying along the parameterization x of each valley spline", §4.3.2), so this fit shares
//! them: with t ∈ [−1, 1] the section's position along the measured part of the valley,
//!
//! d(x) = Σ_k δ_k P_k(t),   w(x) = Σ_k ω_k P_k(t)   (Legendre polynomials P_k, k ≤ degree)
//!
//! and minimizes eq. 4.4 over every sample of every section at once,
//!
//! min Σ_i Σ_p ω_ip [I_obs(p)/I_obs(m_i) − c_i F(w(x_i), d(x_i), p − p₀ᵢ)]²,
//!
//! keeping each section's own valley offset p₀ᵢ and reference scale c_i (the per-section nuisance
//! parameters of [`fit_cross_section`](crate::track::fit_cross_section)) and its
//! effective-variance weights ω_ip. Degree 0 is one (d, w) per wrinkle and frame. The start is
//! the per-section fits: the medians of their (d, w), their own p₀ᵢ and c_i.
//!
//! **Uncertainty.** The covariance of the estimate is σ̂² (JᵀJ)⁻¹ at the solution (J the weighted
//! Jacobian, σ̂² = ‖r‖²/(m − n) the weighted residual variance): the Cramér–Rao bound of the
//! Gaussian-noise model, with the noise level read off the fit itself. [`PooledProfile`] reports
//! the standard deviations of d and w at the middle of the valley (t = 0).

use nalgebra::DMatrix;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_core::{
    Bounds, LeastSquaresProblem, LevenbergMarquardtSettings, SolverStatus, levenberg_marquardt,
};

use crate::cross_section::{HorizonSettings, UnitHorizons, wedge_shading};
use crate::error::{FaceError, Result};
use crate::track::effective_variance_weight;

/// Settings of the pooled fit ([`fit_pooled`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoolSettings {
    /// Fit the wrinkle's sections jointly (else every section keeps its own (d, w)).
    pub enabled: bool,
    /// Degree of the Legendre polynomials d(x), w(x) along the valley (0: one profile).
    pub degree: usize,
    /// Gauss–Newton / LM settings of the joint fit.
    pub solver: LevenbergMarquardtSettings,
}

impl Default for PoolSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            degree: 0,
            solver: LevenbergMarquardtSettings {
                max_iterations: 100,
                ..Default::default()
            },
        }
    }
}

/// The samples of one cross-section and its own fit (the start of the pooled fit).
#[derive(Clone, Debug, PartialEq)]
pub struct SectionSamples {
    /// Spline parameter x of the section.
    pub x: f64,
    /// Signed distances p of the samples to the valley spline (pixels).
    pub p: Vec<f64>,
    /// Intensity ratios I_obs(p)/I_obs(m).
    pub ratio: Vec<f64>,
    /// The section's own fit (d, w, p₀, c).
    pub start: [f64; 4],
}

/// The pooled profile of one wrinkle in one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PooledProfile {
    /// d at the middle of the valley (pixels).
    pub depth_px: f64,
    /// w at the middle of the valley (pixels).
    pub width_px: f64,
    /// Standard deviation of `depth_px` (σ̂² (JᵀJ)⁻¹, module docs; NaN when JᵀJ is singular).
    pub depth_sigma_px: f64,
    /// Standard deviation of `width_px`.
    pub width_sigma_px: f64,
    /// Covariance of `depth_px` and `width_px` (px²; d and w err together on a shallow wrinkle).
    #[serde(default)]
    pub depth_width_cov_px2: f64,
    /// Unweighted RMS of the intensity-ratio residuals over all samples.
    pub rms: f64,
    /// Whether the joint fit converged.
    pub converged: bool,
    /// Cross-sections pooled.
    pub sections: usize,
}

/// The result of [`fit_pooled`]: the profile and, per section, (d, w, p₀) at its x.
#[derive(Clone, Debug, PartialEq)]
pub struct PooledFit {
    /// The wrinkle's profile.
    pub profile: PooledProfile,
    /// Per section, in input order: (d(xᵢ), w(xᵢ), p₀ᵢ).
    pub sections: Vec<[f64; 3]>,
}

/// Smallest width the model is evaluated at (pixels; the per-section fit's lower bound).
pub(crate) const MIN_WIDTH_PX: f64 = 0.3;

/// Legendre polynomials P_0..P_degree at t.
fn legendre(t: f64, degree: usize) -> Vec<f64> {
    let mut p = Vec::with_capacity(degree + 1);
    p.push(1.0);
    if degree >= 1 {
        p.push(t);
    }
    for k in 1..degree {
        let kf = k as f64;
        p.push(((2.0 * kf + 1.0) * t * p[k] - kf * p[k - 1]) / (kf + 1.0));
    }
    p
}

/// One section inside the joint problem.
struct Section<'a> {
    data: &'a SectionSamples,
    /// P_k(tᵢ).
    basis: Vec<f64>,
    /// Effective-variance weights of its samples.
    weight: Vec<f64>,
    /// Horizons at the last (w, p₀) evaluated.
    cache: Option<(f64, f64, Vec<UnitHorizons>)>,
}

/// Eq. 4.4 summed over the sections (module docs). Parameters: δ_0..δ_K, ω_0..ω_K, then
/// (p₀ᵢ, cᵢ) per section (p₀ᵢ only when the reference scale is not fitted).
struct PooledProblem<'a> {
    sections: Vec<Section<'a>>,
    n_basis: usize,
    scale: bool,
    horizon: HorizonSettings,
    offsets: Vec<usize>,
    n_residuals: usize,
}

/// Section i's (d, w, p₀, c) and whether d, w are inside their domain (else clamped, with zero
/// derivative).
struct Local {
    d: f64,
    w: f64,
    p0: f64,
    c: f64,
    d_free: bool,
    w_free: bool,
}

impl PooledProblem<'_> {
    fn per_section(&self) -> usize {
        if self.scale { 2 } else { 1 }
    }

    fn local(&self, i: usize, params: &[f64]) -> Local {
        let nb = self.n_basis;
        let s = &self.sections[i];
        let d: f64 = (0..nb).map(|k| params[k] * s.basis[k]).sum();
        let w: f64 = (0..nb).map(|k| params[nb + k] * s.basis[k]).sum();
        let at = 2 * nb + i * self.per_section();
        Local {
            d: d.max(0.0),
            w: w.max(MIN_WIDTH_PX),
            p0: params[at],
            c: if self.scale { params[at + 1] } else { 1.0 },
            d_free: d >= 0.0,
            w_free: w >= MIN_WIDTH_PX,
        }
    }

    /// Run `f` on every section with its (d, w, p₀, c) at `params`, in parallel (the sections
    /// are independent and each writes only its own state).
    fn for_each_section(
        &mut self,
        params: &[f64],
        f: impl Fn(&mut Section<'_>, &Local, &HorizonSettings) + Sync + Send,
    ) {
        let locals: Vec<Local> = (0..self.sections.len())
            .map(|i| self.local(i, params))
            .collect();
        let horizon = self.horizon;
        self.sections
            .par_iter_mut()
            .zip(&locals)
            .for_each(|(s, l)| f(s, l, &horizon));
    }

    /// Refresh every section's horizons at `params`.
    fn refresh(&mut self, params: &[f64]) {
        self.for_each_section(params, |s, l, horizon| {
            let fresh = !matches!(&s.cache, Some((w, p0, _)) if *w == l.w && *p0 == l.p0);
            if fresh {
                let h = s
                    .data
                    .p
                    .iter()
                    .map(|&pk| UnitHorizons::new((pk - l.p0) / l.w, horizon))
                    .collect();
                s.cache = Some((l.w, l.p0, h));
            }
        });
    }

    /// Effective-variance weights at `params`, as in the per-section fit.
    fn reweight(&mut self, params: &[f64], sigma_ratio: f64, sigma_p_px: f64) {
        self.for_each_section(params, |s, l, horizon| {
            for (wk, &pk) in s.weight.iter_mut().zip(&s.data.p) {
                *wk = effective_variance_weight(
                    [l.d, l.w, l.c],
                    pk - l.p0,
                    [sigma_ratio, sigma_p_px],
                    horizon,
                );
            }
        });
    }
}

impl LeastSquaresProblem for PooledProblem<'_> {
    fn num_params(&self) -> usize {
        2 * self.n_basis + self.sections.len() * self.per_section()
    }
    fn num_residuals(&self) -> usize {
        self.n_residuals
    }
    fn residuals(&mut self, params: &[f64], r: &mut [f64]) {
        self.refresh(params);
        for (i, s) in self.sections.iter().enumerate() {
            let l = self.local(i, params);
            let Some((_, _, hs)) = &s.cache else { continue };
            for (k, h) in hs.iter().enumerate() {
                let p = s.data.p[k] - l.p0;
                r[self.offsets[i] + k] =
                    s.weight[k] * (s.data.ratio[k] - l.c * wedge_shading(l.w, l.d, p, h).ratio);
            }
        }
    }
    fn jacobian(&mut self, params: &[f64], j: &mut DMatrix<f64>) -> bool {
        self.refresh(params);
        let nb = self.n_basis;
        j.fill(0.0);
        for (i, s) in self.sections.iter().enumerate() {
            let l = self.local(i, params);
            let at = 2 * nb + i * self.per_section();
            let Some((_, _, hs)) = &s.cache else { continue };
            for (k, h) in hs.iter().enumerate() {
                let row = self.offsets[i] + k;
                let sh = wedge_shading(l.w, l.d, s.data.p[k] - l.p0, h);
                let wk = s.weight[k];
                for b in 0..nb {
                    if l.d_free {
                        j[(row, b)] = -wk * l.c * sh.d_depth * s.basis[b];
                    }
                    if l.w_free {
                        j[(row, nb + b)] = -wk * l.c * sh.d_width * s.basis[b];
                    }
                }
                j[(row, at)] = wk * l.c * sh.d_p;
                if self.scale {
                    j[(row, at + 1)] = -wk * sh.ratio;
                }
            }
        }
        true
    }
}

/// Median of a non-empty list.
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// Fit one profile d(x), w(x) to every cross-section of a wrinkle at once (module docs).
/// `fit_reference_scale`, `ratio_sigma`, `position_sigma_px`, `reweight_passes` and `horizon`
/// are those of the per-section fit ([`TrackSettings`](crate::track::TrackSettings)).
/// Non-convergence is reported in [`PooledProfile::converged`]; errors only on invalid input.
#[allow(clippy::too_many_arguments)]
pub fn fit_pooled(
    sections: &[SectionSamples],
    pool: &PoolSettings,
    fit_reference_scale: bool,
    ratio_sigma: f64,
    position_sigma_px: f64,
    reweight_passes: usize,
    horizon: &HorizonSettings,
) -> Result<PooledFit> {
    let bad = |reason: String| FaceError::InvalidInput {
        what: "pooled cross-sections",
        reason,
    };
    if sections.len() < pool.degree + 1 {
        return Err(bad(format!(
            "{} sections for degree {}",
            sections.len(),
            pool.degree
        )));
    }
    if let Some(i) = sections
        .iter()
        .position(|s| s.p.len() != s.ratio.len() || s.p.is_empty())
    {
        return Err(bad(format!("section {i}: positions and ratios differ")));
    }
    let (x_lo, x_hi) = sections
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), s| {
            (a.min(s.x), b.max(s.x))
        });
    let half = 0.5 * (x_hi - x_lo);
    let mid = 0.5 * (x_hi + x_lo);
    let nb = pool.degree + 1;
    let mut offsets = Vec::with_capacity(sections.len());
    let mut m = 0;
    for s in sections {
        offsets.push(m);
        m += s.p.len();
    }
    let mut problem = PooledProblem {
        sections: sections
            .iter()
            .map(|s| Section {
                data: s,
                basis: legendre(
                    if half > 0.0 { (s.x - mid) / half } else { 0.0 },
                    pool.degree,
                ),
                weight: vec![1.0; s.p.len()],
                cache: None,
            })
            .collect(),
        n_basis: nb,
        scale: fit_reference_scale,
        horizon: *horizon,
        offsets,
        n_residuals: m,
    };
    let n = problem.num_params();
    let mut start = vec![0.0; n];
    start[0] = median(sections.iter().map(|s| s.start[0]).collect());
    start[nb] = median(sections.iter().map(|s| s.start[1]).collect()).max(MIN_WIDTH_PX);
    let (mut lo, mut hi) = (vec![f64::NEG_INFINITY; n], vec![f64::INFINITY; n]);
    lo[0] = 0.0;
    lo[nb] = MIN_WIDTH_PX;
    for (i, s) in sections.iter().enumerate() {
        let at = 2 * nb + i * problem.per_section();
        start[at] = s.start[2].clamp(-2.0, 2.0);
        (lo[at], hi[at]) = (-2.0, 2.0);
        if fit_reference_scale {
            start[at + 1] = s.start[3].clamp(0.8, 1.2);
            (lo[at + 1], hi[at + 1]) = (0.8, 1.2);
        }
    }
    let bounds = Bounds::new(lo, hi).map_err(|e| FaceError::Core(e.to_string()))?;
    let mut rep = None;
    for _ in 0..reweight_passes.max(1) {
        if position_sigma_px > 0.0 {
            problem.reweight(&start, ratio_sigma, position_sigma_px);
        }
        let r = levenberg_marquardt(&mut problem, &start, Some(&bounds), &pool.solver)
            .map_err(|e| FaceError::Core(e.to_string()))?;
        start.clone_from(&r.params);
        rep = Some(r);
    }
    let Some(rep) = rep else {
        return Err(FaceError::Core("no pooled fit pass ran".into()));
    };
    let params = rep.params;
    // covariance σ̂² (JᵀJ)⁻¹ of the weighted problem at the solution
    let mut jac = DMatrix::zeros(m, n);
    problem.jacobian(&params, &mut jac);
    let dof = m.saturating_sub(n).max(1) as f64;
    let sigma2 = 2.0 * rep.cost / dof;
    let cov = (jac.transpose() * &jac).try_inverse();
    let at_mid = legendre(0.0, pool.degree);
    // Cov(a, b) of the profile at the middle of the valley, a/b the first coefficient of d or w
    let cov_mid = |fa: usize, fb: usize| {
        cov.as_ref().map_or(f64::NAN, |c| {
            let mut v = 0.0;
            for a in 0..nb {
                for b in 0..nb {
                    v += at_mid[a] * c[(fa + a, fb + b)] * at_mid[b];
                }
            }
            sigma2 * v
        })
    };
    let (depth_sigma_px, width_sigma_px) = (
        cov_mid(0, 0).max(0.0).sqrt(),
        cov_mid(nb, nb).max(0.0).sqrt(),
    );
    let depth_width_cov_px2 = cov_mid(0, nb);
    // unweighted RMS
    for s in &mut problem.sections {
        s.weight.fill(1.0);
    }
    let mut res = vec![0.0; m];
    problem.residuals(&params, &mut res);
    let rms = (res.iter().map(|r| r * r).sum::<f64>() / m.max(1) as f64).sqrt();
    let eval = |first: usize| -> f64 { (0..nb).map(|k| params[first + k] * at_mid[k]).sum() };
    let per_section = (0..sections.len())
        .map(|i| {
            let l = problem.local(i, &params);
            [l.d, l.w, l.p0]
        })
        .collect();
    Ok(PooledFit {
        profile: PooledProfile {
            depth_px: eval(0).max(0.0),
            width_px: eval(nb).max(MIN_WIDTH_PX),
            depth_sigma_px,
            width_sigma_px,
            depth_width_cov_px2,
            rms,
            converged: matches!(rep.status, SolverStatus::Converged { .. }),
            sections: sections.len(),
        },
        sections: per_section,
    })
}

/// One frame's pooled estimate for [`smooth_in_time`]: (d, w) and their covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameEstimate {
    /// d (px).
    pub depth_px: f64,
    /// w (px).
    pub width_px: f64,
    /// Var d, Cov(d, w), Var w (px²).
    pub cov_px2: [f64; 3],
}

impl FrameEstimate {
    /// The estimate of a pooled profile; `None` when its covariance is unknown or degenerate.
    pub fn of(p: &PooledProfile) -> Option<Self> {
        let cov_px2 = [
            p.depth_sigma_px.powi(2),
            p.depth_width_cov_px2,
            p.width_sigma_px.powi(2),
        ];
        (cov_px2.iter().all(|c| c.is_finite()) && cov_px2[0] > 0.0 && cov_px2[2] > 0.0).then_some(
            Self {
                depth_px: p.depth_px,
                width_px: p.width_px,
                cov_px2,
            },
        )
    }
}

/// A smooth-in-time prior on the width of a wrinkle over consecutive frames: w_{t+1} = w_t + η_t,
/// η_t ~ N(0, (`drift` · ŵ_t)²) (a random walk, `drift` the relative change per frame), and no
/// prior on the depth (a wrinkle deepens and relaxes within a few frames). Each frame's pooled
/// estimate (d̂, ŵ) with covariance C is a measurement; the Rauch–Tung–Striebel smoother gives
/// w̃_t from all frames of the run, and d follows by Gaussian conditioning on the frame's own
/// joint estimate, d̃ = d̂ + (C_dw / C_ww)(w̃ − ŵ). Returns, per frame, the smoothed
/// estimate with its covariance (Var d̃ = C_dd − C_dw²/C_ww + (C_dw/C_ww)² P̃_w).
pub fn smooth_in_time(frames: &[FrameEstimate], drift: f64) -> Vec<FrameEstimate> {
    let n = frames.len();
    if n == 0 {
        return Vec::new();
    }
    // forward Kalman filter on w: predicted (m⁻, P⁻) and filtered (m, P)
    let mut pred = vec![(0.0, f64::INFINITY); n];
    let mut filt = vec![(0.0, 0.0); n];
    for (t, f) in frames.iter().enumerate() {
        let r = f.cov_px2[2];
        let (m_pred, p_pred) = if t == 0 {
            (f.width_px, f64::INFINITY)
        } else {
            let (m, p) = filt[t - 1];
            (m, p + (drift * m).powi(2))
        };
        pred[t] = (m_pred, p_pred);
        filt[t] = if p_pred.is_finite() {
            let k = p_pred / (p_pred + r);
            (m_pred + k * (f.width_px - m_pred), (1.0 - k) * p_pred)
        } else {
            (f.width_px, r)
        };
    }
    // backward RTS pass
    let mut smooth = filt.clone();
    for t in (0..n - 1).rev() {
        let (m, p) = filt[t];
        let (m_next_pred, p_next_pred) = pred[t + 1];
        let g = p / p_next_pred;
        smooth[t] = (
            m + g * (smooth[t + 1].0 - m_next_pred),
            p + g * g * (smooth[t + 1].1 - p_next_pred),
        );
    }
    frames
        .iter()
        .zip(&smooth)
        .map(|(f, &(w, pw))| {
            let [cdd, cdw, cww] = f.cov_px2;
            let beta = cdw / cww;
            FrameEstimate {
                depth_px: (f.depth_px + beta * (w - f.width_px)).max(0.0),
                width_px: w,
                cov_px2: [cdd - beta * cdw + beta * beta * pw, beta * pw, pw],
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothing_a_constant_width_pools_the_frames() {
        // five frames of one width, equal variances, no drift: w̃ is the mean, its variance /5,
        // and d moves by β (w̃ − ŵ) with β = C_dw / C_ww
        let ws = [4.8, 5.3, 5.0, 4.9, 5.0];
        let frames: Vec<FrameEstimate> = ws
            .iter()
            .map(|&w| FrameEstimate {
                depth_px: 1.0,
                width_px: w,
                cov_px2: [0.01, 0.02, 0.04],
            })
            .collect();
        let out = smooth_in_time(&frames, 0.0);
        for (f, o) in frames.iter().zip(&out) {
            assert!((o.width_px - 5.0).abs() < 1e-12, "{o:?}");
            assert!((o.cov_px2[2] - 0.04 / 5.0).abs() < 1e-12);
            assert!((o.depth_px - (1.0 + 0.5 * (5.0 - f.width_px))).abs() < 1e-12);
        }
        // a large drift leaves every frame alone
        let free = smooth_in_time(&frames, 1e6);
        for (f, o) in frames.iter().zip(&free) {
            assert!((o.width_px - f.width_px).abs() < 1e-9);
        }
    }

    #[test]
    fn legendre_matches_closed_forms() {
        for t in [-1.0, -0.3, 0.0, 0.45, 1.0] {
            let p = legendre(t, 3);
            assert_eq!(p[0], 1.0);
            assert_eq!(p[1], t);
            assert!((p[2] - 0.5 * (3.0 * t * t - 1.0)).abs() < 1e-15);
            assert!((p[3] - 0.5 * (5.0 * t * t * t - 3.0 * t)).abs() < 1e-15);
        }
    }
}
