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

/// How one of ln d, ln w moves between frames in the smooth-in-time prior.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TimeModel {
    /// Random walk: it changes by N(0, q²) per frame.
    Walk(f64),
    /// Integrated random walk (a local linear trend): its change per frame changes by N(0, q²)
    /// per frame, so a steady widening or narrowing is followed without lag.
    Trend(f64),
}

impl TimeModel {
    /// (process noise of the value, of its rate, whether the rate moves the value).
    fn noise(self) -> (f64, f64, f64) {
        match self {
            TimeModel::Walk(q) => (q * q, 0.0, 0.0),
            TimeModel::Trend(q) => (0.0, q * q, 1.0),
        }
    }
}

/// A smooth-in-time prior on a wrinkle's profile over consecutive frames: ln d and ln w each
/// follow a random walk or an integrated random walk ([`TimeModel`]) with relative changes per
/// frame `q = [depth, width]`. Each frame's pooled estimate (d̂, ŵ) with covariance C is a
/// measurement of (ln d, ln w) with covariance D⁻¹ C D⁻¹, D = diag(d̂, ŵ) (the d–w correlation
/// of a shallow wrinkle's fit is kept: a well-determined w corrects d); a Kalman filter and the
/// Rauch–Tung–Striebel smoother give the estimate from all frames of the run. Returns, per
/// frame, the smoothed (d, w) and covariance. The models are chosen from the data by
/// [`estimate_time_noise`].
pub fn smooth_in_time(frames: &[FrameEstimate], q: [TimeModel; 2]) -> Vec<FrameEstimate> {
    let Some(pass) = kalman_pass(frames, q) else {
        return frames.to_vec();
    };
    let n = frames.len();
    let f = transition(q);
    let mut smooth = pass.filtered.clone();
    for t in (0..n.saturating_sub(1)).rev() {
        let (m, p) = pass.filtered[t];
        let (m_pred, p_pred) = pass.predicted[t + 1];
        let Some(inv) = p_pred.try_inverse() else {
            continue;
        };
        let g = p * f.transpose() * inv;
        let (ms, ps) = smooth[t + 1];
        let cov = p + g * (ps - p_pred) * g.transpose();
        smooth[t] = (m + g * (ms - m_pred), 0.5 * (cov + cov.transpose()));
    }
    smooth
        .iter()
        .map(|(m, p)| {
            let (d, w) = (m[0].exp(), m[1].exp());
            FrameEstimate {
                depth_px: d,
                width_px: w,
                cov_px2: [p[(0, 0)] * d * d, p[(0, 1)] * d * w, p[(1, 1)] * w * w],
            }
        })
        .collect()
}

type Vec2 = nalgebra::Vector2<f64>;
type Mat2 = nalgebra::Matrix2<f64>;
type Vec4 = nalgebra::Vector4<f64>;
type Mat4 = nalgebra::Matrix4<f64>;

/// One forward Kalman pass over a run; state (ln d, ln w, their rates per frame).
struct KalmanPass {
    /// Per frame: predicted mean and covariance (frame 0: its own measurement).
    predicted: Vec<(Vec4, Mat4)>,
    /// Per frame: filtered mean and covariance.
    filtered: Vec<(Vec4, Mat4)>,
    /// ln p(y_2 … y_n | y_0, y_1, q): the marginal likelihood of the run given its first two
    /// frames (which start a trend's rate), the same data for every model.
    log_likelihood: f64,
}

/// Measurement (ln d̂, ln ŵ) and its covariance D⁻¹ C D⁻¹ of one frame.
fn log_measurement(f: &FrameEstimate) -> (Vec2, Mat2) {
    let (d, w) = (f.depth_px, f.width_px);
    let [cdd, cdw, cww] = f.cov_px2;
    (
        Vec2::new(d.ln(), w.ln()),
        Mat2::new(cdd / (d * d), cdw / (d * w), cdw / (d * w), cww / (w * w)),
    )
}

/// State transition of the models: a trend's rate moves its value.
fn transition(q: [TimeModel; 2]) -> Mat4 {
    let mut f = Mat4::identity();
    for (k, m) in q.iter().enumerate() {
        f[(k, k + 2)] = m.noise().2;
    }
    f
}

