//! The next experiment of an `inconclusive` verdict: the recorded session re-planned under
//! alternative probing protocols, and each look-alike's fitted (linearised) extended model
//! simulated under every one. The protocol under which the leading two candidates' predicted
//! marker motions differ most is the measurement that separates them.
//!
//! A protocol is a transformation of the recording's probe program (tip poses and force per
//! frame); the markers of the planned session are unknown and not needed: every candidate is
//! predicted from the default model's baseline of the planned program ([`crate::baseline`]) and
//! its extension's variants with the parameters fitted on the recorded session.
//!
//! The differences are measured only where the cameras can see them: on the markers the recording
//! observes (after outlier runs are left out — the observations the held-out scores use), frame
//! by frame; a planned frame is observed as the recorded frame it is planned from. They are net
//! of a global stiffness refit (the screen's nuisance model, [`stiffness_scale_variant`]): the
//! re-recorded session is fitted afresh, and a difference a stiffer or softer material takes up
//! does not separate the candidates.

use crate::baseline::{Prepared, prepare};
use crate::evidence::{NextExperiment, ProtocolPrediction};
use crate::hypotheses::{Context, Hypothesis};
use crate::recording::{Frame, Recording};
use crate::screen::{Refit, Variant, predict, stiffness_scale_variant};
use crate::segment::{Phase, Segmentation};
use crate::sim::{Field, ProbeSimulator};
use crate::{DiagnoseError, Result};
use indicatif::ProgressBar;
use nalgebra::{Rotation3, Vector3};

/// Length of the rest of [`Protocol::RestAfterRelease`], s: long against the gaps between the
/// releases of a standard session (≈ 1–3 s), so that a creep recovering with τ' of a few seconds
/// — whose set persists over those gaps like a permanent one — visibly recovers.
pub const REST_AFTER_RELEASE_S: f64 = 3.0;

/// Frames observed during the rest of [`Protocol::RestAfterRelease`] (evenly spaced; a camera
/// recording the whole rest adds frames of a motionless object).
pub const REST_FRAMES: usize = 10;

/// An alternative probing protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Protocol {
    /// Every hold three times as long.
    LongerHolds,
    /// Loading and unloading ramps twice as fast.
    FasterRamps,
    /// The object at rest for [`REST_AFTER_RELEASE_S`] after each release, observed at
    /// [`REST_FRAMES`] evenly spaced frames.
    RestAfterRelease,
    /// The probe force and shaft tilted by [`OBLIQUE_TILT_DEG`] about the axis across the
    /// location's mean shaft and the support normal (world y for a shaft within 5° of the normal).
    ObliqueProbe,
    /// Every location moved towards the marker nearest the support, stopping three tip radii
    /// short of it (measured across the shaft).
    NearSupport,
}

impl Protocol {
    /// Every protocol, in the order they are tried.
    pub const ALL: [Protocol; 5] = [
        Protocol::LongerHolds,
        Protocol::FasterRamps,
        Protocol::RestAfterRelease,
        Protocol::ObliqueProbe,
        Protocol::NearSupport,
    ];

