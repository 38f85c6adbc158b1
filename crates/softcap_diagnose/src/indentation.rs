//! The force channel against the indentation: the force the default model needs to reach the
//! measured tip depth, compared with the force sensor's reading, leave-one-location-out.
//!
//! The diagnosis drives the default model with the measured force (bickel2009 §4.1) and scores
//! the markers. An effect of the force channel itself (a sensor that lags and loops behind the
//! force, `crate::hypotheses::sensor_lag`) moves the markers only as far as the force error
//! moves the surface, which away from the tip can sit at the marker noise; but the probe's tip
//! is tracked too, and where it presses the model's force–indentation relation is sharp. Per
//! contact frame k (axis a_k, reading f_k = F_k · a_k) the baseline solve gives the model's load
//! point x_P,k under the reading and its axial compliance c_k = a_kᵀ (∂x_P/∂f) a_k
//! ([`crate::sim::LoadPoint`]), so the force the model needs for the measured tip position p_k is,
//! to first order about that solve,
//!
//!   y_k = max(0, f_k + (p_k − x_P,k) · a_k / c_k)
//!
//! (a tip off the surface needs no force: the contact cannot pull).
//!
//! Without an effect of the channel, y ≈ a f + o/c (a: the material's overall stiffness the
//! tissue fit may have missed; o: a constant offset of the tip along the axis, a tip-length
//! calibration) — the **nuisance** every force-channel extension must beat. An extension adds
//! columns (a lagging sensor: y ≈ a f + τ ḟ + h sgn(ḟ) f, the FSR chain to first order) or
//! replaces f by a corrected force; [`heldout_fit`] fits them on the other locations and scores
//! the held-out one, as the marker screen does.
//!
//! **Noise model.** y is noisy through the tracked tip (p_k / c_k) and the reading; its σ comes
//! from the data: the median absolute second difference of y over consecutive contact frames of
//! one location (robust to the few frames where the press turns), σ = 1.4826 · med|Δ²y| / √6 —
//! the same estimator as the marker noise, on the force channel.

use crate::baseline::Prepared;
use crate::recording::Recording;
use crate::screen::{bounded_least_squares, rss};
use crate::segment::Segmentation;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// The force channel's observations (module docs).
#[derive(Clone, Debug)]
pub struct ForceObservations {
    /// Axial reading f_k per frame, N.
    pub reading_n: Vec<f64>,
    /// The force the default model needs for the measured tip position, y_k, per frame, N
    /// (`None` where it is not observed: out of contact, outside the location folds).
    pub model_n: Vec<Option<f64>>,
    /// Axial stiffness 1/c_k of the model's load point per frame, N/m (0 where not observed).
    pub stiffness_n_per_m: Vec<f64>,
    /// Noise σ of y, N (module docs).
    pub noise_n: f64,
}

impl ForceObservations {
    /// The observations of `rec` against the baseline `p`.
    pub fn new(rec: &Recording, seg: &Segmentation, p: &Prepared) -> Self {
        let nt = rec.frames.len();
        let reading_n: Vec<f64> = rec.frames.iter().map(|f| f.force_n.dot(&f.axis)).collect();
        let mut model_n = vec![None; nt];
        let mut stiffness_n_per_m = vec![0.0; nt];
        for (k, f) in rec.frames.iter().enumerate() {
            if seg.fold_of_frame[k].is_none() || !seg.phases[k].in_contact() {
                continue;
            }
            let Some(Some(lp)) = p.load_point.get(k) else {
                continue;
            };
            let Some(r) = lp.response_m_per_n else {
                continue;
            };
            let a = f.axis;
            let c = a.dot(&(r[0] * a.x + r[1] * a.y + r[2] * a.z));
            if c.is_nan() || c <= 0.0 {
                continue;
            }
            // a tip off the surface needs no force (the contact cannot pull)
            model_n[k] = Some((reading_n[k] + (f.tip_m - lp.position_m).dot(&a) / c).max(0.0));
            stiffness_n_per_m[k] = 1.0 / c;
        }
        let noise_n = noise_sigma(seg, &model_n);
        Self {
            reading_n,
            model_n,
            stiffness_n_per_m,
            noise_n,
        }
    }

