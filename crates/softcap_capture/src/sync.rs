//! Camera ↔ DAQ clock alignment `t_daq = offset_s + (1 + drift)·t_camera`: from the trigger line's
//! edges (least-squares line through the exposure mid-times), or, without a trigger line, from the
//! data: a camera-side signal (probe depth below the rest surface, or marker deformation) against
//! the DAQ force — first the offset maximising their normalized correlation, then offset and drift
//! refined by least squares on the force model `F(t_daq,k) ≈ a + b·d_k` ([`refine_sync_least_squares`]).

use serde::{Deserialize, Serialize};

/// How the clock relation was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SyncMethod {
    /// Trigger line edges sampled by the DAQ.
    Trigger,
    /// From the data: correlation of force with probe depth (or marker deformation), refined by
    /// least squares on offset and drift.
    Data,
}

/// Estimated clock relation and its quality.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ClockSync {
    /// Method.
    pub method: SyncMethod,
    /// Offset, s.
    pub offset_s: f64,
    /// Relative drift (dimensionless).
    pub drift: f64,
    /// Residual, s: RMS of the line fit to the exposure mid-times (trigger); for data, the RMS
    /// force residual of the least-squares fit divided by the RMS force rate `|dF/dt|` at the
    /// frames (the timing error that would explain it).
    pub residual: f64,
    /// Number of trigger pulses matched (trigger) or frames used (data).
    pub samples: usize,
    /// Data sync only: RMS force residual of `F(t_daq,k) − (a + b·d_k)`, N (NaN for trigger).
    pub residual_force_n: f64,
    /// Data sync only: normalized correlation of force and signal at the estimate (NaN for trigger).
    pub correlation: f64,
}

impl ClockSync {
    /// DAQ time of a camera time.
    pub fn to_daq(&self, t_camera_s: f64) -> f64 {
        self.offset_s + (1.0 + self.drift) * t_camera_s
    }
}

/// Exposure pulses on the trigger line: threshold halfway between the low and high levels
/// (5th/99.5th percentiles), edges located by linear interpolation of the crossing; returns the
/// mid-time of each complete pulse.
pub fn trigger_pulses(t_daq_s: &[f64], trigger_v: &[f64]) -> Vec<f64> {
    let mut sorted: Vec<f64> = trigger_v.to_vec();
    sorted.sort_by(f64::total_cmp);
    if sorted.is_empty() {
        return Vec::new();
    }
    // Exposures are short against the frame period: the line is low most of the time, so the low
    // level is a low percentile and the high level a very high one.
    let lo = sorted[sorted.len() / 20];
    let hi = sorted[sorted.len() - 1 - sorted.len() / 200];
    if hi - lo < 1e-6 {
        return Vec::new();
    }
    let thr = 0.5 * (lo + hi);
    let cross = |i: usize| {
        let (v0, v1) = (trigger_v[i - 1], trigger_v[i]);
        let a = ((thr - v0) / (v1 - v0)).clamp(0.0, 1.0);
        t_daq_s[i - 1] + a * (t_daq_s[i] - t_daq_s[i - 1])
    };
    let mut out = Vec::new();
    let mut rise: Option<f64> = None;
    for i in 1..trigger_v.len() {
        let (was, is) = (trigger_v[i - 1] > thr, trigger_v[i] > thr);
        if !was && is {
            rise = Some(cross(i));
        } else if was
            && !is
            && let Some(r) = rise.take()
        {
            out.push(0.5 * (r + cross(i)));
        }
    }
    out
}

