//! Stage MCAP of `softcap psd animate` (thesis §5.5.2 run time over a recorded trajectory).
//!
//! **Input**: a handle (marker) trajectory on the standard [`topics::MARKERS`] channel
//! (`/capture/markers`, `softcap.MarkerFrame`, one message per frame at its time): `Marker.id`
//! is the handle index `k` of the rig (`0 ≤ k < H`, [`crate::FaceRig::handles`]), `position_m`
//! the handle's position in metres. Every frame must carry every handle exactly once.
//!
//! **Output** (written atomically, `NAME.mcap.PID-N.tmp` renamed when complete):
//!
//! | topic | schema | when | content |
//! |---|---|---|---|
//! | `/mesh/surface` | `softcap.TriMesh` | static | rest face |
//! | `/face/mesh` | `softcap.TriMesh` | per input frame, same time | large scale + WPSD details (final surface) |
//! | `/psd/large_scale` | `softcap.TriMesh` | per input frame, same time | large-scale shell `x0 + B u_H` only; `/face/mesh` − this = the detail |
//! | `/psd/report` | `softcap.Report` | static | vertices, H, F, P, method, mean rank of the low-rank basis |
//! | `/viz/...` | `foxglove.SceneUpdate` | twins of the meshes | |
//!
//! Positions are metres (`metres_per_unit` converts the rig's unit: 0.01 for the ICT face in cm).
//! The whole input is read and validated before the output file is created, so bad input leaves
//! nothing behind.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_mcap::{Provenance, Recording, Topic, Writer, proto, topics, viz, viz_topic};

use crate::error::{PsdError, Result};
use crate::rig::Animator;

/// Large-scale-only surface per frame (`/face/mesh` minus this is the WPSD detail).
pub const LARGE_SCALE_TOPIC: &str = "/psd/large_scale";
/// Static summary report of the animation.
pub const REPORT_TOPIC: &str = "/psd/report";

/// One frame of a handle trajectory.
#[derive(Clone, Debug, PartialEq)]
pub struct HandleFrame {
    /// Frame number (`MarkerFrame.frame`).
    pub frame: u64,
    /// Log time (ns since session start).
    pub log_time_ns: u64,
    /// Handle positions in rig units, indexed by handle.
    pub positions: Vec<Vector3<f64>>,
}

/// Handle positions over time.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HandleTrajectory {
    /// Frames in log-time order.
    pub frames: Vec<HandleFrame>,
}

/// Settings of the MCAP animation output.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AnimateSettings {
    /// Metres per rig unit (0.01 for the ICT face in cm).
    pub metres_per_unit: f64,
    /// Also write `/psd/large_scale` (the shell without details) per frame.
    pub large_scale: bool,
    /// Write the Foxglove `/viz` twins of the meshes.
    pub viz: bool,
}

impl Default for AnimateSettings {
    fn default() -> Self {
        Self {
            metres_per_unit: 0.01,
            large_scale: true,
            viz: true,
        }
    }
}

/// What [`animate_to_mcap`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct AnimateSummary {
    /// The finished file.
    pub path: PathBuf,
    /// Frames synthesized.
    pub frames: usize,
    /// Wall time spent in [`Animator::frame`] over all frames (s; excludes encoding and I/O).
    pub synthesis_s: f64,
}

fn bad_message(
    path: &Path,
    frame: Option<u64>,
    field: impl Into<String>,
    reason: impl Into<String>,
) -> PsdError {
    PsdError::BadMessage {
        path: path.into(),
        topic: topics::MARKERS.name().into(),
        frame: frame.map_or_else(|| "-".into(), |f| f.to_string()),
        field: field.into(),
        reason: reason.into(),
    }
}