    /// Name.
    pub fn name(self) -> &'static str {
        match self {
            Protocol::LongerHolds => "longer-holds",
            Protocol::FasterRamps => "faster-ramps",
            Protocol::RestAfterRelease => "rest-after-release",
            Protocol::ObliqueProbe => "oblique-probe",
            Protocol::NearSupport => "near-support",
        }
    }

    /// What to record.
    pub fn description(self) -> &'static str {
        match self {
            Protocol::LongerHolds => "re-record with every hold three times as long",
            Protocol::FasterRamps => "re-record with the loading and unloading ramps twice as fast",
            Protocol::RestAfterRelease => {
                "re-record with the probe lifted off and the object at rest for 3 s after each \
                 release"
            }
            Protocol::ObliqueProbe => "re-record with the probe tilted 20° from the recorded shaft",
            Protocol::NearSupport => {
                "re-record with the probe locations moved close to the support"
            }
        }
    }

    /// The recording's probe program under this protocol (markers unobserved).
    pub fn apply(self, rec: &Recording, seg: &Segmentation) -> Recording {
        self.plan(rec, seg).0
    }

    /// [`Protocol::apply`] and, per planned frame, the recorded frame it is planned from (a
    /// repeated hold frame: the hold frame; a rest frame: the release it follows).
    fn plan(self, rec: &Recording, seg: &Segmentation) -> (Recording, Vec<usize>) {
        // time steps of the planned frames (index k: from frame k − 1 to k) where they differ
        // from the recording's median step
        let mut dt = frame_steps(rec, seg, self);
        let planned: Vec<(usize, Frame)> = match self {
            Protocol::LongerHolds => repeat_where(rec, |k| seg.phases[k] == Phase::Hold, 3),
            Protocol::RestAfterRelease => {
                let last_of_location = |k: usize| {
                    seg.fold_of_frame[k].is_some()
                        && seg.fold_of_frame.get(k + 1).copied().flatten() != seg.fold_of_frame[k]
                };
                let rest_step = REST_AFTER_RELEASE_S / REST_FRAMES as f64;
                let mut out = Vec::new();
                for (k, f) in rec.frames.iter().enumerate() {
                    out.push((k, f.clone()));
                    dt.push(if k == 0 {
                        0.0
                    } else {
                        f.time_s - rec.frames[k - 1].time_s
                    });
                    if last_of_location(k) {
                        let mut rest = f.clone();
                        rest.force_n = Vector3::zeros();
                        out.extend(std::iter::repeat_n((k, rest), REST_FRAMES));
                        dt.extend(std::iter::repeat_n(rest_step, REST_FRAMES));
                    }
                }
                out
            }
            Protocol::FasterRamps => rec.frames.iter().cloned().enumerate().collect(),
            Protocol::ObliqueProbe => {
                let n = rec.support.map_or(Vector3::z(), |s| s.normal);
                rec.frames
                    .iter()
                    .enumerate()
                    .map(|(k, f)| {
                        // the location's mean shaft: a measured one tilts the same way all along
                        let shaft = seg.fold_of_frame[k].map_or(f.axis, |l| seg.locations[l].axis);
                        let r = Rotation3::from_axis_angle(
                            &tilt_axis(&shaft, &n),
                            OBLIQUE_TILT_DEG.to_radians(),
                        );
                        let planned = Frame {
                            axis: r * f.axis,
                            force_n: r * f.force_n,
                            ..f.clone()
                        };
                        (k, planned)
                    })
                    .collect()
            }
            Protocol::NearSupport => near_support(rec, seg).into_iter().enumerate().collect(),
        };
        let (sources, frames): (Vec<usize>, Vec<Frame>) = planned.into_iter().unzip();
        let mut t = rec.frames.first().map_or(0.0, |f| f.time_s);
        let frames = frames
            .into_iter()
            .enumerate()
            .map(|(k, f)| {
                if k > 0 {
                    t += dt.get(k).copied().unwrap_or_else(|| median_step(rec));
                }
                Frame {
                    frame: k as u64,
                    time_s: t,
                    markers_m: vec![None; rec.num_markers()],
                    ..f
                }
            })
            .collect();
        let planned = Recording {
            frames,
            ..rec.clone()
        };
        (planned, sources)
    }
}

/// The tilt of [`Protocol::ObliqueProbe`], degrees.
pub const OBLIQUE_TILT_DEG: f64 = 20.0;

/// A shaft closer than this to the support normal, degrees, counts as along it
/// ([`tilt_axis`]): a measured straight probe is a fraction of a degree off.
const SHAFT_ALONG_NORMAL_DEG: f64 = 5.0;

