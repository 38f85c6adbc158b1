//! Wrinkle tracking over the frames of one camera (thesis §4.3): the paint classifier is trained
//! on the labelled first frame and applied to every frame (§4.3.1), the predefined wrinkles are
//! the label's patches, and in each frame every wrinkle takes the classified patches that overlap
//! its previous patch (dilated by the largest expected motion). Each wrinkle's patch then gets
//! its PCA parameterization, weighted valley B-spline (eq. 4.2) and cross-section (d, w) fits
//! (eq. 4.3–4.4) by [`track_wrinkle`]. "If no wrinkle is present, the fitted depth d is 0"
//! (§4.3.2): a wrinkle whose median fitted depth stays below [`VideoTrackSettings::min_depth_px`]
//! (or whose width or d/w is below its bound) is reported absent in that frame.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::classify::{SvmSettings, classify_frames};
use crate::error::Result;
use crate::image::RgbImage;
use crate::morphology::{close, connected_components, dilate, open};
use crate::pooled::{FrameEstimate, MIN_WIDTH_PX, TimeModel, estimate_time_noise, smooth_in_time};
use crate::track::{TrackSettings, TrackedWrinkle, track_wrinkle};

/// Settings of [`track_video`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct VideoTrackSettings {
    /// The paint classifier.
    pub svm: SvmSettings,
    /// Valley spline and cross-section fits.
    pub track: TrackSettings,
    /// Radius of the opening and closing that clean the classified mask (pixels).
    pub morphology_radius_px: usize,
    /// Largest motion of a wrinkle's paint between two frames (pixels).
    pub search_radius_px: usize,
    /// Smallest label patch that defines a wrinkle (pixels).
    pub min_label_patch_px: usize,
    /// Smallest classified patch given to a wrinkle (pixels).
    pub min_patch_px: usize,
    /// A wrinkle is visible when the median fitted depth of its cross-sections reaches this
    /// (pixels; on smooth painted skin the fits return d ≲ 0.25 px, mostly at the width bound) …
    pub min_depth_px: f64,
    /// … the median width this (pixels: a narrower dip is a few noisy pixels) …
    pub min_width_px: f64,
    /// … and the median d/w this.
    pub visible_depth_ratio: f64,
    /// … and at least this many cross-sections converged.
    pub min_sections: usize,
    /// Smooth each wrinkle's pooled (d, w) over runs of consecutive visible frames
    /// ([`smooth_in_time`]; needs [`TrackSettings::pool`](crate::track::TrackSettings::pool)).
    pub smooth_in_time: bool,
    /// How ln d and ln w move between frames in the smoother ([`TimeModel`]); `None`: chosen
    /// per wrinkle from its frames in all cameras by maximum marginal likelihood
    /// ([`estimate_time_noise`]).
    pub drift_per_frame: Option<[TimeModel; 2]>,
}

impl Default for VideoTrackSettings {
    fn default() -> Self {
        Self {
            svm: SvmSettings::default(),
            track: TrackSettings::default(),
            morphology_radius_px: 1,
            search_radius_px: 8,
            min_label_patch_px: 100,
            min_patch_px: 20,
            min_depth_px: 0.3,
            min_width_px: 1.0,
            visible_depth_ratio: 0.1,
            min_sections: 3,
            smooth_in_time: true,
            drift_per_frame: None,
        }
    }
}

/// What the tracker found of one wrinkle in one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum WrinkleStatus {
    /// Paint found and the fitted depth shows a wrinkle.
    Visible,
    /// Paint found, but the fitted depth is (near) zero: the skin is smooth there.
    Absent,
    /// Too little paint found (occluded or out of view).
    Lost,
}

impl WrinkleStatus {
    /// Lower-case name as written to MCAP.
    pub fn name(self) -> &'static str {
        match self {
            WrinkleStatus::Visible => "visible",
            WrinkleStatus::Absent => "absent",
            WrinkleStatus::Lost => "lost",
        }
    }
}

