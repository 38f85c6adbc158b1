//! Phase segmentation of the force trace (rest, loading, hold, unloading, released), grouping of
//! contact frames into probe *locations* by the tip position (the held-out unit of
//! leave-one-location-out), and the marker regions (probed / attached / free).

use crate::recording::Recording;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

pub use softcap_mcap::Phase;

/// Region of a marker.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Region {
    /// Within the near radius of a probe location.
    Probed,
    /// On the support plane (boundary condition region).
    Attached,
    /// Everything else.
    Free,
}

impl Region {
    /// All regions.
    pub const ALL: [Region; 3] = [Region::Probed, Region::Attached, Region::Free];
    /// The name used in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Region::Probed => "probed",
            Region::Attached => "attached",
            Region::Free => "free",
        }
    }
}

/// Settings of the segmentation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SegmentSettings {
    /// A frame is in contact when ‖f‖ exceeds this fraction of the session's peak force …
    pub contact_force_fraction: f64,
    /// … and this absolute force, N.
    pub contact_force_min_n: f64,
    /// Contact runs whose peak tip positions lie closer than this belong to one location, m.
    pub same_location_radius_m: f64,
    /// In a contact run, frames whose depth (or force, when the tip does not move) is within this
    /// fraction of the run's maximum form the hold.
    pub hold_fraction: f64,
    /// Markers within this distance of a location's contact point are `probed`, m
    /// (0 → 4 × the probe tip radius, at least 5 mm).
    pub near_radius_m: f64,
}

impl Default for SegmentSettings {
    fn default() -> Self {
        Self {
            contact_force_fraction: 0.05,
            contact_force_min_n: 0.01,
            same_location_radius_m: 0.004,
            hold_fraction: 0.03,
            near_radius_m: 0.0,
        }
    }
}

/// One probe location: the frames of its ramp/hold/release.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Location {
    /// Index of the location (order of first contact).
    pub index: usize,
    /// Tip position at the frame of peak force, m.
    pub peak_tip_m: Vector3<f64>,
    /// Tip position at the first contact frame, m.
    pub contact_tip_m: Vector3<f64>,
    /// Mean probe axis over the contact frames.
    pub axis: Vector3<f64>,
    /// Frame (index into `Recording::frames`) of peak force.
    pub peak_frame: usize,
    /// Peak ‖f‖, N.
    pub peak_force_n: f64,
    /// Contact frames (indices into `Recording::frames`), ascending.
    pub contact_frames: Vec<usize>,
}

/// Phases, locations and regions of a recording.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Segmentation {
    /// Phase of every frame.
    pub phases: Vec<Phase>,
    /// Fold (location) of every frame: contact frames belong to their location, released frames to
    /// the last location touched before them, rest frames to none (always training).
    pub fold_of_frame: Vec<Option<usize>>,
    /// The locations.
    pub locations: Vec<Location>,
    /// Region of every marker.
    pub regions: Vec<Region>,
    /// The near radius used for `probed`, m.
    pub near_radius_m: f64,
}

impl Segmentation {
    /// The largest probe force of the session, N: the maximum of the locations' peak forces
    /// (0 without locations).
    pub fn peak_force_n(&self) -> f64 {
        self.locations
            .iter()
            .map(|l| l.peak_force_n)
            .fold(0.0, f64::max)
    }

    /// Segments `rec` (see the module docs): contact runs of the probe force, extended back over
    /// the approach a late force channel misses; runs at one place are one location; phases
    /// inside each run, released frames after it; marker regions from the rest shape.
    pub fn new(rec: &Recording, settings: &SegmentSettings) -> Self {
        let n = rec.frames.len();
        let fmag: Vec<f64> = rec.frames.iter().map(|f| f.force_n.norm()).collect();
        let mut runs = contact_runs(rec, &fmag, settings);
        extend_runs_back(rec, &mut runs, settings);

        let mut phases = vec![Phase::Rest; n];
        let mut fold_of_frame = vec![None; n];
        let mut locations: Vec<Location> = Vec::new();
        let mut run_location = Vec::with_capacity(runs.len());
        for &(s, e) in &runs {
            let li = add_run(rec, &fmag, s, e, settings, &mut locations);
            run_location.push(li);
            for (k, phase) in (s..e).zip(run_phases(rec, &fmag, s, e, settings)) {
                phases[k] = phase;
                fold_of_frame[k] = Some(li);
            }
        }
        // Released frames: after a run until the next one, fold of the preceding run.
        for (r, &(_, e)) in runs.iter().enumerate() {
            let next = runs.get(r + 1).map(|x| x.0).unwrap_or(n);
            for k in e..next {
                phases[k] = Phase::Released;
                fold_of_frame[k] = Some(run_location[r]);
            }
        }
        for l in &mut locations {
            let a: Vector3<f64> = l.contact_frames.iter().map(|&k| rec.frames[k].axis).sum();
            l.axis = a.try_normalize(1e-12).unwrap_or_else(Vector3::zeros);
        }

        let near_radius_m = if settings.near_radius_m > 0.0 {
            settings.near_radius_m
        } else {
            (4.0 * rec.tip_radius_m).max(0.005)
        };
        let regions = marker_regions(rec, &locations, near_radius_m);
        Segmentation {
            phases,
            fold_of_frame,
            locations,
            regions,
            near_radius_m,
        }
    }