/// The axis [`Protocol::ObliqueProbe`] tilts a shaft about: perpendicular to the shaft and the
/// support normal `n`; for a shaft along the normal (within [`SHAFT_ALONG_NORMAL_DEG`]) world y
/// made perpendicular to the shaft (else world x). The threshold keeps a measured straight shaft,
/// whose cross product with the normal is its measurement noise, from tilting in the noise's
/// direction — one direction per frame (seen on the third-party sessions: the tilted force
/// turned from frame to frame, and a clock offset's f(t + δ) − f(t) grew to 80 % of the force).
fn tilt_axis(shaft: &Vector3<f64>, n: &Vector3<f64>) -> nalgebra::Unit<Vector3<f64>> {
    let shaft = shaft.try_normalize(1e-12).unwrap_or(*n);
    let across = shaft.cross(n);
    if across.norm() > SHAFT_ALONG_NORMAL_DEG.to_radians().sin() {
        return nalgebra::Unit::new_normalize(across);
    }
    [Vector3::y(), Vector3::x()]
        .into_iter()
        .map(|e| e - shaft * shaft.dot(&e))
        .find(|e| e.norm() > 0.5)
        .map_or_else(Vector3::y_axis, nalgebra::Unit::new_normalize)
}

/// The median time step of the recording, s.
fn median_step(rec: &Recording) -> f64 {
    let mut d: Vec<f64> = rec
        .frames
        .windows(2)
        .map(|w| w[1].time_s - w[0].time_s)
        .collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().unwrap_or(0.05)
}

/// Time steps of the planned frames (index k: from frame k − 1 to k): the recorded ones, halved
/// on ramps for [`Protocol::FasterRamps`]; empty for the others (the median step, or the steps
/// [`Protocol::apply`] sets for [`Protocol::RestAfterRelease`]).
fn frame_steps(rec: &Recording, seg: &Segmentation, p: Protocol) -> Vec<f64> {
    if p != Protocol::FasterRamps {
        return Vec::new();
    }
    (0..rec.frames.len())
        .map(|k| {
            let d = if k == 0 {
                0.0
            } else {
                rec.frames[k].time_s - rec.frames[k - 1].time_s
            };
            match seg.phases[k] {
                Phase::Loading | Phase::Unloading => 0.5 * d,
                _ => d,
            }
        })
        .collect()
}

/// The frames (each with its index) with every frame `sel` selects repeated `times` times.
fn repeat_where(rec: &Recording, sel: impl Fn(usize) -> bool, times: usize) -> Vec<(usize, Frame)> {
    rec.frames
        .iter()
        .enumerate()
        .flat_map(|(k, f)| std::iter::repeat_n((k, f.clone()), if sel(k) { times } else { 1 }))
        .collect()
}

/// Every location's tip poses shifted across the shaft towards the marker nearest the support,
/// to three tip radii from it.
fn near_support(rec: &Recording, seg: &Segmentation) -> Vec<Frame> {
    let Some(support) = rec.support else {
        return rec.frames.clone();
    };
    let anchor = rec
        .rest_markers_m
        .iter()
        .min_by(|a, b| {
            (support.normal.dot(a) - support.offset_m)
                .total_cmp(&(support.normal.dot(b) - support.offset_m))
        })
        .copied()
        .unwrap_or_else(Vector3::zeros);
    let shift: Vec<Vector3<f64>> = seg
        .locations
        .iter()
        .map(|loc| {
            let a = loc.axis;
            let d = anchor - loc.contact_tip_m;
            let across = d - a * a.dot(&d);
            let len = across.norm();
            let keep = 3.0 * rec.tip_radius_m;
            if len > keep {
                across * ((len - keep) / len)
            } else {
                Vector3::zeros()
            }
        })
        .collect();
    rec.frames
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let s = seg.fold_of_frame[k].map_or(Vector3::zeros(), |l| shift[l]);
            Frame {
                tip_m: f.tip_m + s,
                ..f.clone()
            }
        })
        .collect()
}

