//! Outlier markers: a marker whose residual against the default model steps away and steps back
//! (a plateau) for a while — the shape of a marker assigned to the wrong blob for seconds, e.g.
//! a persistent spurious blob beside it — is flagged and its observations on the plateau are left
//! out of every score, so that one mislabeled marker cannot decide the diagnosis.
//!
//! Per marker, the residual r_k = measured − default model over its observed frames; a *step* is
//! the change d_k = r_k − r_{k−1} between consecutive observations. The model follows the
//! object's deformation, so d_k is small wherever the marker is the marker (it carries the
//! noise and the slowly varying model error); a relabeling moves the measured point by the
//! distance to the other blob in one frame. An outlier run starts at a step of at least
//! `step_m` (and `noise_factor` × the robust spread of every marker's steps) and ends at the
//! first later step back (|d_a + d_b| ≤ ½ |d_a|) within `max_duration_s`, with every residual in
//! between within ½ |d_a| of the plateau r_{a−1} + d_a. Both steps must happen while the model's
//! marker stands still (it moves by at most ¼ of the step: a lagging or leading force moves the
//! model, a relabel does not), and the run must last `min_duration_s`. A permanent set (a step
//! without a step back) and a gradual drift (ramps of many frames) are not outliers.

use crate::recording::Recording;
use crate::residual::Residuals;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// How outlier markers are found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutlierSettings {
    /// Look for outlier markers and leave their runs out of the diagnosis.
    pub enabled: bool,
    /// The smallest step that opens a run, m.
    pub step_m: f64,
    /// … and at least this multiple of the steps' robust spread (1.4826 × median |d|, all
    /// markers).
    pub noise_factor: f64,
    /// The longest run, s.
    pub max_duration_s: f64,
    /// The shortest run, s.
    pub min_duration_s: f64,
}

impl Default for OutlierSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            step_m: 2e-4,
            noise_factor: 8.0,
            max_duration_s: 10.0,
            min_duration_s: 0.3,
        }
    }
}

/// One flagged run of one marker.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OutlierRun {
    /// Marker id.
    pub marker: String,
    /// Marker index.
    pub marker_index: usize,
    /// First and last frame index (into the recording's frames) of the run.
    pub frames: [usize; 2],
    /// Times of the first and last frame, s.
    pub time_s: [f64; 2],
    /// |d_a|: the step into the run, m.
    pub step_m: f64,
    /// Observations left out.
    pub observations: usize,
}

/// The outlier runs of every marker against the default model's markers `baseline_m`.
pub fn outlier_runs(
    rec: &Recording,
    baseline_m: &[Vec<Vector3<f64>>],
    settings: &OutlierSettings,
) -> Vec<OutlierRun> {
    if !settings.enabled {
        return Vec::new();
    }
    let res = crate::residual::residuals(rec, baseline_m);
    let nm = rec.num_markers();
    let tracks: Vec<Vec<(usize, Vector3<f64>)>> = (0..nm)
        .map(|m| {
            res.iter()
                .enumerate()
                .filter_map(|(k, row)| row[m].map(|r| (k, r)))
                .collect()
        })
        .collect();
    let mut steps: Vec<f64> = tracks
        .iter()
        .flat_map(|t| t.windows(2).map(|w| (w[1].1 - w[0].1).norm()))
        .collect();
    if steps.is_empty() {
        return Vec::new();
    }
    steps.sort_by(f64::total_cmp);
    let spread = 1.4826 * steps[steps.len() / 2];
    let threshold = settings.step_m.max(settings.noise_factor * spread);
    let mut runs = Vec::new();
    for (m, track) in tracks.iter().enumerate() {
        let mut i = 1;
        while i < track.len() {
            let still = |j: usize| {
                let (k0, k1) = (track[j - 1].0, track[j].0);
                (baseline_m[k1][m] - baseline_m[k0][m]).norm()
                    <= 0.25 * (track[j].1 - track[j - 1].1).norm()
            };
            match run_from(rec, track, i, threshold, settings, &still) {
                Some(end) => {
                    let (a, b) = (track[i].0, track[end - 1].0);
                    runs.push(OutlierRun {
                        marker: rec.marker_ids[m].clone(),
                        marker_index: m,
                        frames: [a, b],
                        time_s: [rec.frames[a].time_s, rec.frames[b].time_s],
                        step_m: (track[i].1 - track[i - 1].1).norm(),
                        observations: end - i,
                    });
                    i = end + 1;
                }
                None => i += 1,
            }
        }
    }
    runs
}