/// One wrinkle in one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameWrinkle {
    /// Wrinkle id: index of its label patch (label patches ordered by centroid row, then column).
    pub id: usize,
    /// Status.
    pub status: WrinkleStatus,
    /// Pixels of its patch.
    pub patch_px: usize,
    /// Valley spline and cross-sections (`None` when lost).
    pub tracked: Option<TrackedWrinkle>,
}

/// Median of a non-empty slice.
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// The wrinkle patches of the training label, ordered by centroid (row, column).
fn label_patches(label: &[bool], w: usize, h: usize, min_px: usize) -> Vec<Vec<usize>> {
    let mut patches: Vec<Vec<usize>> = connected_components(label, w, h)
        .into_iter()
        .filter(|c| c.len() >= min_px)
        .collect();
    let centroid = |c: &[usize]| {
        let n = c.len() as f64;
        let (sx, sy) = c.iter().fold((0.0, 0.0), |(a, b), &i| {
            (a + (i % w) as f64, b + (i / w) as f64)
        });
        (sy / n, sx / n)
    };
    patches.sort_by(|a, b| {
        let (ca, cb) = (centroid(a), centroid(b));
        ca.0.total_cmp(&cb.0).then(ca.1.total_cmp(&cb.1))
    });
    patches
}

/// Track the labelled wrinkles through `frames` (frame 0 is the labelled one). Returns, per
/// frame, one [`FrameWrinkle`] per label patch. `on_frame` is called after each frame.
pub fn track_video(
    label: &[bool],
    frames: &[RgbImage],
    settings: &VideoTrackSettings,
    on_frame: &(dyn Fn() + Sync),
) -> Result<Vec<Vec<FrameWrinkle>>> {
    let Some(first) = frames.first() else {
        return Ok(Vec::new());
    };
    let (w, h) = (first.width, first.height);
    let refs: Vec<&RgbImage> = frames.iter().collect();
    // classify in parallel chunks (the SVM is trained once, deterministically)
    let masks = classify_frames(first, label, &refs, &settings.svm)?;
    let r = settings.morphology_radius_px;
    let cleaned: Vec<Vec<Vec<usize>>> = masks
        .par_iter()
        .map(|m| connected_components(&close(&open(m, w, h, r), w, h, r), w, h))
        .collect();
    let mut previous = label_patches(label, w, h, settings.min_label_patch_px);
    let mut out = Vec::with_capacity(frames.len());
    for (image, comps) in frames.iter().zip(&cleaned) {
        // each classified patch goes to the wrinkle whose dilated previous patch it overlaps most
        let reach: Vec<Vec<bool>> = previous
            .iter()
            .map(|p| {
                let mut m = vec![false; w * h];
                for &i in p {
                    m[i] = true;
                }
                dilate(&m, w, h, settings.search_radius_px)
            })
            .collect();
        let mut patches: Vec<Vec<usize>> = vec![Vec::new(); previous.len()];
        for c in comps.iter().filter(|c| c.len() >= settings.min_patch_px) {
            let best = reach
                .iter()
                .enumerate()
                .map(|(k, m)| (k, c.iter().filter(|&&i| m[i]).count()))
                .max_by_key(|&(_, n)| n);
            if let Some((k, n)) = best
                && n > 0
            {
                patches[k].extend_from_slice(c);
            }
        }
        let mut row = Vec::with_capacity(patches.len());
        for (id, patch) in patches.iter_mut().enumerate() {
            patch.sort_unstable();
            let tracked = if patch.len() >= 3 * settings.track.n_control.max(4) {
                track_wrinkle(image, patch, &settings.track).ok()
            } else {
                None
            };
            let status = match &tracked {
                None => WrinkleStatus::Lost,
                Some(t) => {
                    let ok: Vec<_> = t.sections.iter().filter(|s| s.converged).collect();
                    let d = median(ok.iter().map(|s| s.depth_px).collect());
                    let w = median(ok.iter().map(|s| s.width_px).collect());
                    if ok.len() >= settings.min_sections
                        && d >= settings.min_depth_px
                        && w >= settings.min_width_px
                        && d >= settings.visible_depth_ratio * w
                    {
                        WrinkleStatus::Visible
                    } else {
                        WrinkleStatus::Absent
                    }
                }
            };
            if status != WrinkleStatus::Lost {
                previous[id].clone_from(patch);
            }
            row.push(FrameWrinkle {
                id,
                status,
                patch_px: patch.len(),
                tracked,
            });
        }
        out.push(row);
        on_frame();
    }
    if settings.smooth_in_time {
        smooth_profiles(&mut [&mut out], settings.drift_per_frame);
    }
    Ok(out)
}