/// A candidate's linearised prediction under a planned program: the variant of its grid closest
/// to the fitted one (same nonlinear parameters, else the nearest) with the fitted linear
/// parameters.
fn candidate_prediction(vars: &[Variant], fitted: &Variant, r: &Refit, p: &Prepared) -> Field {
    let distance = |v: &Variant| -> f64 {
        v.fixed
            .iter()
            .zip(&fitted.fixed)
            .map(|(a, b)| ((a.1 - b.1) / b.1.abs().max(1e-12)).powi(2))
            .sum::<f64>()
            + if v.bases.len() == fitted.bases.len() {
                0.0
            } else {
                1e9
            }
    };
    let Some(i) =
        (0..vars.len()).min_by(|&a, &b| distance(&vars[a]).total_cmp(&distance(&vars[b])))
    else {
        return p.baseline_m.clone();
    };
    predict(
        vars,
        p,
        &Refit {
            variant: i,
            ..r.clone()
        },
    )
}

/// Which markers the cameras observe, per frame of `rec` (`[k][m]`).
fn observed(rec: &Recording) -> Vec<Vec<bool>> {
    rec.frames
        .iter()
        .map(|f| f.markers_m.iter().map(Option::is_some).collect())
        .collect()
}

/// Which markers the cameras would observe per planned frame: those of the recorded frame it is
/// planned from (`sources`, [`Protocol::plan`]) — the same cameras, the same object.
fn observed_planned(rec_observed: &[Vec<bool>], sources: &[usize]) -> Vec<Vec<bool>> {
    sources.iter().map(|&k| rec_observed[k].clone()).collect()
}

/// RMS of the difference of two predictions over the observed (frame k, marker m) samples
/// (`observed[k][m]`), m; 0 without any. Only observed markers count: a difference on markers
/// the cameras never see (e.g. the support markers under a camera above the block) cannot be
/// measured by re-recording with the same cameras, so it must not make a protocol the next
/// experiment; and the samples are those the held-out scores of the candidates are taken on.
///
/// The part of the difference along `absorbed` (the program's global stiffness-scale field,
/// [`stiffness_scale_variant`]) is removed first, by least squares over the same samples: a
/// re-recording is fitted afresh, and the stiffness scale is the nuisance every hypothesis is
/// refitted with, so a difference the re-fitted stiffness takes up separates nothing. (A
/// viscoelastic candidate carries an instantaneous compliance term of exactly that field; under
/// an oblique program its linearised difference from a clock offset is mostly that term.)
fn rms_difference(a: &Field, b: &Field, absorbed: &Field, observed: &[Vec<bool>]) -> f64 {
    let samples = || {
        a.iter()
            .zip(b)
            .zip(absorbed)
            .zip(observed)
            .flat_map(|(((ra, rb), rc), seen)| {
                ra.iter()
                    .zip(rb)
                    .zip(rc)
                    .zip(seen)
                    .filter(|(_, seen)| **seen)
                    .map(|(((x, y), c), _)| (x - y, *c))
            })
    };
    let (mut dc, mut cc, mut n) = (0.0, 0.0, 0usize);
    for (d, c) in samples() {
        dc += d.dot(&c);
        cc += c.norm_squared();
        n += 1;
    }
    let scale = if cc > 0.0 { dc / cc } else { 0.0 };
    let s: f64 = samples().map(|(d, c)| (d - c * scale).norm_squared()).sum();
    if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
}

/// RMS difference of two force-channel models' readings ([`Hypothesis::reading_of`], each with
/// its force-fit parameters) of the program `rec`'s axial force, over its contact frames, N;
/// `None` when either has no reading model or there is no contact frame.
fn force_difference(
    rec: &Recording,
    seg: &Segmentation,
    a: (&dyn Hypothesis, &[(String, f64)]),
    b: (&dyn Hypothesis, &[(String, f64)]),
) -> Option<f64> {
    let t = rec.times_s();
    let f: Vec<f64> = rec.frames.iter().map(|f| f.force_n.dot(&f.axis)).collect();
    let ra = a.0.reading_of(a.1, &t, &f)?;
    let rb = b.0.reading_of(b.1, &t, &f)?;
    let d: Vec<f64> = (0..t.len())
        .filter(|&k| seg.phases[k].in_contact())
        .map(|k| (ra[k] - rb[k]).powi(2))
        .collect();
    (!d.is_empty()).then(|| (d.iter().sum::<f64>() / d.len() as f64).sqrt())
}