    /// The observed frames of location fold `l`.
    fn frames_of(&self, seg: &Segmentation, l: usize) -> impl Iterator<Item = usize> + '_ {
        let folds = seg.fold_of_frame.clone();
        (0..self.model_n.len()).filter(move |&k| folds[k] == Some(l) && self.model_n[k].is_some())
    }

    /// The nuisance columns (a f, o / c) at every frame.
    pub fn nuisance(&self) -> Vec<Column> {
        vec![
            Column::free("force_scale", self.reading_n.clone()),
            Column::free("tip_offset_m", self.stiffness_n_per_m.clone()),
        ]
    }
}

/// σ = 1.4826 · med|Δ²y| / √6 over the triples of consecutive observed frames of one location.
fn noise_sigma(seg: &Segmentation, y: &[Option<f64>]) -> f64 {
    let mut d2: Vec<f64> = (1..y.len().saturating_sub(1))
        .filter(|&k| {
            seg.fold_of_frame[k].is_some()
                && seg.fold_of_frame[k - 1] == seg.fold_of_frame[k]
                && seg.fold_of_frame[k + 1] == seg.fold_of_frame[k]
        })
        .filter_map(|k| match (y[k - 1], y[k], y[k + 1]) {
            (Some(a), Some(b), Some(c)) => Some((a - 2.0 * b + c).abs()),
            _ => None,
        })
        .collect();
    if d2.is_empty() {
        return 0.0;
    }
    d2.sort_by(f64::total_cmp);
    let med = d2[d2.len() / 2];
    1.4826 * med / 6f64.sqrt()
}

/// One regressor of y: its values per frame and whether its coefficient must be ≥ 0.
#[derive(Clone, Debug)]
pub struct Column {
    /// Parameter name.
    pub name: &'static str,
    /// Coefficient ≥ 0.
    pub nonneg: bool,
    /// Value per frame.
    pub values: Vec<f64>,
}

impl Column {
    /// A column with a free coefficient.
    pub fn free(name: &'static str, values: Vec<f64>) -> Self {
        Self {
            name,
            nonneg: false,
            values,
        }
    }

    /// A column whose coefficient is ≥ 0.
    pub fn nonneg(name: &'static str, values: Vec<f64>) -> Self {
        Self {
            name,
            nonneg: true,
            values,
        }
    }
}

/// The held-out force error of a force-channel model (JSON `evidence.force_channel`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ForceScore {
    /// Held-out RMS of y against the nuisance model (a f + o / c), N.
    pub heldout_force_rmse_before_n: f64,
    /// Held-out RMS of y against the extension, N.
    pub heldout_force_rmse_after_n: f64,
    /// Noise σ of y, N.
    pub force_noise_n: f64,
    /// BIC of the extension minus the nuisance model's (full data).
    pub force_delta_bic: f64,
    /// Observed frames (contact frames of the locations).
    pub force_frames: usize,
    /// Full-data parameters of the extension (grid values, then the linear coefficients).
    pub force_params: Vec<(String, f64)>,
    /// Held-out RSS of the nuisance model per location fold, N².
    pub fold_rss_before_n2: Vec<f64>,
    /// Held-out RSS of the extension per location fold, N².
    pub fold_rss_after_n2: Vec<f64>,
    /// The part of `fold_rss_before_n2` on the frames after a ramp's corner ([`after_corner`]), N².
    #[serde(default)]
    pub corner_rss_before_n2: Vec<f64>,
    /// The part of `fold_rss_after_n2` on the frames after a ramp's corner, N².
    #[serde(default)]
    pub corner_rss_after_n2: Vec<f64>,
}

impl ForceScore {
    /// 1 − after² / before²: the share of the held-out force MSE the extension removes.
    pub fn gain(&self) -> f64 {
        let b = self.heldout_force_rmse_before_n;
        if b > 0.0 {
            1.0 - (self.heldout_force_rmse_after_n / b).powi(2)
        } else {
            0.0
        }
    }
}

/// A model of y: named grid parameters and its columns.
pub type ForceCandidate = (Vec<(String, f64)>, Vec<Column>);