/// Read and validate a handle trajectory from `/capture/markers` of `path`: `handles` handles per
/// frame, positions divided by `metres_per_unit` (→ rig units).
///
/// Errors name the file, topic, frame and field: an unreadable / truncated file
/// ([`PsdError::BadRecording`]), a missing channel or wrong schema, a marker id ≥ `handles`, a
/// duplicate or missing handle, a missing or non-finite position ([`PsdError::BadMessage`]).
pub fn read_handle_trajectory(
    path: &Path,
    handles: usize,
    metres_per_unit: f64,
) -> Result<HandleTrajectory> {
    if !(metres_per_unit.is_finite() && metres_per_unit > 0.0) {
        return Err(PsdError::InvalidSetting {
            field: "metres_per_unit",
            reason: format!("{metres_per_unit} is not a positive length"),
        });
    }
    let recording = Recording::open(path).map_err(|e| PsdError::BadRecording {
        path: path.into(),
        reason: e.to_string(),
    })?;
    let messages = recording
        .read(&topics::MARKERS)
        .map_err(|e| bad_message(path, None, "-", e.to_string()))?;
    if messages.is_empty() {
        return Err(bad_message(path, None, "-", "the channel has no frames"));
    }
    let mut frames = Vec::with_capacity(messages.len());
    for (log_time_ns, msg) in messages {
        let f = Some(msg.frame);
        let mut positions: Vec<Option<Vector3<f64>>> = vec![None; handles];
        for m in &msg.markers {
            let k = m.id as usize;
            if k >= handles {
                return Err(bad_message(
                    path,
                    f,
                    "markers.id",
                    format!("marker id {k} ≥ {handles} handles"),
                ));
            }
            let p = m.position_m.as_ref().ok_or_else(|| {
                bad_message(
                    path,
                    f,
                    "markers.position_m",
                    format!("marker {k} has no position"),
                )
            })?;
            for (axis, x) in [("x", p.x), ("y", p.y), ("z", p.z)] {
                if !x.is_finite() {
                    return Err(bad_message(
                        path,
                        f,
                        format!("markers.position_m.{axis}"),
                        format!("marker {k}: {x} is not finite"),
                    ));
                }
            }
            if positions[k].is_some() {
                return Err(bad_message(
                    path,
                    f,
                    "markers.id",
                    format!("marker {k} appears twice"),
                ));
            }
            positions[k] = Some(Vector3::new(p.x, p.y, p.z) / metres_per_unit);
        }
        let positions = positions
            .into_iter()
            .enumerate()
            .map(|(k, p)| {
                p.ok_or_else(|| {
                    bad_message(path, f, "markers", format!("no marker for handle {k}"))
                })
            })
            .collect::<Result<Vec<_>>>()?;
        frames.push(HandleFrame {
            frame: msg.frame,
            log_time_ns,
            positions,
        });
    }
    Ok(HandleTrajectory { frames })
}

fn output_err(path: &Path) -> impl Fn(softcap_mcap::Error) -> PsdError + '_ {
    move |e| PsdError::Output {
        path: path.into(),
        reason: e.to_string(),
    }
}

/// Write a handle trajectory to `/capture/markers` of `path` (positions × `metres_per_unit`
/// → metres; `t_camera_s` = log time). The input format of [`read_handle_trajectory`].
pub fn write_handle_trajectory(
    path: &Path,
    provenance: &Provenance,
    trajectory: &HandleTrajectory,
    metres_per_unit: f64,
) -> Result<PathBuf> {
    let err = output_err(path);
    let mut w = Writer::create(path, provenance).map_err(&err)?;
    for f in &trajectory.frames {
        let msg = proto::MarkerFrame {
            frame: f.frame,
            t_camera_s: f.log_time_ns as f64 * 1e-9,
            markers: f
                .positions
                .iter()
                .enumerate()
                .map(|(k, p)| proto::Marker {
                    id: k as u32,
                    position_m: Some(proto::Vec3 {
                        x: p.x * metres_per_unit,
                        y: p.y * metres_per_unit,
                        z: p.z * metres_per_unit,
                    }),
                    visible: true,
                    ..Default::default()
                })
                .collect(),
        };
        w.write(&topics::MARKERS, f.log_time_ns, &msg)
            .map_err(&err)?;
    }
    w.finish().map_err(&err)
}

/// `softcap.TriMesh` of f32 positions in rig units, scaled to metres.
pub fn mesh_message(
    name: &str,
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    metres_per_unit: f64,
) -> proto::TriMesh {
    proto::TriMesh {
        name: name.into(),
        frame_id: "face".into(),
        positions_m: positions
            .iter()
            .flat_map(|p| p.map(|x| x as f64 * metres_per_unit))
            .collect(),
        triangles: triangles.iter().flatten().copied().collect(),
    }
}

fn report_entry(key: &str, value: proto::key_value::Value, unit: &str) -> proto::KeyValue {
    proto::KeyValue {
        key: key.into(),
        value: Some(value),
        unit: unit.into(),
    }
}