/// The run opened by the step into observation `i` of `track`: the index of the observation that
/// steps back (the first after the run), or `None`.
fn run_from(
    rec: &Recording,
    track: &[(usize, Vector3<f64>)],
    i: usize,
    threshold: f64,
    settings: &OutlierSettings,
    still: &dyn Fn(usize) -> bool,
) -> Option<usize> {
    let d_in = track[i].1 - track[i - 1].1;
    let size = d_in.norm();
    if size < threshold || !still(i) {
        return None;
    }
    let plateau = track[i].1;
    let t0 = rec.frames[track[i].0].time_s;
    for j in i + 1..track.len() {
        let duration_s = rec.frames[track[j].0].time_s - t0;
        if duration_s > settings.max_duration_s {
            return None;
        }
        let d = track[j].1 - track[j - 1].1;
        if d.norm() >= threshold && (d_in + d).norm() <= 0.5 * size {
            return (still(j) && duration_s >= settings.min_duration_s).then_some(j);
        }
        if (track[j].1 - plateau).norm() > 0.5 * size {
            return None;
        }
    }
    None
}

/// `rec` without the observations of `runs` (set to unobserved).
pub fn without_runs(rec: &Recording, runs: &[OutlierRun]) -> Recording {
    let mut out = rec.clone();
    for r in runs {
        for f in &mut out.frames[r.frames[0]..=r.frames[1]] {
            f.markers_m[r.marker_index] = None;
        }
    }
    out
}

/// The residuals of `res` with the observations of `runs` removed.
pub fn mask_residuals(res: &mut Residuals, runs: &[OutlierRun]) {
    for r in runs {
        for row in &mut res[r.frames[0]..=r.frames[1]] {
            row[r.marker_index] = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::Frame;

    /// A recording of `nm` still markers at the origin with small alternating noise; the model
    /// predicts the origin.
    fn still(nm: usize, nt: usize) -> (Recording, Vec<Vec<Vector3<f64>>>) {
        let frames = (0..nt)
            .map(|k| Frame {
                frame: k as u64,
                time_s: 0.1 * k as f64,
                tip_m: Vector3::zeros(),
                axis: -Vector3::z(),
                force_n: Vector3::zeros(),
                markers_m: (0..nm)
                    .map(|m| {
                        let s = if (k + m) % 2 == 0 { 1.0 } else { -1.0 };
                        Some(Vector3::new(s * 1e-5, 0.0, 0.0))
                    })
                    .collect(),
            })
            .collect();
        let rec = Recording {
            marker_ids: (0..nm).map(|m| format!("m{m}")).collect(),
            rest_markers_m: vec![Vector3::zeros(); nm],
            normals: vec![Vector3::z(); nm],
            gravity_m_s2: Vector3::zeros(),
            support: None,
            tip_radius_m: 0.005,
            frames,
        };
        (rec, vec![vec![Vector3::zeros(); nm]; nt])
    }

    /// A marker moved 0.45 mm for 3 s (30 frames) and back is one run of exactly those frames;
    /// the clean markers are not flagged, and without the run the marker is clean.
    #[test]
    fn a_relabeled_marker_is_one_run() {
        let (mut rec, base) = still(6, 100);
        for f in &mut rec.frames[40..70] {
            f.markers_m[2] = f.markers_m[2].map(|p| p + Vector3::new(0.0, 4.5e-4, 0.0));
        }
        let runs = outlier_runs(&rec, &base, &OutlierSettings::default());
        assert_eq!(runs.len(), 1, "{runs:?}");
        assert_eq!((runs[0].marker_index, runs[0].frames), (2, [40, 69]));
        assert!((runs[0].step_m - 4.5e-4).abs() < 3e-5, "{}", runs[0].step_m);
        let clean = without_runs(&rec, &runs);
        assert!(outlier_runs(&clean, &base, &OutlierSettings::default()).is_empty());
    }

    /// A permanent step (a plastic set) and a gradual ramp of the same size are not outliers.
    #[test]
    fn a_permanent_set_and_a_ramp_are_not_outliers() {
        let (mut rec, base) = still(6, 100);
        for f in &mut rec.frames[40..] {
            f.markers_m[1] = f.markers_m[1].map(|p| p + Vector3::new(0.0, 0.0, -5e-4));
        }
        for (i, f) in rec.frames[30..60].iter_mut().enumerate() {
            let h = 5e-4 * (1.0 - (i as f64 - 15.0).abs() / 15.0);
            f.markers_m[3] = f.markers_m[3].map(|p| p + Vector3::new(h, 0.0, 0.0));
        }
        assert!(outlier_runs(&rec, &base, &OutlierSettings::default()).is_empty());
    }
}