/// The protocol that best separates the two leading candidates `a` and `b` (each a hypothesis
/// with its screen refit on the recorded session): both simulated under the recorded program and
/// under every [`Protocol`]; the largest RMS difference between their predicted markers wins,
/// taken over the markers observed (per recorded frame, and per planned frame those of the
/// recorded frame it is planned from; module docs).
///
/// Two force-channel candidates (`force`: each one's force-fit parameters, both with a reading
/// model, [`Hypothesis::reading_of`]) are compared on the force channel instead: under each
/// program, the planned force read through both models (`force_difference`); the largest
/// difference wins.
pub fn next_experiment(
    cx: &Context<'_>,
    a: (&dyn Hypothesis, &Refit),
    b: (&dyn Hypothesis, &Refit),
    force: Option<(&[(String, f64)], &[(String, f64)])>,
    sim: &mut dyn ProbeSimulator,
) -> Result<NextExperiment> {
    let fitted = |h: &dyn Hypothesis, r: &Refit| -> Result<Variant> {
        h.variants(cx)
            .into_iter()
            .nth(r.variant)
            .ok_or_else(|| DiagnoseError::BadRecording {
                what: format!(
                    "{}: no variant {} to plan with",
                    h.effect().name(),
                    r.variant
                ),
            })
    };
    let (va, vb) = (fitted(a.0, a.1)?, fitted(b.0, b.1)?);
    let prediction = |cx: &Context<'_>, h: &dyn Hypothesis, fitted: &Variant, r: &Refit| {
        let Some(v) = h.planning_variant(cx, r) else {
            return candidate_prediction(&h.variants(cx), fitted, r, cx.prepared);
        };
        let planned = Refit {
            variant: 0,
            ..r.clone()
        };
        predict(&[v], cx.prepared, &planned)
    };
    let difference = |cx: &Context<'_>, observed: &[Vec<bool>]| {
        let pa = prediction(cx, a.0, &va, a.1);
        let pb = prediction(cx, b.0, &vb, b.1);
        let absorbed = &stiffness_scale_variant(cx.prepared).bases[0].field;
        rms_difference(&pa, &pb, absorbed, observed)
    };
    let seen = observed(cx.rec);
    let recorded = difference(cx, &seen);
    let mut protocols = Vec::new();
    for p in Protocol::ALL {
        let (rec, sources) = p.plan(cx.rec, cx.seg);
        let seg = Segmentation::new(&rec, &cx.settings.segment);
        let prepared = prepare(&rec, &seg, sim, cx.settings, &ProgressBar::hidden())?;
        let planned = Context {
            rec: &rec,
            seg: &seg,
            prepared: &prepared,
            ..*cx
        };
        protocols.push(ProtocolPrediction {
            protocol: p.name().into(),
            predicted_difference_m: difference(&planned, &observed_planned(&seen, &sources)),
            predicted_force_difference_n: force
                .and_then(|(pa, pb)| force_difference(&rec, &seg, (a.0, pa), (b.0, pb))),
        });
    }
    // on the force channel when both candidates have its difference, else on the markers
    let on_force = protocols
        .iter()
        .all(|p| p.predicted_force_difference_n.is_some());
    let score = |p: &ProtocolPrediction| match on_force {
        true => p.predicted_force_difference_n.unwrap_or(0.0),
        false => p.predicted_difference_m,
    };
    let best = Protocol::ALL
        .into_iter()
        .zip(&protocols)
        .max_by(|x, y| score(x.1).total_cmp(&score(y.1)))
        .map(|(p, pp)| (p, pp.predicted_difference_m))
        .unwrap_or((Protocol::LongerHolds, 0.0));
    Ok(NextExperiment {
        protocol: best.0.name().into(),
        description: best.0.description().into(),
        predicted_difference_m: best.1,
        recorded_difference_m: recorded,
        protocols,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segment::SegmentSettings;

    /// Two locations, each: rest, ramp, hold, unload, released.
    fn toy() -> (Recording, Segmentation) {
        toy_of(&[0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0, 0.5, 0.0, 0.0], 0.1)
    }

    /// Two locations pressed along `profile` (depth and force fractions per frame), frames
    /// `dt` apart.
    fn toy_of(profile: &[f64], dt: f64) -> (Recording, Segmentation) {
        let mut frames = Vec::new();
        for tip in [Vector3::new(0.0, 0.0, 0.01), Vector3::new(0.03, 0.0, 0.01)] {
            for &s in profile {
                let k = frames.len();
                frames.push(Frame {
                    frame: k as u64,
                    time_s: k as f64 * dt,
                    tip_m: tip - Vector3::z() * 0.002 * s,
                    axis: -Vector3::z(),
                    force_n: -Vector3::z() * 2.0 * s,
                    markers_m: vec![None, None],
                });
            }
        }
        let rec = Recording::two_marker_toy(frames);
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        (rec, seg)
    }

    /// A lag (τ 0.1 s) and a clock offset (0.1 s) read the same ramps alike but part at the
    /// corners, by the rate times the delay: on ramps of 10 frames 50 ms apart (0.5 s, five
    /// times the delay) faster ramps part them more than the recorded program and than longer
    /// holds (the planner's force-channel choice for that pair). Fails
    /// when either reading model is missing (no difference) or the offset reads the clock the
    /// wrong way (then the recorded program already parts them by twice the delay).
    #[test]
    fn faster_ramps_part_a_lag_from_a_clock_offset_on_the_force_channel() {
        use crate::hypotheses::{clock_offset::ClockOffset, sensor_lag::SensorLag};
        let mut profile = vec![0.0; 3];
        profile.extend((1..=10).map(|i| i as f64 / 10.0));
        profile.extend([1.0; 10]);
        profile.extend((0..10).rev().map(|i| i as f64 / 10.0));
        profile.extend([0.0; 3]);
        let (rec, seg) = toy_of(&profile, 0.05);
        let lag = vec![("tau_s".to_string(), 0.1), ("hysteresis".to_string(), 0.0)];
        let shift = vec![("offset_s".to_string(), 0.1)];
        let under = |p: Option<Protocol>| {
            let planned = p.map_or_else(|| rec.clone(), |p| p.apply(&rec, &seg));
            let seg = Segmentation::new(&planned, &SegmentSettings::default());
            force_difference(&planned, &seg, (&SensorLag, &lag), (&ClockOffset, &shift)).unwrap()
        };
        let (recorded, faster, longer) = (
            under(None),
            under(Some(Protocol::FasterRamps)),
            under(Some(Protocol::LongerHolds)),
        );
        assert!(
            recorded > 0.0 && recorded < 0.5 && faster > 1.2 * recorded && faster > longer,
            "recorded {recorded} faster {faster} longer {longer}"
        );
    }

    #[test]
    fn predicted_difference_counts_only_observed_markers() {
        // 2 frames × 3 markers; observed: frame 0 marker 0, frame 1 markers 0 and 1; marker 2
        // (e.g. on the support, under a camera above the block) never
        let seen = vec![vec![true, false, false], vec![true, true, false]];
        let a: Field = vec![vec![Vector3::zeros(); 3]; 2];
        let mut b = a.clone();
        for row in &mut b {
            row[2] = Vector3::new(1e-3, -2e-3, 5e-3);
        }
        b[0][1] = Vector3::new(7e-3, 0.0, 0.0);
        let none = a.clone();
        assert_eq!(rms_difference(&a, &b, &none, &seen), 0.0);
        // observed differences: (3, 4, 0) mm at frame 0 marker 0, (0, 0, 1) mm at frame 1
        // marker 1, 0 at frame 1 marker 0: RMS √((25 + 1 + 0)/3) mm
        b[0][0] = Vector3::new(3e-3, 4e-3, 0.0);
        b[1][1] = Vector3::new(0.0, 0.0, 1e-3);
        let want = 1e-3 * (26.0f64 / 3.0).sqrt();
        assert!((rms_difference(&a, &b, &none, &seen) - want).abs() < 1e-15);
        // nothing observed: no difference
        assert_eq!(
            rms_difference(&a, &b, &none, &[vec![false; 3], vec![false; 3]]),
            0.0
        );
    }

    #[test]
    fn predicted_difference_is_net_of_a_stiffness_refit() {
        // 3 frames × 2 markers, all observed; the stiffness field c and a difference d = 0.4 c + e
        // with e ⟂ c over the samples: only e remains
        let seen = vec![vec![true; 2]; 3];
        let c: Field = (0..3)
            .map(|k| {
                let k = k as f64;
                vec![Vector3::new(k, 0.0, 1.0), Vector3::new(0.0, 2.0 * k, 0.0)]
            })
            .collect();
        let e: Field = (0..3)
            .map(|k| {
                let k = k as f64;
                vec![
                    Vector3::new(0.0, 1e-3 * k, 0.0),
                    Vector3::new(0.0, 0.0, 2e-3),
                ]
            })
            .collect();
        let dot = |x: &Field, y: &Field| -> f64 {
            x.iter()
                .zip(y)
                .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| p.dot(q)))
                .sum()
        };
        assert_eq!(dot(&c, &e), 0.0);
        let a: Field = vec![vec![Vector3::zeros(); 2]; 3];
        let b: Field = c
            .iter()
            .zip(&e)
            .map(|(rc, re)| rc.iter().zip(re).map(|(c, e)| 0.4 * c + e).collect())
            .collect();
        let want = (dot(&e, &e) / 6.0).sqrt();
        let got = rms_difference(&a, &b, &c, &seen);
        assert!((got - want).abs() < 1e-15, "{got} {want}");
        // a difference that is all stiffness separates nothing
        assert!(rms_difference(&a, &c, &c, &seen) < 1e-15);
    }

    #[test]
    fn planned_frames_are_observed_as_their_recorded_frame() {
        let (mut rec, seg) = toy();
        // marker 0 seen in every frame, marker 1 in the odd ones
        for (k, f) in rec.frames.iter_mut().enumerate() {
            f.markers_m = vec![Some(Vector3::zeros()), (k % 2 == 1).then(Vector3::zeros)];
        }
        let seen = observed(&rec);
        for p in Protocol::ALL {
            let (planned, sources) = p.plan(&rec, &seg);
            assert_eq!(sources.len(), planned.frames.len(), "{}", p.name());
            let rows = observed_planned(&seen, &sources);
            for (j, &k) in sources.iter().enumerate() {
                assert_eq!(rows[j], [true, k % 2 == 1], "{}", p.name());
                assert!(planned.frames[j].markers_m.iter().all(Option::is_none));
            }
            assert!(sources.windows(2).all(|w| w[0] <= w[1]), "{}", p.name());
        }
        // longer holds: each hold frame planned three times; rest after release: each release
        // followed by REST_FRAMES rest frames planned from it
        let (_, sources) = Protocol::LongerHolds.plan(&rec, &seg);
        for (k, phase) in seg.phases.iter().enumerate() {
            let times = sources.iter().filter(|&&s| s == k).count();
            assert_eq!(times, if *phase == Phase::Hold { 3 } else { 1 });
        }
        let (rest, sources) = Protocol::RestAfterRelease.plan(&rec, &seg);
        for (j, f) in rest.frames.iter().enumerate() {
            assert_eq!(f.tip_m, rec.frames[sources[j]].tip_m);
        }
        let times: Vec<usize> = (0..rec.frames.len())
            .map(|k| sources.iter().filter(|&&s| s == k).count())
            .collect();
        let released = times.iter().filter(|&&t| t == 1 + REST_FRAMES).count();
        assert_eq!(released, seg.num_folds(), "{times:?}");
        assert!(times.iter().all(|&t| t == 1 || t == 1 + REST_FRAMES));
    }

    #[test]
    fn protocols_replan_the_probe_program() {
        let (rec, seg) = toy();
        let holds = seg.phases.iter().filter(|p| **p == Phase::Hold).count();
        assert!(holds >= 2, "{:?}", seg.phases);
        let n = rec.frames.len();
        let longer = Protocol::LongerHolds.apply(&rec, &seg);
        assert_eq!(longer.frames.len(), n + 2 * holds);
        let rest = Protocol::RestAfterRelease.apply(&rec, &seg);
        assert_eq!(rest.frames.len(), n + 10 * seg.num_folds());
        // times increase by the recorded step everywhere but on the ramps of faster-ramps and
        // during the rests
        for w in longer.frames.windows(2) {
            assert!((w[1].time_s - w[0].time_s - 0.1).abs() < 1e-12);
        }
        let rest_step = REST_AFTER_RELEASE_S / REST_FRAMES as f64;
        let steps: Vec<f64> = rest
            .frames
            .windows(2)
            .map(|w| w[1].time_s - w[0].time_s)
            .collect();
        assert!(
            steps
                .iter()
                .all(|d| (d - 0.1).abs() < 1e-12 || (d - rest_step).abs() < 1e-12)
        );
        let rested = steps
            .iter()
            .filter(|d| (*d - rest_step).abs() < 1e-12)
            .count();
        assert_eq!(rested, REST_FRAMES * seg.num_folds(), "{steps:?}");
        let span = |r: &Recording| r.frames[r.frames.len() - 1].time_s - r.frames[0].time_s;
        let folds = seg.num_folds() as f64;
        assert!((span(&rest) - span(&rec) - REST_AFTER_RELEASE_S * folds).abs() < 1e-9);
        let fast = Protocol::FasterRamps.apply(&rec, &seg);
        assert!(span(&fast) < span(&rec) - 0.05);
        let oblique = Protocol::ObliqueProbe.apply(&rec, &seg);
        for (a, b) in oblique.frames.iter().zip(&rec.frames) {
            assert!((a.axis.angle(&b.axis) - 20f64.to_radians()).abs() < 1e-9);
            assert!((a.force_n.norm() - b.force_n.norm()).abs() < 1e-12);
            assert!(a.markers_m.iter().all(|m| m.is_none()));
        }
    }

    /// A measured straight shaft (0.3° off the normal, in a direction that turns from frame to
    /// frame) is tilted one way all along: about world y, as an exact one; a shaft 30° off the
    /// normal is tilted about the axis across both.
    #[test]
    fn oblique_probe_tilts_a_noisy_straight_shaft_one_way() {
        let (mut rec, _) = toy();
        let wobble = 0.3f64.to_radians();
        for (k, f) in rec.frames.iter_mut().enumerate() {
            let phi = k as f64 * 2.4;
            let axis = Vector3::new(wobble * phi.cos(), wobble * phi.sin(), -1.0).normalize();
            f.force_n = axis * f.force_n.norm();
            f.axis = axis;
        }
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        let oblique = Protocol::ObliqueProbe.apply(&rec, &seg);
        for (a, b) in oblique.frames.iter().zip(&rec.frames) {
            // tilted towards −x (about +y, 20°) within the wobble
            let tilted = a.axis - b.axis * b.axis.dot(&a.axis);
            assert!(tilted.normalize().x < -0.999, "{tilted:?}");
            assert!((a.axis.angle(&b.axis) - OBLIQUE_TILT_DEG.to_radians()).abs() < 2.0 * wobble);
        }
        let n = Vector3::z();
        assert_eq!(tilt_axis(&-Vector3::z(), &n).into_inner(), Vector3::y());
        let shaft = Vector3::new(30f64.to_radians().sin(), 0.0, -30f64.to_radians().cos());
        let about = tilt_axis(&shaft, &n);
        assert!((about.dot(&shaft)).abs() < 1e-12 && about.z.abs() < 1e-12);
    }
}
