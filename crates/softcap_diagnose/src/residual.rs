//! Residuals between the recording and a simulation of it, their decomposition into components
//! (normal / tangential to the surface, along gravity, along the probe axis) and the *located*
//! table: RMS per (region, phase, component), largest first (DESIGN.md "Missing-physics diagnosis" 1).

use crate::recording::Recording;
use crate::segment::{Phase, Region, Segmentation};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Residual r = measured − simulated per frame and marker (`None` where the marker is unobserved).
pub type Residuals = Vec<Vec<Option<Vector3<f64>>>>;

/// Mean residual of every marker over the rest frames (zero when never seen at rest): what a
/// template that differs from the observed rest shape adds to every frame.
pub fn rest_mean(
    res: &[Vec<Option<Vector3<f64>>>],
    seg: &Segmentation,
    num_markers: usize,
) -> Vec<Vector3<f64>> {
    let mut acc = vec![(Vector3::zeros(), 0usize); num_markers];
    for (k, row) in res.iter().enumerate() {
        if seg.phases[k] == Phase::Rest {
            for (m, r) in row.iter().enumerate() {
                if let Some(r) = r {
                    acc[m].0 += r;
                    acc[m].1 += 1;
                }
            }
        }
    }
    acc.into_iter()
        .map(|(a, n)| if n > 0 { a / n as f64 } else { a })
        .collect()
}

/// A residual component.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Component {
    /// Along the outward surface normal at the marker.
    Normal,
    /// In the tangent plane at the marker (magnitude).
    Tangential,
    /// Along gravity.
    Gravity,
    /// Along the probe axis of the frame (last contact axis outside contact).
    Axis,
    /// The whole 3-D residual.
    Total,
}

impl Component {
    /// All components.
    pub const ALL: [Component; 5] = [
        Component::Total,
        Component::Normal,
        Component::Tangential,
        Component::Gravity,
        Component::Axis,
    ];
    /// The name used in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Component::Normal => "normal",
            Component::Tangential => "tangential",
            Component::Gravity => "gravity",
            Component::Axis => "probe-axis",
            Component::Total => "total",
        }
    }
}

/// `measured − simulated` for every observed marker.
pub fn residuals(rec: &Recording, simulated_m: &[Vec<Vector3<f64>>]) -> Residuals {
    rec.frames
        .iter()
        .zip(simulated_m)
        .map(|(f, sim)| {
            f.markers_m
                .iter()
                .zip(sim)
                .map(|(m, s)| m.map(|m| m - s))
                .collect()
        })
        .collect()
}

/// Component `c` of residual `r` at a marker with outward normal `normal`, for a frame whose probe
/// axis is `axis`, with unit gravity direction `gravity_dir`. Normal, gravity and axis components
/// are signed; tangential and total are magnitudes.
pub fn component(
    r: &Vector3<f64>,
    c: Component,
    normal: &Vector3<f64>,
    gravity_dir: &Vector3<f64>,
    axis: &Vector3<f64>,
) -> f64 {
    match c {
        Component::Normal => r.dot(normal),
        Component::Tangential => (r - normal * r.dot(normal)).norm(),
        Component::Gravity => r.dot(gravity_dir),
        Component::Axis => r.dot(axis),
        Component::Total => r.norm(),
    }
}

/// Probe axis per frame: the frame's axis while in contact, the last contact axis otherwise (the
/// first location's axis before any contact).
pub fn frame_axes(rec: &Recording, seg: &Segmentation) -> Vec<Vector3<f64>> {
    let mut last = seg
        .locations
        .first()
        .map(|l| l.axis)
        .unwrap_or_else(Vector3::zeros);
    rec.frames
        .iter()
        .zip(&seg.phases)
        .map(|(f, p)| {
            if p.in_contact() {
                last = f.axis;
            }
            last
        })
        .collect()
}

/// One row of the located table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Located {
    /// `probed`, `attached` or `free`.
    pub region: String,
    /// `rest`, `loading`, `hold`, `unloading` or `released`.
    pub phase: String,
    /// `total`, `normal`, `tangential`, `gravity` or `probe-axis`.
    pub component: String,
    /// RMS of the component over the cell, m.
    pub rmse_m: f64,
}

