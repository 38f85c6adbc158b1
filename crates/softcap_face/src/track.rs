//! Wrinkle tracking (thesis §4.3.1) and per-cross-section shape estimation (§4.3.2).
//!
//! patch of wrinkle pixels → PCA (mean p̄, principal axis a, x_i = (p_i − p̄)ᵀa) → uniform cubic
//! B-spline valley v(x) fitted by weighted least squares (eq. 4.2) with w_i = (g_max − g_min)/(g_i − g_min)
//! → cross-sections perpendicular to v → (d, w) by Gauss–Newton on eq. 4.4 (softcap_core's
//! bounded Levenberg–Marquardt, i.e. Gauss–Newton with a trust-region safeguard).

use nalgebra::{DMatrix, Vector2};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use softcap_core::{
    BSplineFitSettings, Bounds, LeastSquaresProblem, LevenbergMarquardtSettings, SolverStatus,
    UniformCubicBSpline, fit_uniform_cubic_bspline, levenberg_marquardt,
};

use crate::cross_section::{HorizonSettings, UnitHorizons, wedge_shading};
use crate::error::{FaceError, Result};
use crate::image::RgbImage;
use crate::pooled::{PoolSettings, PooledProfile, SectionSamples, fit_pooled};

/// The valley spline v: [x0, x1] → ℝ², a uniform cubic B-spline (softcap_core
/// [`UniformCubicBSpline`]) over the PCA parameter x.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ValleySpline {
    /// Parameter range start (pixels along the PCA axis).
    pub x0: f64,
    /// Parameter range end.
    pub x1: f64,
    /// The curve.
    pub curve: UniformCubicBSpline,
}

impl ValleySpline {
    /// v(x).
    pub fn eval(&self, x: f64) -> Vector2<f64> {
        let v = self.curve.evaluate(x.clamp(self.x0, self.x1));
        Vector2::new(v[0], v[1])
    }

    /// v'(x).
    pub fn deriv(&self, x: f64) -> Vector2<f64> {
        let v = self.curve.derivative(x.clamp(self.x0, self.x1));
        Vector2::new(v[0], v[1])
    }

    /// Weighted least-squares fit (thesis eq. 4.2) of `n_control` (≥ 4) control points to
    /// points `p_i` at parameters `x_i` with weights `w_i` (softcap_core
    /// [`fit_uniform_cubic_bspline`], with a tiny second-difference term so spans without
    /// pixels stay determined).
    pub fn fit(
        xs: &[f64],
        points: &[Vector2<f64>],
        weights: &[f64],
        n_control: usize,
    ) -> Result<Self> {
        if n_control < 4 || xs.len() < n_control {
            return Err(FaceError::InvalidInput {
                what: "valley spline",
                reason: format!("{} pixels for {n_control} control points", xs.len()),
            });
        }
        let (x0, x1) = xs
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        let values: Vec<f64> = points.iter().flat_map(|p| [p.x, p.y]).collect();
        let wsum: f64 = weights.iter().sum();
        let settings = BSplineFitSettings {
            num_control_points: n_control,
            smoothing: 1e-6 * wsum / n_control as f64,
            domain: Some((x0, x1)),
        };
        let curve = fit_uniform_cubic_bspline(xs, &values, 2, Some(weights), &settings)
            .map_err(|e| FaceError::Core(e.to_string()))?;
        Ok(Self { x0, x1, curve })
    }

    /// Closest parameter to `q` (Newton on ‖q − v(x)‖² from `x_guess`, clamped to the range).
    pub fn closest(&self, q: &Vector2<f64>, x_guess: f64) -> f64 {
        let mut x = x_guess.clamp(self.x0, self.x1);
        for _ in 0..8 {
            let r = self.eval(x) - q;
            let d = self.deriv(x);
            let step = r.dot(&d) / d.norm_squared().max(1e-12);
            x = (x - step).clamp(self.x0, self.x1);
            if step.abs() < 1e-10 {
                break;
            }
        }
        x
    }
}