/// Least-squares line `t_daq = offset + (1 + drift)·t_camera` through matched pulse mid-times.
/// Pulses are matched to frames in order; with more pulses than frames, the run of consecutive
/// pulses with the smallest residual is used. `None` with fewer than two pulses.
pub fn sync_from_trigger(t_camera_s: &[f64], pulses_daq_s: &[f64]) -> Option<ClockSync> {
    let n = t_camera_s.len();
    if n < 2 || pulses_daq_s.len() < n {
        return None;
    }
    let mut best: Option<ClockSync> = None;
    for start in 0..=pulses_daq_s.len() - n {
        let y = &pulses_daq_s[start..start + n];
        let mx = t_camera_s.iter().sum::<f64>() / n as f64;
        let my = y.iter().sum::<f64>() / n as f64;
        let sxy: f64 = t_camera_s
            .iter()
            .zip(y)
            .map(|(x, y)| (x - mx) * (y - my))
            .sum();
        let sxx: f64 = t_camera_s.iter().map(|x| (x - mx).powi(2)).sum();
        if sxx <= 0.0 {
            return None;
        }
        let b = sxy / sxx;
        let a = my - b * mx;
        let rms = (t_camera_s
            .iter()
            .zip(y)
            .map(|(x, y)| (a + b * x - y).powi(2))
            .sum::<f64>()
            / n as f64)
            .sqrt();
        if best.is_none_or(|s| rms < s.residual) {
            best = Some(ClockSync {
                method: SyncMethod::Trigger,
                offset_s: a,
                drift: b - 1.0,
                residual: rms,
                samples: n,
                residual_force_n: f64::NAN,
                correlation: f64::NAN,
            });
        }
    }
    best
}

/// Linear interpolation of samples `(t, y)` at time `t`, clamped at the ends.
pub fn interpolate(t: &[f64], y: &[f64], at: f64) -> f64 {
    if at <= t[0] {
        return y[0];
    }
    if at >= t[t.len() - 1] {
        return y[y.len() - 1];
    }
    let i = t.partition_point(|&x| x <= at) - 1;
    let a = (at - t[i]) / (t[i + 1] - t[i]);
    y[i] + a * (y[i + 1] - y[i])
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    if saa <= 0.0 || sbb <= 0.0 {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}

/// Clock offset from the data: maximises the normalized correlation between the DAQ signal
/// `force(offset + t_k)` and the camera-side signal `deformation_k` over offsets covering every
/// placement of the frames inside the DAQ record (grid at `step_s`, then golden-section refinement).
/// Drift is not observable this way at these durations and is fixed at 0.
pub fn sync_from_data(
    t_camera_s: &[f64],
    deformation: &[f64],
    t_daq_s: &[f64],
    force: &[f64],
    step_s: f64,
) -> Option<ClockSync> {
    if t_camera_s.len() < 3 || t_daq_s.len() < 2 {
        return None;
    }
    let span_cam = t_camera_s[t_camera_s.len() - 1] - t_camera_s[0];
    let lo = t_daq_s[0] - t_camera_s[0];
    let hi = t_daq_s[t_daq_s.len() - 1] - t_camera_s[0] - span_cam;
    if hi < lo {
        return None;
    }
    let score = |off: f64| {
        let f: Vec<f64> = t_camera_s
            .iter()
            .map(|t| interpolate(t_daq_s, force, off + t))
            .collect();
        correlation(&f, deformation)
    };
    let steps = ((hi - lo) / step_s).ceil() as usize;
    let (mut best_off, mut best) = (lo, f64::NEG_INFINITY);
    for k in 0..=steps {
        let off = lo + k as f64 * step_s;
        let s = score(off);
        if s > best {
            best = s;
            best_off = off;
        }
    }
    let (mut a, mut b) = (best_off - step_s, best_off + step_s);
    let g = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..60 {
        let (c, d) = (b - g * (b - a), a + g * (b - a));
        if score(c) > score(d) { b = d } else { a = c }
    }
    let off = 0.5 * (a + b);
    let s = score(off);
    let fit = ForceModelFit::new(t_camera_s, deformation, t_daq_s, force, None);
    let (residual_force_n, residual_s) = fit.residuals_at(off, 0.0);
    Some(ClockSync {
        method: SyncMethod::Data,
        offset_s: off,
        drift: 0.0,
        residual: residual_s,
        samples: t_camera_s.len(),
        residual_force_n,
        correlation: s,
    })
}

/// The least-squares problem of [`refine_sync_least_squares`]: parameters
/// `[c, drift, a, b_0 … b_{L−1}]` with `t_daq,k = c + (1 + drift)(t_k − t̄)` (centred, so `c` and
/// `drift` are uncorrelated), residuals `r_k = a + b_{g(k)}·d_k − F(t_daq,k)` where `g(k)` is the
/// frame's group (one slope per probe location: the object's stiffness differs between them).
struct ForceModelFit<'a> {
    t_camera_s: &'a [f64],
    signal: &'a [f64],
    t_daq_s: &'a [f64],
    force: &'a [f64],
    /// Slope group of each frame.
    group: Vec<usize>,
    groups: usize,
    t_mean: f64,
    /// Half-width of the central difference of F, s (one DAQ sample interval).
    h_s: f64,
}