/// The pooled estimate of a visible wrinkle, if it has one with a usable covariance.
fn estimate(fw: &FrameWrinkle) -> Option<FrameEstimate> {
    if fw.status != WrinkleStatus::Visible {
        return None;
    }
    FrameEstimate::of(fw.tracked.as_ref()?.profile.as_ref()?)
}

/// The runs of consecutive frames in which wrinkle `k` is visible with a pooled profile: (first
/// frame, estimates).
fn visible_runs(frames: &[Vec<FrameWrinkle>], k: usize) -> Vec<(usize, Vec<FrameEstimate>)> {
    let mut runs = Vec::new();
    let mut t = 0;
    while t < frames.len() {
        let run: Vec<FrameEstimate> = frames[t..]
            .iter()
            .map_while(|row| row.get(k).and_then(estimate))
            .collect();
        if run.is_empty() {
            t += 1;
        } else {
            t += run.len();
            runs.push((t - run.len(), run));
        }
    }
    runs
}

/// [`smooth_in_time`] over every run of consecutive frames in which a wrinkle is visible with a
/// pooled profile, in every camera of `cameras` (each `[frame][wrinkle]` as [`track_video`]
/// returns them), with the process noise `drift` or, when `None`, the one that makes the
/// wrinkle's runs in all cameras most likely ([`estimate_time_noise`]; its relative changes per
/// frame are the same in every camera, wrinkle k being the same label patch in each): the
/// profile takes the smoothed (d, w) and covariance, every cross-section is shifted by the same
/// change of d and w.
pub fn smooth_profiles(cameras: &mut [&mut Vec<Vec<FrameWrinkle>>], drift: Option<[TimeModel; 2]>) {
    let n_wrinkles = cameras
        .iter()
        .map(|c| c.first().map_or(0, Vec::len))
        .max()
        .unwrap_or(0);
    for k in 0..n_wrinkles {
        let runs: Vec<Vec<(usize, Vec<FrameEstimate>)>> =
            cameras.iter().map(|c| visible_runs(c, k)).collect();
        let q = drift.unwrap_or_else(|| {
            let all: Vec<Vec<FrameEstimate>> =
                runs.iter().flatten().map(|(_, r)| r.clone()).collect();
            estimate_time_noise(&all)
        });
        for (frames, runs) in cameras.iter_mut().zip(&runs) {
            for (t, run) in runs {
                let smoothed = smooth_in_time(run, q);
                for (i, (old, new)) in run.iter().zip(&smoothed).enumerate() {
                    let Some(tw) = frames[t + i][k].tracked.as_mut() else {
                        continue;
                    };
                    let (dd, dw) = (new.depth_px - old.depth_px, new.width_px - old.width_px);
                    for s in &mut tw.sections {
                        s.depth_px = (s.depth_px + dd).max(0.0);
                        s.width_px = (s.width_px + dw).max(MIN_WIDTH_PX);
                    }
                    if let Some(p) = tw.profile.as_mut() {
                        p.depth_px = new.depth_px;
                        p.width_px = new.width_px;
                        p.depth_sigma_px = new.cov_px2[0].max(0.0).sqrt();
                        p.width_sigma_px = new.cov_px2[2].max(0.0).sqrt();
                        p.depth_width_cov_px2 = new.cov_px2[1];
                    }
                }
            }
        }
    }
}