/// Settings of [`track_wrinkle`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackSettings {
    /// Valley-spline control points (thesis: 5–12, by wrinkle length).
    pub n_control: usize,
    /// Spacing of cross-sections along the spline (pixels).
    pub section_spacing_px: f64,
    /// Half thickness of the slab of pixels pooled into one cross-section (pixels).
    pub section_half_thickness_px: f64,
    /// Cross-sections closer than this to either spline end are skipped (pixels).
    pub end_margin_px: f64,
    /// Cross-sections whose slab holds fewer pixels than this fraction of the wrinkle's median
    /// slab are skipped: the slab is cut (an occluder in front, the end of the paint) and its
    /// pixels no longer sample the whole profile.
    pub min_slab_fraction: f64,
    /// I_obs(m): mean gray of the slab's pixels above this quantile (the unshadowed bulge).
    pub ambient_quantile: f64,
    /// Fit a scale c of the reference I_obs(m) with (d, w, p₀) (residual ratio − c·F): the
    /// quantile estimate of I_obs(m) is biased high by image noise (the top of a noisy sample),
    /// which a shallow wrinkle's small dip cannot absorb without a deeper, wider profile.
    pub fit_reference_scale: bool,
    /// σ_p: uncertainty of a sample's distance to the valley (pixels) in the effective-variance
    /// weights (0 = unweighted, the thesis's plain least squares).
    pub position_sigma_px: f64,
    /// σ_I: noise of an intensity ratio in the effective-variance weights.
    pub ratio_sigma: f64,
    /// Gauss–Newton runs, the weights re-evaluated at the previous result before each.
    pub reweight_passes: usize,
    /// Horizon search of the 2.5D model.
    pub horizon: HorizonSettings,
    /// Gauss–Newton / LM settings.
    pub solver: LevenbergMarquardtSettings,
    /// The joint fit of all sections of the wrinkle ([`crate::pooled`]), started from the
    /// per-section fits.
    pub pool: PoolSettings,
}

impl Default for TrackSettings {
    fn default() -> Self {
        Self {
            n_control: 6,
            section_spacing_px: 8.0,
            section_half_thickness_px: 3.0,
            end_margin_px: 22.0,
            min_slab_fraction: 0.75,
            ambient_quantile: 0.9,
            fit_reference_scale: true,
            position_sigma_px: 0.1,
            ratio_sigma: 0.005,
            reweight_passes: 2,
            horizon: HorizonSettings::default(),
            solver: LevenbergMarquardtSettings {
                max_iterations: 50,
                ..Default::default()
            },
            pool: PoolSettings::default(),
        }
    }
}

/// One estimated cross-section.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CrossSection {
    /// Spline parameter x.
    pub x: f64,
    /// Image position of the valley: v(x) moved by the fitted offset p₀ along the normal.
    pub valley_px: [f64; 2],
    /// Estimated depth d (pixels).
    pub depth_px: f64,
    /// Estimated width w (pixels).
    pub width_px: f64,
    /// RMS of the intensity-ratio residuals.
    pub rms: f64,
    /// Whether the solver reported convergence.
    pub converged: bool,
}

/// A tracked wrinkle: valley spline plus cross-sections.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrackedWrinkle {
    /// PCA mean p̄ (pixels).
    pub mean_px: [f64; 2],
    /// PCA principal axis a.
    pub axis: [f64; 2],
    /// The valley spline v(x).
    pub spline: ValleySpline,
    /// Cross-sections along it: with [`TrackSettings::pool`] each holds the pooled d(x), w(x)
    /// at its x and its own valley offset.
    pub sections: Vec<CrossSection>,
    /// The pooled profile (`None` when pooling is off or had too few sections).
    #[serde(default)]
    pub profile: Option<PooledProfile>,
}

/// Samples (p_k, I_obs(p_k)/I_obs(m)) of one cross-section and the eq. 4.4 residuals.
struct SectionProblem<'a> {
    p: &'a [f64],
    ratio: &'a [f64],
    horizon: HorizonSettings,
    /// Whether params[3] is the reference scale c (else c = 1).
    scale: bool,
    /// Effective-variance weights 1/√(σ_I² + (c ∂F/∂p)² σ_p²), scaled by σ_I.
    weight: Vec<f64>,
    /// Horizons of the last evaluated (w, p₀): the Jacobian is requested at the point whose
    /// residuals were just computed, and the horizon search is the expensive part.
    cache: Option<(f64, f64, Vec<UnitHorizons>)>,
}