/// Prior standard deviation of a rate at the start of a run (per frame, in ln units: 100 %).
const RATE_PRIOR: f64 = 1.0;

/// The forward pass of [`smooth_in_time`]; `None` when a frame has d̂ or ŵ ≤ 0 or a singular
/// innovation covariance.
fn kalman_pass(frames: &[FrameEstimate], q: [TimeModel; 2]) -> Option<KalmanPass> {
    let f = transition(q);
    let mut process = Mat4::zeros();
    for (k, m) in q.iter().enumerate() {
        let (value, rate, _) = m.noise();
        process[(k, k)] = value;
        process[(k + 2, k + 2)] = rate;
    }
    let mut predicted = Vec::with_capacity(frames.len());
    let mut filtered: Vec<(Vec4, Mat4)> = Vec::with_capacity(frames.len());
    let mut log_likelihood = 0.0;
    for (t, fr) in frames.iter().enumerate() {
        if !(fr.depth_px > 0.0 && fr.width_px > 0.0) {
            return None;
        }
        let (y, r) = log_measurement(fr);
        let Some(&(m, p)) = filtered.last() else {
            // diffuse start: the first frame is its own estimate, the rates are unknown
            let m = Vec4::new(y.x, y.y, 0.0, 0.0);
            let mut p = Mat4::zeros();
            p.fixed_view_mut::<2, 2>(0, 0).copy_from(&r);
            p[(2, 2)] = RATE_PRIOR * RATE_PRIOR;
            p[(3, 3)] = RATE_PRIOR * RATE_PRIOR;
            predicted.push((m, p));
            filtered.push((m, p));
            continue;
        };
        let m_pred = f * m;
        let p_pred = f * p * f.transpose() + process;
        let s = p_pred.fixed_view::<2, 2>(0, 0) + r;
        let s_inv = s.try_inverse()?;
        let nu = y - m_pred.fixed_rows::<2>(0);
        if t >= 2 {
            log_likelihood -= 0.5
                * (s.determinant().max(f64::MIN_POSITIVE).ln()
                    + (nu.transpose() * s_inv * nu)[(0, 0)]
                    + 2.0 * std::f64::consts::TAU.ln());
        }
        // K = P⁻ Hᵀ S⁻¹ with H = [I 0]
        let k = p_pred.fixed_view::<4, 2>(0, 0) * s_inv;
        let mut i_kh = Mat4::identity();
        i_kh.fixed_view_mut::<4, 2>(0, 0)
            .copy_from(&(nalgebra::Matrix4x2::identity() - k));
        // Joseph form: stays symmetric positive definite
        let cov = i_kh * p_pred * i_kh.transpose() + k * r * k.transpose();
        predicted.push((m_pred, p_pred));
        filtered.push((m_pred + k * nu, 0.5 * (cov + cov.transpose())));
    }
    Some(KalmanPass {
        predicted,
        filtered,
        log_likelihood,
    })
}

/// Candidate models of [`estimate_time_noise`] for one of ln d, ln w: random walks with 0 and
/// 0.1 % … 100 % per frame, integrated random walks with 0.01 % … 10 % per frame², on log grids
/// of 10 steps per decade.
fn model_grid() -> Vec<TimeModel> {
    let walks = std::iter::once(0.0)
        .chain((0..=30u32).map(|k| 10f64.powf(-3.0 + f64::from(k) / 10.0)))
        .map(TimeModel::Walk);
    let trends = (0..=30u32)
        .map(|k| 10f64.powf(-4.0 + f64::from(k) / 10.0))
        .map(TimeModel::Trend);
    walks.chain(trends).collect()
}

