//! Base-material measurements from a `capture.mcap` (thesis §8.3 input; §8.5: probe sessions on
//! 4 × 5 × 2.5 cm blocks of each base material).
//!
//! A capture of a homogeneous block (read with `softcap_mcap::CaptureData::read`, so this stage
//! does not depend on another stage's crate) becomes [`BaseMeasurements`]:
//!
//! - **Block placement**: the object markers sit on the block's top face; the block is the box
//!   of [`CaptureMappingSettings::block_size_m`] whose top is at the mean rest height of the
//!   markers and whose lateral centre is the centre of the markers' rest bounding box (or
//!   [`CaptureMappingSettings::block_origin_m`] when given). Bottom face fixed (the table).
//! - **Markers → nodes**: the mesh is a regular grid of `cells`; each object marker is matched
//!   to the nearest top-face node, which must lie within `marker_snap_m` (an error names the
//!   marker otherwise), two markers on one node are an error. Displacements are measured
//!   positions minus rest positions (`SessionInfo::rest_positions_m`).
//! - **Examples**: one probe location (`CaptureData::probe_locations`) gives
//!   `levels_per_location` examples: the loading-phase frames whose force is nearest
//!   k/levels × the peak force (the last one is the peak frame). The force vector is the
//!   recorded force on the object; the probed patch is the top nodes within the tip radius
//!   (`SessionInfo::tip_radius_m`, or `probe_radius_m` if larger) of the tip's lateral position.

use crate::error::{DesignError, Result};
use crate::fit::{BaseMeasurements, ProbeExample};
use serde::{Deserialize, Serialize};
use softcap_mcap::capture::{CaptureData, ProbeLocationSettings};
use std::collections::BTreeMap;

/// How a capture is mapped onto the block mesh (see module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CaptureMappingSettings {
    /// Block width × length × height \[m\] (thesis §8.5: 4 × 5 × 2.5 cm).
    pub block_size_m: [f64; 3],
    /// Minimum corner of the block in the capture's world frame \[m\]; `None`: from the markers.
    pub block_origin_m: Option<[f64; 3]>,
    /// Grid cells of the tet mesh (x, y, z).
    pub cells: [usize; 3],
    /// Largest marker-to-node distance accepted \[m\].
    pub marker_snap_m: f64,
    /// Minimum radius of the probed patch \[m\].
    pub probe_radius_m: f64,
    /// Examples taken per probe location (force levels up to the peak).
    pub levels_per_location: usize,
    /// Grouping of frames into probe locations.
    pub locations: ProbeLocationSettings,
}

impl Default for CaptureMappingSettings {
    fn default() -> Self {
        Self {
            block_size_m: [0.04, 0.05, 0.025],
            block_origin_m: None,
            cells: [4, 5, 2],
            marker_snap_m: 0.002,
            probe_radius_m: 0.011,
            levels_per_location: 1,
            locations: ProbeLocationSettings::default(),
        }
    }
}