impl SectionProblem<'_> {
    /// The unit horizons of every sample at (w, p₀), searched once per distinct (w, p₀).
    fn horizons(&mut self, w: f64, p0: f64) -> &[UnitHorizons] {
        let fresh = !matches!(&self.cache, Some((cw, cp, _)) if *cw == w && *cp == p0);
        if fresh {
            let h = self
                .p
                .iter()
                .map(|&pk| UnitHorizons::new((pk - p0) / w, &self.horizon))
                .collect();
            self.cache = Some((w, p0, h));
        }
        match &self.cache {
            Some((_, _, h)) => h,
            None => &[],
        }
    }

    /// Effective-variance weights at `params` (errors in the abscissa, Orear 1982): a sample's
    /// residual variance is σ_I² + (∂(cF)/∂p)² σ_p², with σ_p the uncertainty of its distance p
    /// to the valley. Near the valley kink F rises like √|u| (∂F/∂p → ∞), so those samples
    /// carry almost no weight: without this a handful of pixels within ~0.1 px of the valley pin
    /// p₀ between their own positions (each is a cusp of the cost in p₀) and decide (d, w).
    fn reweight(&mut self, params: &[f64], sigma_ratio: f64, sigma_p_px: f64) {
        let (d, w, p0) = (params[0], params[1], params[2]);
        let c = if self.scale { params[3] } else { 1.0 };
        for k in 0..self.p.len() {
            self.weight[k] = effective_variance_weight(
                [d, w, c],
                self.p[k] - p0,
                [sigma_ratio, sigma_p_px],
                &self.horizon,
            );
        }
    }
}

/// The effective-variance weight σ_I/√(σ_I² + (c ∂F/∂p)² σ_p²) of a sample at distance `p` from
/// the valley, for the profile `[d, w, c]` and `[σ_I, σ_p]` (see `SectionProblem::reweight`).
pub(crate) fn effective_variance_weight(
    [d, w, c]: [f64; 3],
    p: f64,
    [sigma_ratio, sigma_p_px]: [f64; 2],
    horizon: &HorizonSettings,
) -> f64 {
    // at u = 0 exactly use the one-sided slope next to the kink
    let p = if p.abs() < 1e-6 * w { 1e-6 * w } else { p };
    let h = UnitHorizons::new(p / w, horizon);
    let slope = c * wedge_shading(w, d, p, &h).d_p;
    1.0 / (1.0 + (slope * sigma_p_px / sigma_ratio).powi(2)).sqrt()
}

impl LeastSquaresProblem for SectionProblem<'_> {
    fn num_params(&self) -> usize {
        if self.scale { 4 } else { 3 }
    }
    fn num_residuals(&self) -> usize {
        self.p.len()
    }
    fn residuals(&mut self, params: &[f64], r: &mut [f64]) {
        let (d, w, p0) = (params[0], params[1], params[2]);
        let c = if self.scale { params[3] } else { 1.0 };
        let hs = self.horizons(w, p0).to_vec();
        for (k, h) in hs.iter().enumerate() {
            let p = self.p[k] - p0;
            r[k] = self.weight[k] * (self.ratio[k] - c * wedge_shading(w, d, p, h).ratio);
        }
    }
    fn jacobian(&mut self, params: &[f64], j: &mut DMatrix<f64>) -> bool {
        let (d, w, p0) = (params[0], params[1], params[2]);
        let c = if self.scale { params[3] } else { 1.0 };
        let hs = self.horizons(w, p0).to_vec();
        for (k, h) in hs.iter().enumerate() {
            let p = self.p[k] - p0;
            let s = wedge_shading(w, d, p, h);
            let wk = self.weight[k];
            j[(k, 0)] = -wk * c * s.d_depth;
            j[(k, 1)] = -wk * c * s.d_width;
            j[(k, 2)] = wk * c * s.d_p;
            if self.scale {
                j[(k, 3)] = -wk * s.ratio;
            }
        }
        true
    }
}