/// RMS per (region, phase, component) over the observed residuals, sorted by RMS descending
/// (ties by name: deterministic). Cells without samples are left out.
pub fn locate(rec: &Recording, seg: &Segmentation, res: &Residuals) -> Vec<Located> {
    let g = rec.gravity_dir();
    let axes = frame_axes(rec, seg);
    let mut acc: BTreeMap<(Region, Phase, Component), (f64, usize)> = BTreeMap::new();
    for (k, row) in res.iter().enumerate() {
        let phase = seg.phases[k];
        for (m, r) in row.iter().enumerate() {
            let Some(r) = r else { continue };
            let region = seg.regions[m];
            for c in Component::ALL {
                if c == Component::Gravity && g == Vector3::zeros() {
                    continue;
                }
                let v = component(r, c, &rec.normals[m], &g, &axes[k]);
                let e = acc.entry((region, phase, c)).or_insert((0.0, 0));
                e.0 += v * v;
                e.1 += 1;
            }
        }
    }
    let mut out: Vec<Located> = acc
        .into_iter()
        .map(|((region, phase, c), (s, n))| Located {
            region: region.name().into(),
            phase: phase.name().into(),
            component: c.name().into(),
            rmse_m: (s / n as f64).sqrt(),
        })
        .collect();
    out.sort_by(|a, b| b.rmse_m.total_cmp(&a.rmse_m));
    out
}

/// RMS of the 3-D residual norm over the frames selected by `keep`, m (NaN without samples).
pub fn rmse_m(res: &Residuals, keep: impl Fn(usize) -> bool) -> f64 {
    rms_where_m(res, |k, _| keep(k)).unwrap_or(f64::NAN)
}

/// RMS of the 3-D residual norm over the observed (frame `k`, marker `m`) samples selected by
/// `keep(k, m)`, m; `None` without samples. The one masked residual RMS: [`rmse_m`] (frames),
/// the diagnosis's (region, phase) before/after table and the floor harness use it.
pub fn rms_where_m(res: &Residuals, keep: impl Fn(usize, usize) -> bool) -> Option<f64> {
    let (mut s, mut n) = (0.0, 0usize);
    for (k, row) in res.iter().enumerate() {
        for (m, r) in row.iter().enumerate() {
            if let Some(r) = r
                && keep(k, m)
            {
                s += r.norm_squared();
                n += 1;
            }
        }
    }
    (n > 0).then(|| (s / n as f64).sqrt())
}

/// Marker-noise estimate σ (per coordinate, m) from second differences of marker trajectories
/// over frames outside contact: for white noise, Var(x_{k+1} − 2x_k + x_{k−1}) = 6σ². The median
/// absolute value is used (robust to the few frames where the object still moves):
/// σ ≈ median|d| / (0.6745 √6).
pub fn noise_sigma_m(rec: &Recording, seg: &Segmentation) -> f64 {
    let mut d = Vec::new();
    for k in 1..rec.frames.len().saturating_sub(1) {
        if seg.phases[k - 1].in_contact()
            || seg.phases[k].in_contact()
            || seg.phases[k + 1].in_contact()
        {
            continue;
        }
        for m in 0..rec.num_markers() {
            if let (Some(a), Some(b), Some(c)) = (
                rec.frames[k - 1].markers_m[m],
                rec.frames[k].markers_m[m],
                rec.frames[k + 1].markers_m[m],
            ) {
                for v in (a - 2.0 * b + c).iter() {
                    d.push(v.abs());
                }
            }
        }
    }
    if d.is_empty() {
        return 0.0;
    }
    d.sort_by(f64::total_cmp);
    d[d.len() / 2] / (0.6745 * 6f64.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn components_of_a_known_residual() {
        let r = Vector3::new(3.0, 4.0, 12.0);
        let n = Vector3::z();
        let g = -Vector3::z();
        let a = Vector3::x();
        assert_eq!(component(&r, Component::Normal, &n, &g, &a), 12.0);
        assert_eq!(component(&r, Component::Tangential, &n, &g, &a), 5.0);
        assert_eq!(component(&r, Component::Gravity, &n, &g, &a), -12.0);
        assert_eq!(component(&r, Component::Axis, &n, &g, &a), 3.0);
        assert_eq!(component(&r, Component::Total, &n, &g, &a), 13.0);
    }

    #[test]
    fn masked_rms_counts_only_selected_observed_samples() {
        // frame 0: markers (3,4,0) [norm 5] and unobserved; frame 1: (0,0,1) and (0,0,2)
        let res: Residuals = vec![
            vec![Some(Vector3::new(3.0, 4.0, 0.0)), None],
            vec![
                Some(Vector3::new(0.0, 0.0, 1.0)),
                Some(Vector3::new(0.0, 0.0, 2.0)),
            ],
        ];
        let all = rms_where_m(&res, |_, _| true).unwrap();
        assert!((all - ((25.0 + 1.0 + 4.0) / 3.0f64).sqrt()).abs() < 1e-15);
        let marker1 = rms_where_m(&res, |_, m| m == 1).unwrap();
        assert!((marker1 - 2.0).abs() < 1e-15);
        assert_eq!(rms_where_m(&res, |k, m| k == 0 && m == 1), None);
        assert!((rmse_m(&res, |k| k == 1) - 2.5f64.sqrt()).abs() < 1e-15);
        assert!(rmse_m(&res, |_| false).is_nan());
    }
}