impl<'a> ForceModelFit<'a> {
    fn new(
        t_camera_s: &'a [f64],
        signal: &'a [f64],
        t_daq_s: &'a [f64],
        force: &'a [f64],
        group: Option<&[usize]>,
    ) -> Self {
        let group = match group {
            Some(g) if g.len() == signal.len() => g.to_vec(),
            _ => vec![0; signal.len()],
        };
        let groups = group.iter().max().map_or(1, |g| g + 1);
        let mut dt: Vec<f64> = t_daq_s.windows(2).map(|w| w[1] - w[0]).collect();
        dt.sort_by(f64::total_cmp);
        ForceModelFit {
            t_camera_s,
            signal,
            t_daq_s,
            force,
            group,
            groups,
            t_mean: t_camera_s.iter().sum::<f64>() / t_camera_s.len() as f64,
            h_s: dt.get(dt.len() / 2).copied().unwrap_or(1e-3),
        }
    }

    fn tau(&self, c: f64, drift: f64, k: usize) -> f64 {
        c + (1.0 + drift) * (self.t_camera_s[k] - self.t_mean)
    }

    fn force_at(&self, t: f64) -> f64 {
        interpolate(self.t_daq_s, self.force, t)
    }

    fn force_rate(&self, t: f64) -> f64 {
        (self.force_at(t + self.h_s) - self.force_at(t - self.h_s)) / (2.0 * self.h_s)
    }

    /// Best `[a, b_0 …]` for a clock: linear least squares of `F(τ_k)` on `(1, d_k e_{g(k)})`.
    fn linear_fit(&self, c: f64, drift: f64) -> Vec<f64> {
        let n = 1 + self.groups;
        let mut ata = nalgebra::DMatrix::<f64>::zeros(n, n);
        let mut atf = nalgebra::DVector::<f64>::zeros(n);
        for k in 0..self.signal.len() {
            let f = self.force_at(self.tau(c, drift, k));
            let mut row = nalgebra::DVector::<f64>::zeros(n);
            row[0] = 1.0;
            row[1 + self.group[k]] = self.signal[k];
            ata += &row * row.transpose();
            atf += &row * f;
        }
        // A slope group whose signal is all zero gets a zero slope (tiny ridge keeps it regular).
        for i in 0..n {
            ata[(i, i)] += 1e-12 * (1.0 + ata[(i, i)]);
        }
        ata.cholesky()
            .map(|ch| ch.solve(&atf).iter().copied().collect())
            .unwrap_or_else(|| vec![0.0; n])
    }

    fn model(&self, lin: &[f64], k: usize) -> f64 {
        lin[0] + lin[1 + self.group[k]] * self.signal[k]
    }

    /// `(RMS force residual (N), time-equivalent residual (s))` at a clock given as
    /// `t_daq = offset + (1 + drift)·t_camera`, with the best `(a, b)` for it.
    fn residuals_at(&self, offset_s: f64, drift: f64) -> (f64, f64) {
        let c = offset_s + (1.0 + drift) * self.t_mean;
        let lin = self.linear_fit(c, drift);
        let (mut s2, mut rate2) = (0.0, 0.0);
        for k in 0..self.signal.len() {
            let t = self.tau(c, drift, k);
            s2 += (self.model(&lin, k) - self.force_at(t)).powi(2);
            rate2 += self.force_rate(t).powi(2);
        }
        let n = self.signal.len() as f64;
        let rms = (s2 / n).sqrt();
        let rate = (rate2 / n).sqrt();
        (rms, if rate > 0.0 { rms / rate } else { f64::NAN })
    }
}