/// Fit (d, w) of one cross-section to intensity ratios (thesis eq. 4.4), together with a
/// sub-pixel offset p₀ of the valley from the spline (the model is evaluated at p − p₀; the
/// thesis fixes p₀ = 0, which biases w whenever the spline is a fraction of a pixel off).
/// Returns (d, w, p₀, rms, converged).
pub fn fit_cross_section(
    p: &[f64],
    ratio: &[f64],
    settings: &TrackSettings,
) -> Result<(f64, f64, f64, f64, bool)> {
    let (x, rms, converged) = fit_section(p, ratio, settings)?;
    Ok((x[0], x[1], x[2], rms, converged))
}

/// [`fit_cross_section`] returning (d, w, p₀, c), the RMS and whether it converged (c = 1 when
/// the reference scale is not fitted).
fn fit_section(
    p: &[f64],
    ratio: &[f64],
    settings: &TrackSettings,
) -> Result<([f64; 4], f64, bool)> {
    if p.len() != ratio.len() || p.len() < 4 {
        return Err(FaceError::InvalidInput {
            what: "cross-section",
            reason: format!(
                "{} positions, {} ratios (need ≥ 4 pairs)",
                p.len(),
                ratio.len()
            ),
        });
    }
    if let Some(k) = p
        .iter()
        .zip(ratio)
        .position(|(a, b)| !(a.is_finite() && b.is_finite()))
    {
        return Err(FaceError::InvalidInput {
            what: "cross-section",
            reason: format!("sample {k} is not finite"),
        });
    }
    let (a0, w0, c0) = grid_start(p, ratio, settings);
    let mut problem = SectionProblem {
        p,
        ratio,
        horizon: settings.horizon,
        scale: settings.fit_reference_scale,
        weight: vec![1.0; p.len()],
        cache: None,
    };
    let (mut lo, mut hi, mut x0) = (
        vec![0.0, 0.3, -2.0],
        vec![f64::INFINITY, f64::INFINITY, 2.0],
        vec![a0 * w0, w0, 0.0],
    );
    if settings.fit_reference_scale {
        lo.push(0.8);
        hi.push(1.2);
        x0.push(c0);
    }
    let bounds = Bounds::new(lo, hi).map_err(|e| FaceError::Core(e.to_string()))?;
    let mut start = x0;
    let mut rep = None;
    for _ in 0..settings.reweight_passes.max(1) {
        if settings.position_sigma_px > 0.0 {
            problem.reweight(&start, settings.ratio_sigma, settings.position_sigma_px);
        }
        let r = levenberg_marquardt(&mut problem, &start, Some(&bounds), &settings.solver)
            .map_err(|e| FaceError::Core(e.to_string()))?;
        start.clone_from(&r.params);
        rep = Some(r);
    }
    let Some(rep) = rep else {
        return Err(FaceError::Core("no cross-section fit pass ran".into()));
    };
    // unweighted RMS of the ratio residuals
    problem.weight.fill(1.0);
    let mut res = vec![0.0; p.len()];
    problem.residuals(&rep.params, &mut res);
    let rms = (res.iter().map(|r| r * r).sum::<f64>() / p.len() as f64).sqrt();
    let c = rep.params.get(3).copied().unwrap_or(1.0);
    Ok((
        [rep.params[0], rep.params[1], rep.params[2], c],
        rms,
        matches!(rep.status, SolverStatus::Converged { .. }),
    ))
}