/// Run `animator` over every frame of `trajectory` and write the stage MCAP to `path` (see the
/// module docs for the channels). The output is only renamed into place once complete.
pub fn animate_to_mcap(
    animator: &mut Animator<'_>,
    trajectory: &HandleTrajectory,
    path: &Path,
    provenance: &Provenance,
    settings: &AnimateSettings,
) -> Result<AnimateSummary> {
    let rig = animator.rig();
    let h = rig.handles.len();
    if let Some(f) = trajectory.frames.iter().find(|f| f.positions.len() != h) {
        return Err(PsdError::SizeMismatch {
            what: "handle positions of a trajectory frame",
            expected: h,
            got: f.positions.len(),
        });
    }
    let k = settings.metres_per_unit;
    let tris = &rig.topology.triangles;
    let err = output_err(path);
    let mut w = Writer::create(path, provenance).map_err(&err)?;
    let rest = mesh_message("neutral", &rig.rest_f32, tris, k);
    w.write_static(&topics::SURFACE_MESH, &rest).map_err(&err)?;
    if settings.viz {
        w.write_foxglove(
            &viz_topic(topics::SURFACE_MESH.name()),
            0,
            &viz::trimesh_scene(&rest, 0),
        )
        .map_err(&err)?;
    }
    use proto::key_value::Value;
    let model = animator.model();
    let report = proto::Report {
        title: "softcap psd animate".into(),
        entries: vec![
            report_entry("vertices", Value::Integer(rig.num_vertices() as i64), ""),
            report_entry("handles", Value::Integer(h as i64), ""),
            report_entry("feature_edges", Value::Integer(rig.graph.len() as i64), ""),
            report_entry("basis_poses", Value::Integer(model.num_poses() as i64), ""),
            report_entry(
                "method",
                Value::Text(
                    match model.metric {
                        crate::detail::Metric::Global => "PSD",
                        crate::detail::Metric::Weighted(_) => "WPSD",
                    }
                    .into(),
                ),
                "",
            ),
            report_entry(
                "basis_mean_rank",
                Value::Number(animator.layout.basis.mean_rank()),
                "",
            ),
            report_entry("frames", Value::Integer(trajectory.frames.len() as i64), ""),
            report_entry("metres_per_unit", Value::Number(k), "m"),
        ],
    };
    w.write_static(&Topic::<proto::Report>::custom(REPORT_TOPIC), &report)
        .map_err(&err)?;
    let face_topic = topics::FACE_MESH;
    let large_topic = Topic::<proto::TriMesh>::custom(LARGE_SCALE_TOPIC);
    let mut synthesis = std::time::Duration::ZERO;
    for f in &trajectory.frames {
        let t0 = std::time::Instant::now();
        animator.frame(&f.positions)?;
        synthesis += t0.elapsed();
        let t = f.log_time_ns;
        let mut meshes = vec![(
            &face_topic,
            mesh_message("face", &animator.positions, tris, k),
        )];
        if settings.large_scale {
            meshes.push((
                &large_topic,
                mesh_message("large_scale", &animator.large_scale_positions(), tris, k),
            ));
        }
        for (topic, m) in &meshes {
            w.write(topic, t, m).map_err(&err)?;
            if settings.viz {
                w.write_foxglove(&viz_topic(topic.name()), t, &viz::trimesh_scene(m, t))
                    .map_err(&err)?;
            }
        }
    }
    let path = w.finish().map_err(&err)?;
    Ok(AnimateSummary {
        path,
        frames: trajectory.frames.len(),
        synthesis_s: synthesis.as_secs_f64(),
    })
}

/// Reads `frame,handle,x_cm,y_cm,z_cm` rows into per-frame handle positions; every frame
/// needs a row for each of `handles` handles (errors name the line and field).
pub fn read_handle_csv(path: &Path, handles: usize) -> Result<Vec<Vec<Vector3<f64>>>, PsdError> {
    let bad = |line: usize, field: &str, reason: String| PsdError::BadMarkerFile {
        path: path.into(),
        line,
        field: field.into(),
        reason,
    };
    let mut rdr = csv::Reader::from_path(path).map_err(|e| bad(1, "header", e.to_string()))?;
    let mut frames: Vec<Vec<Option<Vector3<f64>>>> = Vec::new();
    for (i, rec) in rdr.records().enumerate() {
        let line = i + 2;
        let rec = rec.map_err(|e| bad(line, "row", e.to_string()))?;
        let get = |k: usize, name: &str| -> Result<&str, PsdError> {
            rec.get(k).ok_or_else(|| bad(line, name, "missing".into()))
        };
        let frame: usize = get(0, "frame")?
            .trim()
            .parse()
            .map_err(|e| bad(line, "frame", format!("{e}")))?;
        let h: usize = get(1, "handle")?
            .trim()
            .parse()
            .map_err(|e| bad(line, "handle", format!("{e}")))?;
        if h >= handles {
            return Err(bad(line, "handle", format!("{h} ≥ {handles} handles")));
        }
        let mut p = Vector3::zeros();
        for (k, name) in ["x_cm", "y_cm", "z_cm"].iter().enumerate() {
            let x: f64 = get(2 + k, name)?
                .trim()
                .parse()
                .map_err(|e| bad(line, name, format!("{e}")))?;
            if !x.is_finite() {
                return Err(bad(line, name, "not finite".into()));
            }
            p[k] = x;
        }
        if frames.len() <= frame {
            frames.resize(frame + 1, vec![None; handles]);
        }
        frames[frame][h] = Some(p);
    }
    frames
        .into_iter()
        .enumerate()
        .map(|(f, hs)| {
            hs.into_iter()
                .enumerate()
                .map(|(h, p)| {
                    p.ok_or_else(|| {
                        bad(0, "handle", format!("frame {f} has no row for handle {h}"))
                    })
                })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod csv_tests {
    use super::*;

    #[test]
    fn bad_marker_row_names_line_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.csv");
        std::fs::write(&p, "frame,handle,x_cm,y_cm,z_cm\n0,0,1,2,3\n0,1,1,zz,3\n").unwrap();
        let e = read_handle_csv(&p, 2).unwrap_err().to_string();
        assert!(e.contains("line 3") && e.contains("y_cm"), "{e}");
        std::fs::write(&p, "frame,handle,x_cm,y_cm,z_cm\n0,0,1,2,3\n").unwrap();
        let e = read_handle_csv(&p, 2).unwrap_err().to_string();
        assert!(e.contains("no row for handle 1"), "{e}");
    }
}