    /// Number of folds (locations).
    pub fn num_folds(&self) -> usize {
        self.locations.len()
    }

    /// The hold frames of location `l`, in time order.
    pub fn hold_frames(&self, l: &Location) -> Vec<usize> {
        l.contact_frames
            .iter()
            .copied()
            .filter(|&k| self.phases[k] == Phase::Hold)
            .collect()
    }

    /// The frames of location `l` in contact (loading, hold or unloading), in time order.
    pub fn in_contact_frames(&self, l: &Location) -> Vec<usize> {
        l.contact_frames
            .iter()
            .copied()
            .filter(|&k| self.phases[k].in_contact())
            .collect()
    }

    /// The markers near location `l`: those whose rest position lies within `near_radius_m` of its
    /// contact point (its probed markers), ascending.
    pub fn near_markers(&self, rec: &Recording, l: &Location) -> Vec<usize> {
        (0..rec.num_markers())
            .filter(|&m| (rec.rest_markers_m[m] - l.contact_tip_m).norm() <= self.near_radius_m)
            .collect()
    }
}

/// Maximal runs `[s, e)` of contact frames (‖f‖ above the contact threshold), split where the tip
/// jumps to another place (a lagging force may not drop below the threshold between two
/// locations).
fn contact_runs(rec: &Recording, fmag: &[f64], settings: &SegmentSettings) -> Vec<(usize, usize)> {
    let n = fmag.len();
    let peak = fmag.iter().cloned().fold(0.0, f64::max);
    let thr = (settings.contact_force_fraction * peak).max(settings.contact_force_min_n);
    let contact: Vec<bool> = fmag.iter().map(|&f| f > thr && peak > 0.0).collect();
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut i = 0;
    while i < n {
        if contact[i] {
            let s = i;
            i += 1;
            while i < n
                && contact[i]
                && (rec.frames[i].tip_m - rec.frames[i - 1].tip_m).norm()
                    < settings.same_location_radius_m
            {
                i += 1;
            }
            runs.push((s, i));
            // The run ended on a tip jump with the force still above the threshold: while the
            // force keeps falling it trails the contact just left (a late or lagging force
            // channel — clock offset, sensor lag), so those frames are released frames of
            // that run, not a new location; a rising force starts the next run.
            if i < n && contact[i] {
                while i < n && contact[i] && fmag[i] <= fmag[i - 1] {
                    i += 1;
                }
            }
        } else {
            i += 1;
        }
    }
    runs
}

/// Geometry leads a late force channel (clock offset, sensor lag): extends each run back over
/// the frames where the tip was already pressing in at the same place — the approach frames
/// whose depth along the probe axis rises monotonically into the run, after the shallowest
/// frame of the approach (which stays out of contact). With an on-time force channel the frame
/// before a run is that shallowest frame, so nothing changes.
fn extend_runs_back(rec: &Recording, runs: &mut [(usize, usize)], settings: &SegmentSettings) {
    for r in 0..runs.len() {
        let (s, e) = runs[r];
        let floor = if r > 0 { runs[r - 1].1 } else { 0 };
        let Some(axis) = rec.frames[s].axis.try_normalize(1e-12) else {
            continue;
        };
        let tip_s = rec.frames[s].tip_m;
        let lateral = |k: usize| {
            let d = rec.frames[k].tip_m - tip_s;
            (d - axis * axis.dot(&d)).norm()
        };
        let depth = |k: usize| (rec.frames[k].tip_m - tip_s).dot(&axis);
        // tolerance for the tracked tip's noise (a hold is flat up to it)
        let tol = 0.1 * rec.tip_radius_m.max(1e-3);
        let mut j = s;
        while j > floor
            && lateral(j - 1) < settings.same_location_radius_m
            && depth(j - 1) <= depth(j) + tol
        {
            j -= 1;
        }
        let shallow = depth(j) + tol;
        if let Some(first) = (j..s).find(|&k| depth(k) > shallow)
            && first < s
        {
            runs[r] = (first, e);
        }
    }
}