/// Global start of the eq. 4.4 fit: the cost over (d, w, p₀, c) has spurious local minima —
/// the model F(a, u) is not differentiable at the valley kink (u = 0: F jumps from
/// cos(atan 2a) to 1/(1 + 4a²) and rises like √u), so a Gauss–Newton run from a poor start
/// (the old half-depth-width guess gave w = 1 px for a shallow d/w = 0.4 wrinkle) stops on a
/// cusp with 10–50× the cost of the true profile and w biased 3–30 % high. The start is the best
/// point of a log grid in w × a linear grid in a = d/w at p₀ = 0, with the reference scale c in
/// closed form (c = Σ r F / Σ F², clamped to its bounds). The horizons depend on u = p/w only
/// (module docs of [`crate::cross_section`]), so they are searched once per (w, sample) on a
/// coarse grid and reused for every a. Returns (a, w, c).
fn grid_start(p: &[f64], ratio: &[f64], settings: &TrackSettings) -> (f64, f64, f64) {
    const N_W: usize = 28;
    const N_A: usize = 36;
    const A_MAX: f64 = 3.5;
    // (only the grid search has a resolution to coarsen; the analytic search is exact)
    let coarse = HorizonSettings {
        range_w: settings.horizon.range_w.min(10.0),
        step_w: settings.horizon.step_w.max(0.1),
        ..settings.horizon
    };
    let p_max = p.iter().fold(0.0f64, |m, &x| m.max(x.abs()));
    let (w_lo, w_hi) = (0.5f64, (p_max / 1.5).max(1.0));
    let mut best = (f64::INFINITY, 0.0, 1.0, 1.0);
    let mut model = vec![0.0; p.len()];
    for iw in 0..N_W {
        let w = w_lo * (w_hi / w_lo).powf(iw as f64 / (N_W - 1) as f64);
        let horizons: Vec<UnitHorizons> = p
            .iter()
            .map(|&pk| UnitHorizons::new(pk / w, &coarse))
            .collect();
        for ia in 1..=N_A {
            let a = A_MAX * ia as f64 / N_A as f64;
            for (k, (&pk, h)) in p.iter().zip(&horizons).enumerate() {
                model[k] = wedge_shading(w, a * w, pk, h).ratio;
            }
            let c = if settings.fit_reference_scale {
                let (num, den) = model
                    .iter()
                    .zip(ratio)
                    .fold((0.0, 0.0), |(n, d), (f, r)| (n + f * r, d + f * f));
                if den > 0.0 {
                    (num / den).clamp(0.8, 1.2)
                } else {
                    1.0
                }
            } else {
                1.0
            };
            let cost: f64 = model
                .iter()
                .zip(ratio)
                .map(|(f, r)| (r - c * f).powi(2))
                .sum();
            if cost < best.0 {
                best = (cost, a, w, c);
            }
        }
    }
    (best.1, best.2, best.3)
}

