//! The in-memory recording the diagnosis works on: frames with time, probe pose, force and marker
//! observations, plus the static session facts (rest markers, surface normals, gravity, support).

use crate::{DiagnoseError, Result};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_mesh::TetMesh;

/// One captured frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Frame index from the capture (frame 0 is the rest state).
    pub frame: u64,
    /// Frame time, seconds (camera clock).
    pub time_s: f64,
    /// Probe tip position, metres, world frame.
    pub tip_m: Vector3<f64>,
    /// Unit vector along the probe shaft, handle → tip.
    pub axis: Vector3<f64>,
    /// Force the probe applies to the object, newtons, world frame.
    pub force_n: Vector3<f64>,
    /// Observed marker positions (metres, world frame); `None` when occluded / filled.
    pub markers_m: Vec<Option<Vector3<f64>>>,
}

/// The support plane `normal · x = offset_m` the object rests on (normal points into the object).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SupportPlane {
    /// Unit normal.
    pub normal: Vector3<f64>,
    /// Offset, metres.
    pub offset_m: f64,
    /// Points within this distance of the plane are attached, metres.
    pub tolerance_m: f64,
}

impl SupportPlane {
    /// Signed distance of `p` from the plane, metres.
    pub fn distance_m(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(p) - self.offset_m
    }

    /// The nodes of `mesh` attached to the plane: within `tolerance_m` of it, at least 1 nm
    /// (`softcap_probing::support_nodes`).
    pub fn nodes(&self, mesh: &TetMesh) -> Vec<usize> {
        softcap_probing::support_nodes(
            mesh,
            &self.normal,
            self.offset_m,
            self.tolerance_m.max(1e-9),
        )
    }
}

/// A probing recording: what `softcap capture` measured, in memory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Recording {
    /// Marker ids (index = marker index everywhere below).
    pub marker_ids: Vec<String>,
    /// Marker positions of the model's rest state (template), metres.
    pub rest_markers_m: Vec<Vector3<f64>>,
    /// Outward unit surface normal at each marker (rest state).
    pub normals: Vec<Vector3<f64>>,
    /// Gravity, m/s² (zero when unknown).
    pub gravity_m_s2: Vector3<f64>,
    /// Support plane, when the object rests on one.
    pub support: Option<SupportPlane>,
    /// Probe tip radius, metres.
    pub tip_radius_m: f64,
    /// Frames in time order.
    pub frames: Vec<Frame>,
}

impl Recording {
    /// Number of markers.
    pub fn num_markers(&self) -> usize {
        self.rest_markers_m.len()
    }

    /// Checks shapes and finiteness; the diagnosis assumes a validated recording.
    pub fn validate(&self) -> Result<()> {
        let m = self.num_markers();
        if m == 0 || self.frames.is_empty() {
            return Err(DiagnoseError::BadRecording {
                what: format!("{} markers, {} frames", m, self.frames.len()),
            });
        }
        if self.normals.len() != m || self.marker_ids.len() != m {
            return Err(DiagnoseError::BadRecording {
                what: format!(
                    "{} rest markers but {} normals and {} ids",
                    m,
                    self.normals.len(),
                    self.marker_ids.len()
                ),
            });
        }
        let mut last_t = f64::NEG_INFINITY;
        for f in &self.frames {
            if f.markers_m.len() != m {
                return Err(DiagnoseError::BadRecording {
                    what: format!(
                        "frame {} has {} markers, expected {m}",
                        f.frame,
                        f.markers_m.len()
                    ),
                });
            }
            if !f.time_s.is_finite() {
                return Err(DiagnoseError::NonFinite {
                    frame: f.frame,
                    field: "time_s",
                });
            }
            if f.time_s <= last_t {
                return Err(DiagnoseError::BadRecording {
                    what: format!("frame {} time {} s is not increasing", f.frame, f.time_s),
                });
            }
            last_t = f.time_s;
            let finite = |v: &Vector3<f64>| v.iter().all(|c| c.is_finite());
            if !finite(&f.tip_m) {
                return Err(DiagnoseError::NonFinite {
                    frame: f.frame,
                    field: "tip_m",
                });
            }
            if !finite(&f.axis) {
                return Err(DiagnoseError::NonFinite {
                    frame: f.frame,
                    field: "axis",
                });
            }
            if !finite(&f.force_n) {
                return Err(DiagnoseError::NonFinite {
                    frame: f.frame,
                    field: "force_n",
                });
            }
            if f.markers_m.iter().flatten().any(|p| !finite(p)) {
                return Err(DiagnoseError::NonFinite {
                    frame: f.frame,
                    field: "markers_m",
                });
            }
        }
        Ok(())
    }

    /// Frame times, seconds.
    pub fn times_s(&self) -> Vec<f64> {
        self.frames.iter().map(|f| f.time_s).collect()
    }

    /// Unit gravity direction (zero vector when gravity is unknown).
    pub fn gravity_dir(&self) -> Vector3<f64> {
        let n = self.gravity_m_s2.norm();
        if n > 0.0 {
            self.gravity_m_s2 / n
        } else {
            Vector3::zeros()
        }
    }

    /// Test fixture: two markers at (0, 0, 10) mm and (30, 0, 10) mm on a surface facing +z, no
    /// gravity or support, a 2 mm tip, the given frames.
    #[cfg(test)]
    pub(crate) fn two_marker_toy(frames: Vec<Frame>) -> Self {
        Self {
            marker_ids: vec!["a".into(), "b".into()],
            rest_markers_m: vec![Vector3::new(0.0, 0.0, 0.01), Vector3::new(0.03, 0.0, 0.01)],
            normals: vec![Vector3::z(); 2],
            gravity_m_s2: Vector3::zeros(),
            support: None,
            tip_radius_m: 0.002,
            frames,
        }
    }
}

/// Outward unit normals at `points` from the closest boundary face of `mesh` (area-weighted vertex
/// normals of the closest face, evaluated at the closest point's barycentric coordinates).
pub fn surface_normals(mesh: &softcap_mesh::TetMesh, points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let tri = softcap_mesh::TriMesh {
        vertices: mesh.vertices.clone(),
        triangles: mesh.boundary_faces(),
    };
    let mut vn = vec![Vector3::zeros(); tri.vertices.len()];
    for t in &tri.triangles {
        let [a, b, c] = t.map(|i| tri.vertices[i]);
        let n = (b - a).cross(&(c - a)); // area-weighted
        for &i in t {
            vn[i] += n;
        }
    }
    let locator = softcap_mesh::TriLocator::new(&tri);
    points
        .iter()
        .map(|p| match locator.locate(p) {
            Some(e) => {
                let t = tri.triangles[e.triangle];
                let n: Vector3<f64> = (0..3).map(|k| vn[t[k]] * e.weights[k]).sum();
                n.try_normalize(1e-300).unwrap_or_else(Vector3::z)
            }
            None => Vector3::z(),
        })
        .collect()
}