/// Maps a capture of a homogeneous block onto [`BaseMeasurements`] (see module docs).
pub fn measurements_from_capture(
    capture: &CaptureData,
    settings: &CaptureMappingSettings,
) -> Result<BaseMeasurements> {
    let path = capture.path.clone();
    let bad = |reason: String| DesignError::File {
        path: path.clone(),
        reason,
    };
    let s = &capture.session;
    let n_obj = s.object_markers.min(s.rest_positions_m.len());
    if n_obj == 0 {
        return Err(bad(
            "/capture/session: no object markers with rest positions".into(),
        ));
    }
    let rest = &s.rest_positions_m[..n_obj];
    let [w, l, h] = settings.block_size_m;
    let origin = match settings.block_origin_m {
        Some(o) => o,
        None => {
            let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
            let mut z = 0.0;
            for p in rest {
                for c in 0..2 {
                    lo[c] = lo[c].min(p[c]);
                    hi[c] = hi[c].max(p[c]);
                }
                z += p[2];
            }
            let top = z / n_obj as f64;
            [
                0.5 * (lo[0] + hi[0]) - 0.5 * w,
                0.5 * (lo[1] + hi[1]) - 0.5 * l,
                top - h,
            ]
        }
    };
    let [nx, ny, nz] = settings.cells.map(|c| c.max(1));
    let mesh = softcap_mesh::box_tet_mesh(
        origin,
        [origin[0] + w, origin[1] + l, origin[2] + h],
        [nx, ny, nz],
    );
    let eps = 1e-9 * (w + l + h);
    let z_top = origin[2] + h;
    let fixed_nodes: Vec<usize> = (0..mesh.vertices.len())
        .filter(|&i| (mesh.vertices[i].z - origin[2]).abs() < eps)
        .collect();
    let top: Vec<usize> = (0..mesh.vertices.len())
        .filter(|&i| (mesh.vertices[i].z - z_top).abs() < eps)
        .collect();
    // Marker → nearest top node.
    let mut marker_node = Vec::with_capacity(n_obj);
    let mut used: BTreeMap<usize, usize> = BTreeMap::new();
    for (k, p) in rest.iter().enumerate() {
        let (node, d) = top
            .iter()
            .map(|&i| {
                let v = mesh.vertices[i];
                let d = ((v.x - p[0]).powi(2) + (v.y - p[1]).powi(2) + (v.z - p[2]).powi(2)).sqrt();
                (i, d)
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((usize::MAX, f64::INFINITY));
        let id = &s.marker_ids[k.min(s.marker_ids.len().saturating_sub(1))];
        if d > settings.marker_snap_m {
            return Err(bad(format!(
                "/capture/session rest_positions_m[{k}] (marker {id}): {:.2} mm from the nearest top-face node of the {}×{}×{} block mesh (limit {:.2} mm)",
                d * 1e3,
                nx,
                ny,
                nz,
                settings.marker_snap_m * 1e3
            )));
        }
        if let Some(other) = used.insert(node, k) {
            return Err(bad(format!(
                "markers {other} and {k} both map to top node {node}; refine `cells`"
            )));
        }
        marker_node.push(node);
    }
    let radius = settings.probe_radius_m.max(s.tip_radius_m);
    let locations = capture.probe_locations(&settings.locations);
    if locations.is_empty() {
        return Err(bad(
            "/capture/probe: no probe contact (no frame with force above the contact threshold)"
                .into(),
        ));
    }
    let levels = settings.levels_per_location.max(1);
    let mut examples = Vec::new();
    for loc in &locations {
        let peak_frame = loc.frames[loc.peak];
        let mut chosen: Vec<usize> = Vec::new();
        for k in 1..=levels {
            let goal = loc.peak_force_n * k as f64 / levels as f64;
            let best = loc.frames[..=loc.peak]
                .iter()
                .copied()
                .min_by(|&a, &b| {
                    let fa = capture.frames[a]
                        .probe
                        .map_or(0.0, |p| p.force_magnitude_n());
                    let fb = capture.frames[b]
                        .probe
                        .map_or(0.0, |p| p.force_magnitude_n());
                    (fa - goal).abs().total_cmp(&(fb - goal).abs())
                })
                .unwrap_or(peak_frame);
            if !chosen.contains(&best) {
                chosen.push(best);
            }
        }
        for fi in chosen {
            let frame = &capture.frames[fi];
            let Some(probe) = frame.probe else { continue };
            let (Some(tip), Some(force)) = (probe.tip_m, probe.force_n) else {
                continue;
            };
            let patch_nodes: Vec<usize> = top
                .iter()
                .copied()
                .filter(|&i| {
                    let v = mesh.vertices[i];
                    ((v.x - tip[0]).powi(2) + (v.y - tip[1]).powi(2)).sqrt() <= radius + eps
                })
                .collect();
            if patch_nodes.is_empty() {
                return Err(bad(format!(
                    "/capture/probe frame {}: no top node within {:.1} mm of the tip",
                    frame.frame,
                    radius * 1e3
                )));
            }
            let mut marker_nodes = Vec::new();
            let mut displacements_m = Vec::new();
            for (k, &node) in marker_node.iter().enumerate() {
                let Some(m) = frame.marker(k as u32) else {
                    continue;
                };
                if !(m.visible || m.filled) {
                    continue;
                }
                marker_nodes.push(node);
                displacements_m.push([
                    m.position_m[0] - rest[k][0],
                    m.position_m[1] - rest[k][1],
                    m.position_m[2] - rest[k][2],
                ]);
            }
            if marker_nodes.is_empty() {
                return Err(bad(format!(
                    "/capture/markers frame {}: no object marker observed",
                    frame.frame
                )));
            }
            examples.push(ProbeExample {
                patch_nodes,
                force_n: force,
                marker_nodes,
                displacements_m,
            });
        }
    }
    Ok(BaseMeasurements {
        mesh,
        fixed_nodes,
        examples,
    })
}
