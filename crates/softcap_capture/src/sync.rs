//! Camera ↔ DAQ clock alignment `t_daq = offset_s + (1 + drift)·t_camera`: from the trigger line's
//! edges (least-squares line through the exposure mid-times), or, without a trigger line, from the
//! data (force against marker deformation, maximised normalized cross-correlation).

use serde::{Deserialize, Serialize};

/// How the clock relation was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SyncMethod {
    /// Trigger line edges sampled by the DAQ.
    Trigger,
    /// Cross-correlation of FSR force with marker deformation (drift fixed at 0).
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
    /// Residual: RMS of the line fit to the exposure mid-times (trigger), s; or 1 − correlation (data).
    pub residual: f64,
    /// Number of trigger pulses matched (trigger) or frames used (data).
    pub samples: usize,
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
    Some(ClockSync {
        method: SyncMethod::Data,
        offset_s: off,
        drift: 0.0,
        residual: 1.0 - s,
        samples: t_camera_s.len(),
    })
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
}
