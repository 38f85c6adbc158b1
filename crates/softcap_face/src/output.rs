//! Stage output: the animated face and its wrinkle parameters as an MCAP recording
//! (`docs/formats.md`): `/mesh/surface` (neutral scan, static), `/face/mesh` (one
//! `softcap.TriMesh` per mocap frame at its time), `/face/wrinkles` (`softcap.FaceWrinkles`, per
//! frame that carries wrinkles), each with its `/viz` twin for Foxglove. Positions are written in
//! metres (`metres_per_unit` converts the scan's unit, 0.01 for the ICT face in cm).

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use softcap_mcap::{Provenance, Writer, proto, topics, viz, viz_topic};
use softcap_mesh::TriMesh;

use crate::error::{FaceError, Result};
use crate::synth::{ProjectedWrinkle, WrinkleCurve};

/// Wrinkle input of `softcap-face run --wrinkles FILE.json`: the camera (face frame) and the
/// tracked image-space wrinkles of some frames.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct WrinkleInput {
    /// The video camera in face coordinates.
    pub camera: Option<crate::synth::PinholeCamera>,
    /// Wrinkles per source mocap frame.
    pub frames: Vec<FrameWrinkles>,
}

impl WrinkleInput {
    /// Check the camera and every wrinkle sample (finite, w > 0, d ≥ 0); the error names the
    /// frame, wrinkle and sample.
    pub fn validate(&self) -> crate::error::Result<()> {
        let Some(camera) = &self.camera else {
            return if self.frames.iter().all(|f| f.wrinkles.is_empty()) {
                Ok(())
            } else {
                Err(crate::error::FaceError::InvalidInput {
                    what: "wrinkles",
                    reason: "wrinkles without a camera".into(),
                })
            };
        };
        for f in &self.frames {
            crate::synth::validate_wrinkles(camera, &f.wrinkles).map_err(|e| match e {
                crate::error::FaceError::InvalidInput { what, reason } => {
                    crate::error::FaceError::InvalidInput {
                        what,
                        reason: format!("frame {}: {reason}", f.frame),
                    }
                }
                other => other,
            })?;
        }
        Ok(())
    }
}

/// The image-space wrinkles of one source frame.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct FrameWrinkles {
    /// Source mocap frame number.
    pub frame: u64,
    /// Its wrinkles.
    pub wrinkles: Vec<WrinkleCurve>,
}

/// One frame of the face stage's output.
#[derive(Clone, Debug, Default)]
pub struct FaceFrame {
    /// Source mocap frame number.
    pub frame: u64,
    /// Time since the take's start (s).
    pub t_s: f64,
    /// Vertex positions (scan units).
    pub vertices: Vec<Vector3<f64>>,
    /// Image-space wrinkles of this frame with, when synthesized, their projection (scan units).
    pub wrinkles: Vec<(WrinkleCurve, Option<ProjectedWrinkle>)>,
}

fn mcap_err(e: softcap_mcap::Error) -> FaceError {
    FaceError::Output(e.to_string())
}

fn to_proto_mesh(
    name: &str,
    vertices: &[Vector3<f64>],
    tris: &[[usize; 3]],
    k: f64,
) -> proto::TriMesh {
    proto::TriMesh {
        name: name.into(),
        frame_id: "face".into(),
        positions_m: vertices
            .iter()
            .flat_map(|v| [v.x * k, v.y * k, v.z * k])
            .collect(),
        triangles: tris.iter().flat_map(|t| t.map(|i| i as u32)).collect(),
    }
}