/// Adds contact run `[s, e)` to the location within `same_location_radius_m` of its peak's tip
/// (a new location when none is); returns the location's index.
fn add_run(
    rec: &Recording,
    fmag: &[f64],
    s: usize,
    e: usize,
    settings: &SegmentSettings,
    locations: &mut Vec<Location>,
) -> usize {
    let pk = (s..e)
        .max_by(|&a, &b| fmag[a].total_cmp(&fmag[b]).then(b.cmp(&a)))
        .unwrap_or(s);
    let tip = rec.frames[pk].tip_m;
    let found = locations
        .iter()
        .position(|l| (l.peak_tip_m - tip).norm() < settings.same_location_radius_m);
    match found {
        Some(li) => {
            let l = &mut locations[li];
            l.contact_frames.extend(s..e);
            if fmag[pk] > l.peak_force_n {
                l.peak_force_n = fmag[pk];
                l.peak_frame = pk;
                l.peak_tip_m = tip;
            }
            li
        }
        None => {
            locations.push(Location {
                index: locations.len(),
                peak_tip_m: tip,
                contact_tip_m: rec.frames[s].tip_m,
                axis: Vector3::zeros(),
                peak_frame: pk,
                peak_force_n: fmag[pk],
                contact_frames: (s..e).collect(),
            });
            locations.len() - 1
        }
    }
}

/// The phases of the frames of contact run `[s, e)`: loading, hold within `hold_fraction` of
/// the peak, unloading — of the depth along the run's mean axis when the tip moves, else of ‖f‖.
fn run_phases(
    rec: &Recording,
    fmag: &[f64],
    s: usize,
    e: usize,
    settings: &SegmentSettings,
) -> Vec<Phase> {
    let axis_sum: Vector3<f64> = (s..e).map(|k| rec.frames[k].axis).sum();
    let axis = axis_sum.try_normalize(1e-12).unwrap_or_else(Vector3::zeros);
    let start_tip = if s > 0 {
        rec.frames[s - 1].tip_m
    } else {
        rec.frames[s].tip_m
    };
    let depth: Vec<f64> = (s..e)
        .map(|k| (rec.frames[k].tip_m - start_tip).dot(&axis))
        .collect();
    let dmax = depth.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let dmin = depth.iter().cloned().fold(f64::INFINITY, f64::min);
    let signal: Vec<f64> = if dmax - dmin > 0.2 * rec.tip_radius_m.max(1e-4) {
        depth.iter().map(|d| d - dmin).collect()
    } else {
        (s..e).map(|k| fmag[k]).collect()
    };
    let smax = signal.iter().cloned().fold(0.0, f64::max);
    let level = (1.0 - settings.hold_fraction) * smax;
    let first = signal.iter().position(|&v| v >= level).unwrap_or(0);
    let last = signal.iter().rposition(|&v| v >= level).unwrap_or(0);
    (0..signal.len())
        .map(|j| {
            if j < first {
                Phase::Loading
            } else if j > last {
                Phase::Unloading
            } else if first == last {
                Phase::Loading
            } else {
                Phase::Hold
            }
        })
        .collect()
}