/// Normal equations of `cols` over the frames `frames`: (G, h, e, n).
fn normal_equations(
    obs: &ForceObservations,
    cols: &[Column],
    frames: impl Iterator<Item = usize>,
) -> (DMatrix<f64>, DVector<f64>, f64, usize) {
    let p = cols.len();
    let (mut g, mut h, mut e, mut n) = (DMatrix::zeros(p, p), DVector::zeros(p), 0.0, 0);
    for k in frames {
        let Some(y) = obs.model_n[k] else { continue };
        let x = DVector::from_fn(p, |i, _| cols[i].values[k]);
        g += &x * x.transpose();
        h += &x * y;
        e += y * y;
        n += 1;
    }
    (g, h, e, n)
}

/// One fitted candidate: its training RSS and coefficients.
fn fit(
    obs: &ForceObservations,
    cols: &[Column],
    frames: impl Iterator<Item = usize>,
) -> (f64, DVector<f64>, usize) {
    let (g, h, e, n) = normal_equations(obs, cols, frames);
    let nonneg: Vec<bool> = cols.iter().map(|c| c.nonneg).collect();
    let theta = bounded_least_squares(&g, &h, &nonneg);
    (rss(&g, &h, e, &theta), theta, n)
}

/// Held-out RSS per fold and the full-data fit of the best of `candidates`: per held-out
/// location l, the candidate with the least training RSS on the other locations, its
/// coefficients from them, its squared error on l.
fn heldout(
    obs: &ForceObservations,
    seg: &Segmentation,
    candidates: &[ForceCandidate],
) -> Option<Heldout> {
    let nf = seg.num_folds();
    let training = |l: Option<usize>| {
        (0..nf)
            .filter(move |&j| Some(j) != l)
            .flat_map(|j| obs.frames_of(seg, j))
    };
    let best = |l: Option<usize>| {
        candidates
            .iter()
            .enumerate()
            .map(|(i, (_, cols))| {
                let (r, theta, n) = fit(obs, cols, training(l));
                (i, r, theta, n)
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
    };
    let mut fold_rss = vec![0.0; nf];
    let mut corner_rss = vec![0.0; nf];
    for l in 0..nf {
        let (i, _, theta, _) = best(Some(l))?;
        let cols = &candidates[i].1;
        for k in obs.frames_of(seg, l) {
            let Some(y) = obs.model_n[k] else { continue };
            let pred: f64 = cols
                .iter()
                .zip(theta.iter())
                .map(|(c, t)| c.values[k] * t)
                .sum();
            fold_rss[l] += (y - pred).powi(2);
            if after_corner(seg, k) {
                corner_rss[l] += (y - pred).powi(2);
            }
        }
    }
    let (i, rss_all, theta, n) = best(None)?;
    Some(Heldout {
        fold_rss,
        corner_rss,
        best: i,
        theta,
        rss_all,
        n,
    })
}

/// The frames after a ramp's corner whose force error tells a lag from a time shift: the first
/// [`CORNER_FRAMES`] frames of each in-contact phase (loading, hold, unloading: the segmentation's
/// phases, from the tracked tip's depth — the camera's clock). A reading through a first-order
/// lag approaches the force exponentially after a corner (the inverse sensor chain's
/// `crate::sensor::true_forces`), a late reading is the force translated rigidly in time: over a
/// ramp both are a delay, and they differ most just after its corners.
pub fn after_corner(seg: &Segmentation, k: usize) -> bool {
    let p = seg.phases[k];
    p.in_contact() && (1..=CORNER_FRAMES.min(k)).any(|j| seg.phases[k - j] != p)
}

/// How many frames after a phase change count as after a corner ([`after_corner`]).
pub const CORNER_FRAMES: usize = 3;

/// A candidate set's leave-one-location-out result ([`heldout`]).
struct Heldout {
    /// Held-out RSS per fold, N².
    fold_rss: Vec<f64>,
    /// The part of `fold_rss` on the frames after a ramp's corner ([`after_corner`]), N².
    corner_rss: Vec<f64>,
    /// The candidate chosen on all locations.
    best: usize,
    /// Its coefficients on all locations.
    theta: DVector<f64>,
    /// Its RSS on all locations, N².
    rss_all: f64,
    /// Observed frames.
    n: usize,
}

/// The held-out force error of the nuisance model (y ≈ a f + o/c) and of the best of the
/// extension's `candidates` (each a full set of columns, the nuisance's included or replaced),
/// leave-one-location-out; `None` with fewer than two folds or no observed frame.
pub fn heldout_fit(
    obs: &ForceObservations,
    seg: &Segmentation,
    candidates: &[ForceCandidate],
) -> Option<ForceScore> {
    if seg.num_folds() < 2 || candidates.is_empty() {
        return None;
    }
    let before = heldout(obs, seg, &[(Vec::new(), obs.nuisance())])?;
    let after = heldout(obs, seg, candidates)?;
    let (rss0, n, rss1, i, theta) = (
        before.rss_all,
        before.n,
        after.rss_all,
        after.best,
        &after.theta,
    );
    if n == 0 {
        return None;
    }
    let nn = n as f64;
    let rmse = |v: &[f64]| (v.iter().sum::<f64>() / nn).sqrt();
    let (grid, cols) = &candidates[i];
    let k0 = obs.nuisance().len();
    let k1 = grid.len() + cols.len();
    let bic = |r: f64, k: usize| nn * (r.max(1e-300) / nn).ln() + k as f64 * nn.ln();
    let mut force_params = grid.clone();
    force_params.extend(
        cols.iter()
            .zip(theta.iter())
            .map(|(c, t)| (c.name.to_string(), *t)),
    );
    Some(ForceScore {
        heldout_force_rmse_before_n: rmse(&before.fold_rss),
        heldout_force_rmse_after_n: rmse(&after.fold_rss),
        force_noise_n: obs.noise_n,
        force_delta_bic: bic(rss1, k1) - bic(rss0, k0),
        force_frames: n,
        force_params,
        corner_rss_before_n2: before.corner_rss,
        corner_rss_after_n2: after.corner_rss,
        fold_rss_before_n2: before.fold_rss,
        fold_rss_after_n2: after.fold_rss,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::Frame;
    use crate::segment::SegmentSettings;
    use crate::sim::LoadPoint;
    use nalgebra::Vector3;

    /// Three locations pressed by a linear-elastic model (axial stiffness 800, 1000, 1300 N/m)
    /// with the reading of a sensor chain of lag `tau_s` and play `h`; the tip tracks the surface
    /// exactly but for a ±1 µm jitter. Returns the observations and the segmentation.
    fn presses(tau_s: f64, h: f64) -> (ForceObservations, Segmentation) {
        let (obs, seg, _) = presses_read(tau_s, h, 0.0);
        (obs, seg)
    }

    /// [`presses`] with the reading also `offset_s` late (the force at t − offset_s, a clock
    /// offset); returns the recording too.
    fn presses_read(
        tau_s: f64,
        h: f64,
        offset_s: f64,
    ) -> (ForceObservations, Segmentation, Recording) {
        let mut profile = vec![0.0; 3];
        profile.extend((1..=10).map(|i| i as f64 / 10.0));
        profile.extend([1.0; 10]);
        profile.extend((0..10).rev().map(|i| i as f64 / 10.0));
        profile.extend([0.0; 3]);
        let stiffness = [800.0, 1000.0, 1300.0];
        let centres = [0.0, 0.03, 0.015].map(|x| Vector3::new(x, 0.0, 0.01));
        let (mut t, mut truth, mut at) = (Vec::new(), Vec::new(), Vec::new());
        for l in 0..3 {
            for &s in &profile {
                t.push(t.len() as f64 * 0.1);
                truth.push(1.5 * s);
                at.push(l);
            }
        }
        let (reading, _) = crate::sensor::reading(&t, &truth, tau_s, h, false);
        let late: Vec<Vector3<f64>> = reading.iter().map(|&r| Vector3::new(r, 0.0, 0.0)).collect();
        let reading: Vec<f64> = t
            .iter()
            .map(|&tk| crate::signal::sample(&t, &late, tk - offset_s).x)
            .collect();
        let axis = -Vector3::z();
        let frames: Vec<Frame> = (0..t.len())
            .map(|k| {
                let jitter = 1e-6 * (1.7 * k as f64).sin();
                Frame {
                    frame: k as u64,
                    time_s: t[k],
                    tip_m: centres[at[k]] + axis * (truth[k] / stiffness[at[k]] + jitter),
                    axis,
                    force_n: axis * reading[k],
                    markers_m: vec![Some(Vector3::new(0.0, 0.0, 0.01)); 2],
                }
            })
            .collect();
        let rec = Recording::two_marker_toy(frames);
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        assert_eq!(seg.num_folds(), 3);
        let load_point = (0..t.len())
            .map(|k| {
                let c = 1.0 / stiffness[at[k]];
                seg.phases[k].in_contact().then(|| LoadPoint {
                    position_m: centres[at[k]] + axis * (reading[k] * c),
                    response_m_per_n: Some([Vector3::x() * c, Vector3::y() * c, Vector3::z() * c]),
                })
            })
            .collect();
        let p = Prepared {
            times_s: t.clone(),
            force_n: rec.frames.iter().map(|f| f.force_n).collect(),
            baseline_m: vec![rec.rest_markers_m.clone(); t.len()],
            response: Vec::new(),
            rest_model_m: rec.rest_markers_m.clone(),
            gravity_field_m: vec![Vector3::zeros(); 2],
            friction_dir: Vec::new(),
            load_point,
        };
        let obs = ForceObservations::new(&rec, &seg, &p);
        for k in 0..t.len() {
            if let Some(y) = obs.model_n[k] {
                // the model's force at the tracked depth is the true force (but for the jitter)
                assert!((y - truth[k]).abs() < 2e-3, "{k}: {y} vs {}", truth[k]);
            }
        }
        (obs, seg, rec)
    }

    /// The first-order sensor columns of `crate::hypotheses::sensor_lag` on `obs`.
    fn lag_candidate(obs: &ForceObservations, seg: &Segmentation) -> ForceCandidate {
        let t: Vec<f64> = (0..obs.reading_n.len()).map(|k| k as f64 * 0.1).collect();
        let d = crate::signal::derivative(&t, &obs.reading_n);
        let mut cols = obs.nuisance();
        cols.push(Column::nonneg("tau_s", d.clone()));
        let _ = seg;
        (Vec::new(), cols)
    }

    /// The lag and the clock offset on the same force channel: a reading one frame (0.1 s) late
    /// is fitted by the shifted clock's y = a f(t + δ) + o / c (`clock_offset`) at δ = 0.1 s to
    /// the tip jitter, better than by the lag's columns; a lagging reading (τ 0.15 s) the other
    /// way round. Fails when the offset has no force-channel model or reads the clock the wrong
    /// way (δ = −0.1 s does not undo a late reading).
    #[test]
    fn a_late_reading_and_a_lagging_one_compete_on_the_force_channel() {
        let offsets: Vec<f64> = (-6..=6)
            .filter(|&i| i != 0)
            .map(|i| 0.05 * i as f64)
            .collect();
        let fit = |tau_s: f64, offset_s: f64| {
            let (obs, seg, rec) = presses_read(tau_s, 0.0, offset_s);
            let t: Vec<f64> = rec.times_s();
            let f: Vec<Vector3<f64>> = rec.frames.iter().map(|f| f.force_n).collect();
            let shift = crate::hypotheses::clock_offset::offset_force_candidates(
                &obs, &rec, &t, &f, &offsets,
            );
            let shift = heldout_fit(&obs, &seg, &shift).unwrap();
            let lag = heldout_fit(&obs, &seg, &[lag_candidate(&obs, &seg)]).unwrap();
            (shift, lag)
        };
        let (shift, lag) = fit(0.0, 0.1);
        assert!(
            shift.gain() > 0.99 && shift.gain() > lag.gain(),
            "{shift:?} {lag:?}"
        );
        assert_eq!(shift.force_params[0], ("offset_s".to_string(), 0.1));
        let (shift, lag) = fit(0.15, 0.0);
        assert!(
            lag.heldout_force_rmse_after_n < shift.heldout_force_rmse_after_n,
            "{shift:?} {lag:?}"
        );
    }

    /// After a ramp's corner the lag and the shift come apart: on a lagging reading (τ 0.15 s) the
    /// inverse sensor chain (`crate::sensor::true_forces`, the lag's confirmation grid) out-explains
    /// the best shifted clock on the frames after the corners, fold by fold beyond their spread
    /// ([`crate::folds::outexplains`]), and on a reading 0.1 s late it does not out-explain the
    /// shift there (corner gains 0.99999 against 0.96–0.99 per fold; the late reading: 0.91–0.94
    /// against 0.99994). Fails when no frame counts as after a corner (checked: with
    /// `after_corner` always false there are no corner gains and the first assertion fails). On
    /// this noiseless toy all frames part them as well; the third-party `sensor_lag` case is where
    /// only the corners do.
    #[test]
    fn a_lag_and_a_shift_part_after_the_ramp_corners() {
        use crate::folds::{fold_gains, outexplains};
        let offsets: Vec<f64> = (-12..=12)
            .filter(|&i| i != 0)
            .map(|i| 0.025 * i as f64)
            .collect();
        let corner_gains =
            |s: &ForceScore| fold_gains(&s.corner_rss_before_n2, &s.corner_rss_after_n2);
        let fit = |tau_s: f64, offset_s: f64| {
            let (obs, seg, rec) = presses_read(tau_s, 0.0, offset_s);
            let t: Vec<f64> = rec.times_s();
            let f: Vec<Vector3<f64>> = rec.frames.iter().map(|f| f.force_n).collect();
            let axes: Vec<Vector3<f64>> = rec.frames.iter().map(|f| f.axis).collect();
            let shift = crate::hypotheses::clock_offset::offset_force_candidates(
                &obs, &rec, &t, &f, &offsets,
            );
            let shift = heldout_fit(&obs, &seg, &shift).unwrap();
            let chain: Vec<ForceCandidate> = [0.12, 0.135, 0.15, 0.165, 0.19]
                .iter()
                .map(|&tau| {
                    let g = crate::sensor::true_forces(&t, &f, &axes, tau, 0.0);
                    let mut cols = obs.nuisance();
                    cols[0].values = g.iter().zip(&axes).map(|(g, a)| g.dot(a)).collect();
                    (vec![("tau_s".to_string(), tau)], cols)
                })
                .collect();
            let lag = heldout_fit(&obs, &seg, &chain).unwrap();
            (corner_gains(&lag), corner_gains(&shift))
        };
        let (lag, shift) = fit(0.15, 0.0);
        assert!(
            lag.len() == 3 && outexplains(&lag, &shift),
            "lag {lag:?} shift {shift:?}"
        );
        let (lag, shift) = fit(0.0, 0.1);
        assert!(
            shift.len() == 3 && !outexplains(&lag, &shift),
            "lag {lag:?} shift {shift:?}"
        );
    }

    #[test]
    fn a_lagging_reading_shows_on_the_force_channel_and_a_true_one_does_not() {
        let (obs, seg) = presses(0.15, 0.0);
        let lag = heldout_fit(&obs, &seg, &[lag_candidate(&obs, &seg)]).unwrap();
        // the lag is ≈ 15 % of the ramp's force per frame: far above the jitter's noise
        assert!(
            lag.heldout_force_rmse_before_n > 50.0 * lag.force_noise_n,
            "{lag:?}"
        );
        assert!(lag.gain() > 0.8, "{lag:?}");
        let tau = lag.force_params.iter().find(|p| p.0 == "tau_s").unwrap().1;
        assert!((tau - 0.15).abs() < 0.03, "{tau}");

        let (obs, seg) = presses(0.0, 0.0);
        let clean = heldout_fit(&obs, &seg, &[lag_candidate(&obs, &seg)]).unwrap();
        // y is the reading: the nuisance leaves the jitter only (1 µm at 1 kN/m: 1 mN)
        assert!(clean.heldout_force_rmse_before_n < 2e-3, "{clean:?}");
        assert!(clean.force_noise_n < 2e-3, "{clean:?}");
    }
}