/// The `softcap.FaceWrinkles` message of one frame.
pub fn wrinkles_message(frame: &FaceFrame, metres_per_unit: f64) -> proto::FaceWrinkles {
    let k = metres_per_unit;
    proto::FaceWrinkles {
        frame: frame.frame,
        wrinkles: frame
            .wrinkles
            .iter()
            .map(|(curve, projected)| proto::Wrinkle {
                sections: curve
                    .samples
                    .iter()
                    .enumerate()
                    .map(|(i, s)| {
                        // project_wrinkle drops missed samples; only a complete projection is
                        // matched sample by sample.
                        let p = projected
                            .as_ref()
                            .filter(|p| p.points.len() == curve.samples.len());
                        proto::WrinkleSection {
                            valley_u_px: s.valley_px[0],
                            valley_v_px: s.valley_px[1],
                            depth_px: s.depth_px,
                            width_px: s.width_px,
                            depth_m: p.map_or(0.0, |p| p.depth[i] * k),
                            width_m: p.map_or(0.0, |p| p.width[i] * k),
                            valley_m: p.map(|p| proto::Vec3 {
                                x: p.points[i].x * k,
                                y: p.points[i].y * k,
                                z: p.points[i].z * k,
                            }),
                        }
                    })
                    .collect(),
            })
            .collect(),
    }
}

/// Write the face stage's MCAP to `path` (atomically: a temporary file renamed on success).
pub fn write_face_mcap(
    path: &Path,
    provenance: &Provenance,
    neutral: &TriMesh,
    frames: &[FaceFrame],
    metres_per_unit: f64,
) -> Result<PathBuf> {
    let n = neutral.vertices.len();
    if let Some(f) = frames.iter().find(|f| f.vertices.len() != n) {
        return Err(FaceError::InvalidInput {
            what: "face frame",
            reason: format!(
                "frame {} has {} vertices, the scan {n}",
                f.frame,
                f.vertices.len()
            ),
        });
    }
    let mut w = Writer::create(path, provenance).map_err(mcap_err)?;
    let rest = to_proto_mesh(
        "neutral",
        &neutral.vertices,
        &neutral.triangles,
        metres_per_unit,
    );
    w.write_static(&topics::SURFACE_MESH, &rest)
        .map_err(mcap_err)?;
    w.write_foxglove(
        &viz_topic(topics::SURFACE_MESH.name()),
        0,
        &viz::trimesh_scene(&rest, 0),
    )
    .map_err(mcap_err)?;
    for f in frames {
        let t_ns = (f.t_s.max(0.0) * 1e9).round() as u64;
        let m = to_proto_mesh("face", &f.vertices, &neutral.triangles, metres_per_unit);
        w.write(&topics::FACE_MESH, t_ns, &m).map_err(mcap_err)?;
        w.write_foxglove(
            &viz_topic(topics::FACE_MESH.name()),
            t_ns,
            &viz::trimesh_scene(&m, t_ns),
        )
        .map_err(mcap_err)?;
        if !f.wrinkles.is_empty() {
            let msg = wrinkles_message(f, metres_per_unit);
            w.write(&topics::FACE_WRINKLES, t_ns, &msg)
                .map_err(mcap_err)?;
            // viz twin: each projected valley as a ribbon of half width w across the segment
            let mut strip = Vec::new();
            let mut tris = Vec::new();
            for wr in &msg.wrinkles {
                let pts: Vec<(Vector3<f64>, f64)> = wr
                    .sections
                    .iter()
                    .filter_map(|s| {
                        s.valley_m
                            .as_ref()
                            .map(|p| (Vector3::new(p.x, p.y, p.z), s.width_m))
                    })
                    .collect();
                for pair in pts.windows(2) {
                    let d = pair[1].0 - pair[0].0;
                    let mut o = d.cross(&Vector3::z());
                    if o.norm() < 1e-12 * d.norm().max(1e-300) {
                        o = d.cross(&Vector3::x());
                    }
                    let o = o.normalize();
                    let base = (strip.len() / 3) as u32;
                    for &(p, wd) in pair {
                        let h = 0.5 * wd.max(1e-5);
                        strip.extend((p - o * h).iter().copied());
                        strip.extend((p + o * h).iter().copied());
                    }
                    tris.extend([base, base + 1, base + 2, base + 1, base + 3, base + 2]);
                }
            }
            let viz_mesh = proto::TriMesh {
                name: "wrinkle_valleys".into(),
                frame_id: "face".into(),
                positions_m: strip,
                triangles: tris,
            };
            w.write_foxglove(
                &viz_topic(topics::FACE_WRINKLES.name()),
                t_ns,
                &viz::trimesh_scene(&viz_mesh, t_ns),
            )
            .map_err(mcap_err)?;
        }
    }
    w.finish().map_err(mcap_err)
}