/// Each marker's region: `attached` on the support plane, `probed` within `near_radius_m` of a
/// location's first contact point, else `free`.
fn marker_regions(rec: &Recording, locations: &[Location], near_radius_m: f64) -> Vec<Region> {
    rec.rest_markers_m
        .iter()
        .map(|p| {
            if let Some(s) = &rec.support
                && s.distance_m(p).abs() <= s.tolerance_m
            {
                return Region::Attached;
            }
            if locations
                .iter()
                .any(|l| (l.contact_tip_m - p).norm() <= near_radius_m)
            {
                Region::Probed
            } else {
                Region::Free
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::{Frame, SupportPlane};

    /// Two ramp/hold/release locations, then a return to the first.
    fn toy() -> Recording {
        let mut frames = Vec::new();
        let profile = [0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 0.5, 0.0, 0.0];
        let tips = [
            Vector3::new(0.0, 0.0, 0.01),
            Vector3::new(0.02, 0.0, 0.01),
            Vector3::new(0.0005, 0.0, 0.01),
        ];
        let mut k = 0u64;
        for tip in tips {
            for &p in &profile {
                frames.push(Frame {
                    frame: k,
                    time_s: k as f64 * 0.1,
                    tip_m: tip - Vector3::z() * 0.002 * p,
                    axis: -Vector3::z(),
                    force_n: -Vector3::z() * 2.0 * p,
                    markers_m: vec![None; 2],
                });
                k += 1;
            }
        }
        Recording {
            marker_ids: vec!["a".into(), "b".into()],
            rest_markers_m: vec![Vector3::new(0.0, 0.0, 0.01), Vector3::new(0.05, 0.0, 0.0)],
            normals: vec![Vector3::z(); 2],
            gravity_m_s2: Vector3::new(0.0, 0.0, -9.81),
            support: Some(SupportPlane {
                normal: Vector3::z(),
                offset_m: 0.0,
                tolerance_m: 1e-4,
            }),
            tip_radius_m: 0.002,
            frames,
        }
    }

    #[test]
    fn a_force_trailing_after_the_tip_left_is_not_a_new_location() {
        // The force channel runs two frames late: after the tip jumps to the next location the
        // force is still falling; those frames are released frames of the location just left.
        let mut rec = toy();
        let f: Vec<Vector3<f64>> = rec.frames.iter().map(|x| x.force_n).collect();
        for (k, fr) in rec.frames.iter_mut().enumerate() {
            fr.force_n = if k >= 2 { f[k - 2] } else { Vector3::zeros() };
        }
        // make the tip leave while the late force is still high: shorten the release by moving
        // the tip of frame 7 (second released frame) to the next location already
        rec.frames[7].tip_m = rec.frames[10].tip_m;
        rec.frames[8].tip_m = rec.frames[10].tip_m;
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        assert_eq!(seg.locations.len(), 2, "{:?}", seg.locations);
        assert_eq!(seg.phases[7], Phase::Released);
        assert_eq!(seg.fold_of_frame[8], Some(0));
    }

    #[test]
    fn a_late_force_channel_keeps_the_geometric_ramp_in_contact() {
        // The force arrives three frames late (it starts at the hold): the ramp frames, where the
        // tip already presses in, are still the location's loading frames.
        let mut rec = toy();
        let f: Vec<Vector3<f64>> = rec.frames.iter().map(|x| x.force_n).collect();
        for (k, fr) in rec.frames.iter_mut().enumerate() {
            fr.force_n = if k >= 1 { f[k - 1] } else { Vector3::zeros() };
        }
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        assert_eq!(seg.locations.len(), 2);
        // frame 2 is the first ramp frame (depth 1 mm) but reads no force yet
        assert_eq!(rec.frames[2].force_n.norm(), 0.0);
        assert_eq!(seg.phases[2], Phase::Loading);
        assert_eq!(seg.fold_of_frame[2], Some(0));
        assert_eq!(
            seg.phases[1],
            Phase::Rest,
            "the approach frame stays out of contact"
        );
        // the on-time toy is unchanged (see the next test)
    }

    #[test]
    fn phases_locations_and_regions_of_a_toy_session() {
        let rec = toy();
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        use Phase::*;
        assert_eq!(
            &seg.phases[..9],
            &[
                Rest, Rest, Loading, Hold, Hold, Hold, Unloading, Released, Released
            ]
        );
        assert_eq!(seg.phases[9], Released);
        assert_eq!(seg.locations.len(), 2, "third ramp returns to location 0");
        assert_eq!(seg.fold_of_frame[0], None);
        assert_eq!(seg.fold_of_frame[8], Some(0));
        assert_eq!(seg.fold_of_frame[12], Some(1));
        assert_eq!(seg.fold_of_frame[22], Some(0));
        assert_eq!(seg.locations[0].contact_frames.len(), 10);
        assert!((seg.locations[0].peak_force_n - 2.0).abs() < 1e-12);
        assert_eq!(seg.regions, vec![Region::Probed, Region::Attached]);
    }
}