impl softcap_core::LeastSquaresProblem for ForceModelFit<'_> {
    fn num_params(&self) -> usize {
        3 + self.groups
    }

    fn num_residuals(&self) -> usize {
        self.signal.len()
    }

    fn residuals(&mut self, p: &[f64], r: &mut [f64]) {
        for (k, r) in r.iter_mut().enumerate() {
            *r = self.model(&p[2..], k) - self.force_at(self.tau(p[0], p[1], k));
        }
    }

    /// `∂r_k/∂c = −F'(τ_k)`, `∂r_k/∂drift = −F'(τ_k)(t_k − t̄)`, `∂r_k/∂a = 1`, `∂r_k/∂b_{g(k)} = d_k`,
    /// with F' the central difference of the interpolated force over one DAQ interval.
    fn jacobian(&mut self, p: &[f64], j: &mut nalgebra::DMatrix<f64>) -> bool {
        for k in 0..self.signal.len() {
            let rate = self.force_rate(self.tau(p[0], p[1], k));
            j[(k, 0)] = -rate;
            j[(k, 1)] = -rate * (self.t_camera_s[k] - self.t_mean);
            j[(k, 2)] = 1.0;
            j[(k, 3 + self.group[k])] = self.signal[k];
        }
        true
    }
}

/// Refines a data-driven clock estimate by least squares over offset and drift together with the
/// linear force model `F(t_daq,k) ≈ a + b_{g(k)}·d_k` with one slope per group `g` (probe
/// location; `None`: one group), the drift bounded by `|drift| ≤ max_drift` (a clock crystal's
/// tolerance; drift is weakly observable over a short take, and unbounded it absorbs model
/// error between probe locations) (Levenberg–Marquardt, `softcap_core`), starting
/// from `initial` (e.g. [`sync_from_data`]'s correlation maximum). Returns the refined estimate
/// with its residuals, or `initial` when the refinement fails or does not lower the residual.
pub fn refine_sync_least_squares(
    t_camera_s: &[f64],
    signal: &[f64],
    t_daq_s: &[f64],
    force: &[f64],
    groups: Option<&[usize]>,
    max_drift: f64,
    initial: &ClockSync,
) -> ClockSync {
    if t_camera_s.len() < 5 {
        return *initial;
    }
    let mut fit = ForceModelFit::new(t_camera_s, signal, t_daq_s, force, groups);
    let c0 = initial.offset_s + (1.0 + initial.drift) * fit.t_mean;
    let mut p0 = vec![c0, initial.drift];
    p0[1] = p0[1].clamp(-max_drift, max_drift);
    p0.extend(fit.linear_fit(c0, p0[1]));
    let mut lower = vec![f64::NEG_INFINITY; p0.len()];
    let mut upper = vec![f64::INFINITY; p0.len()];
    (lower[1], upper[1]) = (-max_drift, max_drift);
    let Ok(bounds) = softcap_core::Bounds::new(lower, upper) else {
        return *initial;
    };
    let settings = softcap_core::LevenbergMarquardtSettings {
        max_iterations: 100,
        ..Default::default()
    };
    let Ok(report) = softcap_core::levenberg_marquardt(&mut fit, &p0, Some(&bounds), &settings)
    else {
        return *initial;
    };
    let p = &report.params;
    if !p.iter().all(|v| v.is_finite()) {
        return *initial;
    }
    let offset_s = p[0] - (1.0 + p[1]) * fit.t_mean;
    let (residual_force_n, residual) = fit.residuals_at(offset_s, p[1]);
    if residual_force_n.is_nan() || residual_force_n > initial.residual_force_n {
        return *initial;
    }
    let corr_signal: Vec<f64> = (0..t_camera_s.len())
        .map(|k| fit.force_at(fit.tau(p[0], p[1], k)))
        .collect();
    ClockSync {
        method: SyncMethod::Data,
        offset_s,
        drift: p[1],
        residual,
        samples: t_camera_s.len(),
        residual_force_n,
        correlation: correlation(&corr_signal, signal),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trigger_line_recovers_offset_and_drift() {
        let (offset, drift) = (2.5, -4e-5);
        let cams: Vec<f64> = (0..30).map(|k| 0.3 + 0.1 * k as f64).collect();
        let dt = 0.001;
        let t: Vec<f64> = (0..6000).map(|i| i as f64 * dt).collect();
        let v: Vec<f64> = t
            .iter()
            .map(|&td| {
                let on = cams
                    .iter()
                    .any(|&tc| (td - (offset + (1.0 + drift) * tc)).abs() <= 0.005);
                if on { 5.0 } else { 0.0 }
            })
            .collect();
        let pulses = trigger_pulses(&t, &v);
        assert_eq!(pulses.len(), 30);
        let s = sync_from_trigger(&cams, &pulses).unwrap();
        assert!(
            (s.offset_s - offset).abs() < 1e-3 && (s.drift - drift).abs() < 5e-4,
            "{s:?}"
        );
    }

    #[test]
    fn data_sync_finds_a_known_lag() {
        let cams: Vec<f64> = (0..40).map(|k| 0.1 * k as f64).collect();
        let signal = |t: f64| {
            (-(t - 1.7f64).powi(2) / 0.1).exp() + 0.5 * (-(t - 3.1f64).powi(2) / 0.05).exp()
        };
        let t: Vec<f64> = (0..2000).map(|i| 1.0 + i as f64 * 0.005).collect();
        let offset = 2.3456;
        let f: Vec<f64> = t.iter().map(|&td| signal(td - offset)).collect();
        let d: Vec<f64> = cams.iter().map(|&tc| 3.0 * signal(tc)).collect();
        let s = sync_from_data(&cams, &d, &t, &f, 0.005).unwrap();
        assert!((s.offset_s - offset).abs() < 1e-3, "{s:?}");
    }

    #[test]
    fn least_squares_refines_offset_and_drift_with_one_slope_per_press() {
        // Two presses (trapezoids in depth) with different stiffness; force = k_j · depth on the
        // DAQ clock t_daq = offset + (1 + drift) t_camera.
        let (offset, drift) = (1.2345, 6e-5);
        let depth = |t: f64| {
            let press =
                |t0: f64| ((t - t0) / 0.6).clamp(0.0, 1.0) - ((t - t0 - 0.9) / 0.3).clamp(0.0, 1.0);
            (2.0 * press(0.5), 2.2 * press(2.5))
        };
        let cams: Vec<f64> = (0..45).map(|k| 0.1 * k as f64 + 0.05).collect();
        let signal: Vec<f64> = cams
            .iter()
            .map(|&t| {
                let (a, b) = depth(t);
                a + b
            })
            .collect();
        let t_daq: Vec<f64> = (0..1200).map(|i| offset + 0.005 * i as f64 - 0.5).collect();
        let force: Vec<f64> = t_daq
            .iter()
            .map(|&td| {
                let (a, b) = depth((td - offset) / (1.0 + drift));
                0.7 * a + 0.9 * b
            })
            .collect();
        let groups = vec![0; cams.len()]
            .iter()
            .zip(&cams)
            .map(|(_, &t)| usize::from(t > 2.0))
            .collect::<Vec<_>>();
        let initial = sync_from_data(&cams, &signal, &t_daq, &force, 0.005).unwrap();
        let refined = refine_sync_least_squares(
            &cams,
            &signal,
            &t_daq,
            &force,
            Some(&groups),
            1e-4,
            &initial,
        );
        assert!(
            (refined.offset_s - offset).abs() < 3e-4,
            "initial {initial:?} refined {refined:?}"
        );
        assert!(refined.residual_force_n <= initial.residual_force_n);
        assert!(refined.residual_force_n < 0.01, "{refined:?}");
    }
}
