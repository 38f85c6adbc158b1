//! Multi-view correspondence of unlabeled blobs (epipolar constraint, third-view support) and
//! labeling of the resulting 3D candidates to template marker ids, tracking over frames
//! (thesis §6.2.2: "a marker can be reconstructed if it is visible in at least two of the three
//! camera images").

use nalgebra::{Matrix3, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::session::MarkerColor;
use crate::triangulate::{PixelObservation, Triangulated, TriangulationSettings, triangulate};

/// A 2D blob of one frame in one camera.
#[derive(Debug, Clone, PartialEq)]
pub struct Blob {
    /// Pixel centroid.
    pub uv: Vector2<f64>,
    /// Colour.
    pub color: MarkerColor,
    /// Given label, if any.
    pub label: Option<String>,
}

/// Settings of the correspondence search.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CorrespondenceSettings {
    /// Largest symmetric epipolar distance of a two-view match, px.
    pub epipolar_tolerance_px: f64,
    /// Largest reprojection distance for a supporting view, px.
    pub support_tolerance_px: f64,
    /// Largest RMS reprojection error of an accepted candidate, px.
    pub max_rms_px: f64,
    /// Gate between a tracked object marker's prediction and a candidate, m.
    pub marker_gate_m: f64,
    /// Gate of a candidate seen in only two views when the rig has three or more cameras, m. Two
    /// rays always meet within the epipolar tolerance, so a spurious blob in one view and a marker
    /// in another make a consistent-looking 3D point displaced along the epipolar line; a marker
    /// missing from a view is the moment such a ghost can take its label, and then its prediction,
    /// for as long as the spurious blob persists. The tighter gate (against one frame's motion)
    /// keeps it off.
    pub two_view_gate_m: f64,
    /// Gate between a shaft marker's previous position and a candidate, m.
    pub shaft_gate_m: f64,
    /// Tolerance on the distance between two shaft markers, m.
    pub shaft_spacing_tolerance_m: f64,
}

impl Default for CorrespondenceSettings {
    fn default() -> Self {
        CorrespondenceSettings {
            epipolar_tolerance_px: 2.0,
            support_tolerance_px: 3.0,
            max_rms_px: 2.0,
            marker_gate_m: 3e-3,
            two_view_gate_m: 1e-3,
            shaft_gate_m: 25e-3,
            shaft_spacing_tolerance_m: 2e-3,
        }
    }
}

/// A 3D candidate: a set of blobs (camera, blob index) from distinct cameras and its triangulation.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// `(camera, blob index)` pairs, sorted by camera.
    pub blobs: Vec<(usize, usize)>,
    /// Colour of the blobs.
    pub color: MarkerColor,
    /// Triangulation.
    pub point: Triangulated,
}

/// Essential matrix `E = [t]ₓ R` of camera `b` relative to camera `a` (normalized coordinates):
/// `n_bᵀ E n_a = 0` for corresponding points.
pub fn essential(a: &Camera, b: &Camera) -> Matrix3<f64> {
    let r = b.rotation * a.rotation.transpose();
    let t = b.translation_m - r * a.translation_m;
    t.cross_matrix() * r
}

fn line_distance(l: &Vector3<f64>, n: &Vector2<f64>) -> f64 {
    (l.x * n.x + l.y * n.y + l.z).abs() / (l.x * l.x + l.y * l.y).sqrt().max(1e-300)
}

/// Finds 3D candidates among unlabeled blobs: every same-colour pair in two cameras within the
/// epipolar tolerance is triangulated, supported by the nearest same-colour blob in every other
/// camera within the support tolerance, and re-triangulated; duplicates are merged.
pub fn find_candidates(
    cameras: &[Camera],
    blobs: &[Vec<Blob>],
    settings: &CorrespondenceSettings,
    tri: &TriangulationSettings,
) -> Vec<Candidate> {
    let normalized: Vec<Vec<Vector2<f64>>> = blobs
        .iter()
        .enumerate()
        .map(|(c, bs)| {
            bs.iter()
                .map(|b| cameras[c].undistort(b.uv.x, b.uv.y))
                .collect()
        })
        .collect();
    let mut out: Vec<Candidate> = Vec::new();
    for a in 0..cameras.len() {
        for b in a + 1..cameras.len() {
            let e = essential(&cameras[a], &cameras[b]);
            let (fa, fb) = (cameras[a].focal_px(), cameras[b].focal_px());
            for (i, bi) in blobs[a].iter().enumerate() {
                let na = normalized[a][i];
                let lb = e * Vector3::new(na.x, na.y, 1.0);
                for (j, bj) in blobs[b].iter().enumerate() {
                    if bj.color != bi.color {
                        continue;
                    }
                    let nb = normalized[b][j];
                    let la = e.transpose() * Vector3::new(nb.x, nb.y, 1.0);
                    let d = 0.5 * (line_distance(&lb, &nb) * fb + line_distance(&la, &na) * fa);
                    if d > settings.epipolar_tolerance_px {
                        continue;
                    }
                    let mut set = vec![(a, i), (b, j)];
                    let obs2 = [
                        PixelObservation {
                            camera: a,
                            uv: bi.uv,
                        },
                        PixelObservation {
                            camera: b,
                            uv: bj.uv,
                        },
                    ];
                    let Some(p2) = triangulate(cameras, &obs2, tri) else {
                        continue;
                    };
                    if cameras[a].to_camera(&p2.position_m).z <= 0.0
                        || cameras[b].to_camera(&p2.position_m).z <= 0.0
                    {
                        continue;
                    }
                    for c in 0..cameras.len() {
                        if c == a || c == b {
                            continue;
                        }
                        let Some(uv) = cameras[c].project(&p2.position_m) else {
                            continue;
                        };
                        let best = blobs[c]
                            .iter()
                            .enumerate()
                            .filter(|(_, bc)| bc.color == bi.color)
                            .map(|(k, bc)| (k, (bc.uv - uv).norm()))
                            .filter(|&(_, d)| d <= settings.support_tolerance_px)
                            .min_by(|x, y| x.1.total_cmp(&y.1));
                        if let Some((k, _)) = best {
                            set.push((c, k));
                        }
                    }
                    set.sort_unstable();
                    if out.iter().any(|c| c.blobs == set) {
                        continue;
                    }
                    let obs: Vec<_> = set
                        .iter()
                        .map(|&(c, k)| PixelObservation {
                            camera: c,
                            uv: blobs[c][k].uv,
                        })
                        .collect();
                    let Some(p) = triangulate(cameras, &obs, tri) else {
                        continue;
                    };
                    if p.reprojection_rms_px <= settings.max_rms_px {
                        out.push(Candidate {
                            blobs: set,
                            color: bi.color,
                            point: p,
                        });
                    }
                }
            }
        }
    }
    out
}