/// The models of [`smooth_in_time`] for ln d and ln w that maximize the marginal likelihood of
/// the measured frames (type-II maximum likelihood, the Kalman filter's innovation likelihood
/// summed over `runs`, each run's first two frames starting it), searched over random walks and
/// integrated random walks on log grids of their noise. A wrinkle whose width is constant gets a
/// walk with q = 0 (every frame of a run shares one width), one that widens steadily a trend;
/// one whose depth jumps (appearing over a few frames) gets a large walk and its depth is left
/// to its frames. With no run of 3 frames, the result is no smoothing (walks with q = ∞).
pub fn estimate_time_noise(runs: &[Vec<FrameEstimate>]) -> [TimeModel; 2] {
    let none = [TimeModel::Walk(f64::INFINITY); 2];
    if runs.iter().all(|r| r.len() < 3) {
        return none;
    }
    let grid = model_grid();
    let mut best = (f64::NEG_INFINITY, none);
    for &qd in &grid {
        for &qw in &grid {
            let ll: Option<f64> = runs
                .iter()
                .filter(|r| r.len() >= 3)
                .map(|r| kalman_pass(r, [qd, qw]).map(|p| p.log_likelihood))
                .sum();
            if let Some(ll) = ll
                && ll > best.0
            {
                best = (ll, [qd, qw]);
            }
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames of log-space estimates (ln d, ln w) with one log covariance [r_dd, r_dw, r_ww].
    fn frames_of(logs: &[[f64; 2]], r: [f64; 3]) -> Vec<FrameEstimate> {
        logs.iter()
            .map(|&[ld, lw]| {
                let (d, w) = (ld.exp(), lw.exp());
                FrameEstimate {
                    depth_px: d,
                    width_px: w,
                    cov_px2: [r[0] * d * d, r[1] * d * w, r[2] * w * w],
                }
            })
            .collect()
    }

    #[test]
    fn smoothing_a_constant_width_pools_the_frames() {
        // five frames, equal log covariances, w constant (q_w = 0), d free: ln w̃ is the mean of
        // ln ŵ, its variance r_ww/5, and ln d moves by β (ln w̃ − ln ŵ) with β = r_dw / r_ww
        let lw = [0.1, -0.05, 0.02, 0.0, -0.07];
        let logs: Vec<[f64; 2]> = lw.iter().map(|&w| [0.3, 5f64.ln() + w]).collect();
        let r = [0.01, 0.006, 0.004];
        let frames = frames_of(&logs, r);
        let out = smooth_in_time(&frames, [TimeModel::Walk(1e6), TimeModel::Walk(0.0)]);
        let mean = 5f64.ln() + lw.iter().sum::<f64>() / 5.0;
        for (l, o) in logs.iter().zip(&out) {
            assert!((o.width_px.ln() - mean).abs() < 1e-9, "{o:?}");
            assert!((o.cov_px2[2] / (o.width_px * o.width_px) - r[2] / 5.0).abs() < 1e-9);
            let expect = l[0] + (r[1] / r[2]) * (mean - l[1]);
            assert!((o.depth_px.ln() - expect).abs() < 1e-6, "{o:?}");
        }
        // a large drift leaves every frame alone
        let free = smooth_in_time(&frames, [TimeModel::Walk(1e6); 2]);
        for (f, o) in frames.iter().zip(&free) {
            assert!((o.width_px / f.width_px - 1.0).abs() < 1e-9);
            assert!((o.depth_px / f.depth_px - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn the_time_noise_estimate_recovers_the_simulated_drift() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut normal = || {
            let u1: f64 = rng.random::<f64>().max(1e-300);
            let u2: f64 = rng.random();
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        // 4 runs of 60 frames: ln w walks with 3 % per frame, ln d is constant; measurement
        // noise 4 % (d) and 5 % (w), correlated 0.6
        let r = [0.04f64.powi(2), 0.6 * 0.04 * 0.05, 0.05f64.powi(2)];
        let (a, b) = (0.04, 0.05 * 0.8); // Cholesky factor rows: [a, 0], [0.6·σ_w, b]
        let runs: Vec<Vec<FrameEstimate>> = (0..4)
            .map(|_| {
                let mut lw = 5f64.ln();
                let logs: Vec<[f64; 2]> = (0..60)
                    .map(|_| {
                        lw += 0.03 * normal();
                        let (e1, e2) = (normal(), normal());
                        [0.7 + a * e1, lw + 0.6 * 0.05 * e1 + b * e2]
                    })
                    .collect();
                frames_of(&logs, r)
            })
            .collect();
        let [qd, qw] = estimate_time_noise(&runs);
        assert!(
            matches!(qd, TimeModel::Walk(q) if q <= 0.01)
                || matches!(qd, TimeModel::Trend(q) if q <= 0.001),
            "q_d {qd:?}"
        );
        assert!(
            matches!(qw, TimeModel::Walk(q) if (0.02..=0.045).contains(&q)),
            "q_w {qw:?}"
        );
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