/// Track one wrinkle patch (pixel indices into `image`): PCA, weighted valley spline,
/// cross-section fits.
pub fn track_wrinkle(
    image: &RgbImage,
    patch: &[usize],
    settings: &TrackSettings,
) -> Result<TrackedWrinkle> {
    if patch.len() < 3 * settings.n_control {
        return Err(FaceError::InvalidInput {
            what: "wrinkle patch",
            reason: format!("{} pixels", patch.len()),
        });
    }
    if let Some(&i) = patch.iter().find(|&&i| i >= image.data.len()) {
        return Err(FaceError::InvalidInput {
            what: "wrinkle patch",
            reason: format!(
                "pixel {i} outside the {}×{} image",
                image.width,
                image.data.len() / image.width.max(1)
            ),
        });
    }
    let pts: Vec<Vector2<f64>> = patch
        .iter()
        .map(|&i| Vector2::new((i % image.width) as f64, (i / image.width) as f64))
        .collect();
    let gray: Vec<f64> = patch.iter().map(|&i| image.gray(i)).collect();
    // PCA of the patch.
    let mean = pts.iter().sum::<Vector2<f64>>() / pts.len() as f64;
    let mut cov = nalgebra::Matrix2::<f64>::zeros();
    for q in &pts {
        cov += (q - mean) * (q - mean).transpose();
    }
    let eig = cov.symmetric_eigen();
    let k = if eig.eigenvalues[0] >= eig.eigenvalues[1] {
        0
    } else {
        1
    };
    let mut axis: Vector2<f64> = eig.eigenvectors.column(k).into_owned();
    if axis.x < 0.0 || (axis.x == 0.0 && axis.y < 0.0) {
        axis = -axis;
    }
    let xs: Vec<f64> = pts.iter().map(|q| (q - mean).dot(&axis)).collect();
    // Valley weights w_i = (g_max − g_min)/(g_i − g_min) (eq. 4.2), floored to stay finite.
    let (gmin, gmax) = gray
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &g| {
            (a.min(g), b.max(g))
        });
    let span = (gmax - gmin).max(1e-12);
    let weights: Vec<f64> = gray
        .iter()
        .map(|&g| span / (g - gmin).max(0.02 * span))
        .collect();
    let spline = ValleySpline::fit(&xs, &pts, &weights, settings.n_control)?;
    // Signed distance p and spline parameter of every patch pixel.
    let mut coords = Vec::with_capacity(pts.len());
    for (q, &x) in pts.iter().zip(&xs) {
        let xc = spline.closest(q, x);
        let t = spline.deriv(xc).normalize();
        let n = Vector2::new(-t.y, t.x);
        coords.push((xc, (q - spline.eval(xc)).dot(&n)));
    }
    // The slabs of every cross-section (sequential, cheap), then the eq. 4.4 fits in parallel:
    // each fit depends on its own slab only and rayon's ordered collect keeps the section order,
    // so the result does not depend on the thread count.
    let mut slabs = Vec::new();
    let mut x = spline.x0 + settings.end_margin_px;
    while x <= spline.x1 - settings.end_margin_px {
        let mut ps = Vec::new();
        let mut gs = Vec::new();
        for (k, &(xc, p)) in coords.iter().enumerate() {
            if (xc - x).abs() <= settings.section_half_thickness_px
                && xc > spline.x0
                && xc < spline.x1
            {
                ps.push(p);
                gs.push(gray[k]);
            }
        }
        if ps.len() >= 8 {
            let mut sorted = gs.clone();
            sorted.sort_by(f64::total_cmp);
            let from = ((sorted.len() as f64 - 1.0) * settings.ambient_quantile) as usize;
            let top = &sorted[from..];
            let i_m = top.iter().sum::<f64>() / top.len() as f64;
            let ratio: Vec<f64> = gs.iter().map(|g| g / i_m).collect();
            slabs.push((x, ps, ratio));
        }
        x += settings.section_spacing_px;
    }
    let mut counts: Vec<usize> = slabs.iter().map(|(_, ps, _)| ps.len()).collect();
    counts.sort_unstable();
    let full = counts.get(counts.len() / 2).copied().unwrap_or(0) as f64;
    slabs.retain(|(_, ps, _)| ps.len() as f64 >= settings.min_slab_fraction * full);
    let fits = slabs
        .par_iter()
        .map(|(_, ps, ratio)| fit_section(ps, ratio, settings))
        .collect::<Result<Vec<_>>>()?;
    let valley = |x: f64, p0: f64| {
        let t = spline.deriv(x).normalize();
        let v = spline.eval(x) + p0 * Vector2::new(-t.y, t.x);
        [v.x, v.y]
    };
    let mut sections: Vec<CrossSection> = slabs
        .iter()
        .zip(&fits)
        .map(|((x, _, _), (q, rms, converged))| CrossSection {
            x: *x,
            valley_px: valley(*x, q[2]),
            depth_px: q[0],
            width_px: q[1],
            rms: *rms,
            converged: *converged,
        })
        .collect();
    let profile = pool_sections(&slabs, &fits, settings).map(|pooled| {
        for (s, [d, w, p0]) in sections.iter_mut().zip(&pooled.sections) {
            s.depth_px = *d;
            s.width_px = *w;
            s.valley_px = valley(s.x, *p0);
            s.converged = pooled.profile.converged;
        }
        pooled.profile
    });
    Ok(TrackedWrinkle {
        mean_px: [mean.x, mean.y],
        axis: [axis.x, axis.y],
        spline,
        sections,
        profile,
    })
}

/// The pooled fit ([`crate::pooled`]) of a wrinkle's sections from their own fits, when
/// [`TrackSettings::pool`] asks for it and there are enough sections (≥ 2 and > degree); `None`
/// also when the joint problem is invalid (the per-section fits stand then).
fn pool_sections(
    slabs: &[(f64, Vec<f64>, Vec<f64>)],
    fits: &[([f64; 4], f64, bool)],
    settings: &TrackSettings,
) -> Option<crate::pooled::PooledFit> {
    let pool = &settings.pool;
    if !pool.enabled || slabs.len() < 2 || slabs.len() <= pool.degree {
        return None;
    }
    let samples: Vec<SectionSamples> = slabs
        .iter()
        .zip(fits)
        .map(|((x, p, ratio), (q, _, _))| SectionSamples {
            x: *x,
            p: p.clone(),
            ratio: ratio.clone(),
            start: *q,
        })
        .collect();
    fit_pooled(
        &samples,
        pool,
        settings.fit_reference_scale,
        settings.ratio_sigma,
        settings.position_sigma_px,
        settings.reweight_passes,
        &settings.horizon,
    )
    .ok()
}