/// What a marker to be labeled looks like: its colour and predicted position (if known).
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerPrediction {
    /// Colour.
    pub color: MarkerColor,
    /// Predicted position, m.
    pub position_m: Option<Point3<f64>>,
    /// Gate radius around the prediction, m.
    pub gate_m: f64,
    /// Gate radius for candidates seen in exactly two views, m (≤ `gate_m`).
    pub two_view_gate_m: f64,
}

/// Assigns candidates to markers: all (marker, candidate) pairs within the marker's gate
/// (`two_view_gate_m` for a two-view candidate), candidates seen in three or more views first —
/// a ghost of a spurious blob is a two-view candidate, and a marker seen in three views must not
/// lose its label to one — then, within each group, greedily by increasing distance (ties: more
/// views first), each blob used at most once. Returns, per marker, the index of its candidate.
pub fn label_candidates(
    markers: &[MarkerPrediction],
    candidates: &[Candidate],
    used_blobs: &mut std::collections::BTreeSet<(usize, usize)>,
) -> Vec<Option<usize>> {
    let mut pairs = Vec::new();
    for (m, pred) in markers.iter().enumerate() {
        let Some(p) = pred.position_m else { continue };
        for (c, cand) in candidates.iter().enumerate() {
            if cand.color != pred.color {
                continue;
            }
            let d = (cand.point.position_m - p).norm();
            let two_view = cand.point.views <= 2;
            let gate = if two_view {
                pred.two_view_gate_m.min(pred.gate_m)
            } else {
                pred.gate_m
            };
            if d <= gate {
                pairs.push((two_view, d, usize::MAX - cand.point.views, m, c));
            }
        }
    }
    pairs.sort_by(|x, y| {
        x.0.cmp(&y.0)
            .then(x.1.total_cmp(&y.1))
            .then(x.2.cmp(&y.2))
            .then(x.3.cmp(&y.3))
            .then(x.4.cmp(&y.4))
    });
    let mut out = vec![None; markers.len()];
    for (_, _, _, m, c) in pairs {
        if out[m].is_some() || candidates[c].blobs.iter().any(|b| used_blobs.contains(b)) {
            continue;
        }
        out[m] = Some(c);
        used_blobs.extend(candidates[c].blobs.iter().copied());
    }
    out
}

/// Picks the two probe shaft markers among unused candidates: the pair whose spacing matches
/// `spacing_m` within tolerance, preferring closeness to the previous positions (when known) and
/// more views. Returns candidate indices `(near, far)`.
pub fn pick_shaft_pair(
    colors: (MarkerColor, MarkerColor),
    spacing_m: f64,
    previous: Option<(Point3<f64>, Point3<f64>)>,
    candidates: &[Candidate],
    used_blobs: &std::collections::BTreeSet<(usize, usize)>,
    settings: &CorrespondenceSettings,
) -> Option<(usize, usize)> {
    let free = |c: &Candidate| c.blobs.iter().all(|b| !used_blobs.contains(b));
    let mut best: Option<(f64, usize, usize)> = None;
    for (i, a) in candidates
        .iter()
        .enumerate()
        .filter(|(_, c)| c.color == colors.0 && free(c))
    {
        for (j, b) in candidates
            .iter()
            .enumerate()
            .filter(|(_, c)| c.color == colors.1 && free(c))
        {
            if a.blobs.iter().any(|x| b.blobs.contains(x)) {
                continue;
            }
            let spacing_err = ((a.point.position_m - b.point.position_m).norm() - spacing_m).abs();
            if spacing_err > settings.shaft_spacing_tolerance_m {
                continue;
            }
            let mut cost = spacing_err - 1e-3 * (a.point.views + b.point.views) as f64;
            if let Some((pa, pb)) = previous {
                let d = (a.point.position_m - pa)
                    .norm()
                    .max((b.point.position_m - pb).norm());
                if d > settings.shaft_gate_m {
                    continue;
                }
                cost += d;
            }
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, i, j));
            }
        }
    }
    best.map(|(_, i, j)| (i, j))
}
