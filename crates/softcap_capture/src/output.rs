//! Writing `capture.mcap` through `softcap_mcap`: per-frame markers and probe samples with their
//! `/viz/...` Foxglove twins, the clock sync, per-camera statistics and a summary report.

use std::path::{Path, PathBuf};

use softcap_mcap::{Provenance, VizSettings, Writer, proto, topics, viz, viz_topic};

use crate::depth::{CloudSource, DynamicCapture};
use crate::error::{CaptureError, Result};
use crate::pipeline::{CaptureResult, CaptureSettings, MarkerState};
use crate::session::Session;
use crate::sync::SyncMethod;

fn vec3(v: &nalgebra::Vector3<f64>) -> proto::Vec3 {
    proto::Vec3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

/// `log_time` of a camera time: ns since the camera clock's zero (never negative).
pub fn log_time_ns(t_camera_s: f64) -> u64 {
    if t_camera_s.is_finite() && t_camera_s > 0.0 {
        (t_camera_s * 1e9).round() as u64
    } else {
        0
    }
}

/// Every input file of a session (sorted, for provenance hashing).
pub fn session_inputs(session: &Session) -> Vec<PathBuf> {
    let mut v = vec![session.root.join("session.toml")];
    v.extend(session.cameras_path.iter().cloned());
    v.extend(session.c3d.iter().cloned());
    if let Some(r) = &session.robot {
        v.push(r.urdf.clone());
        v.push(r.samples.clone());
    }
    v.extend(session.surface.iter().cloned());
    if let Some(dir) = &session.detections {
        v.extend(
            session
                .cameras
                .iter()
                .map(|c| dir.join(format!("{}.csv", c.id))),
        );
    }
    if let Some(dir) = &session.images {
        for c in &session.cameras {
            if let Ok(rd) = std::fs::read_dir(dir.join(&c.id)) {
                v.extend(
                    rd.filter_map(|e| e.ok().map(|e| e.path()))
                        .filter(|p| p.extension().is_some_and(|e| e == "png")),
                );
            }
        }
    }
    v.sort();
    v.dedup();
    v.retain(|p| p.is_file());
    v
}

/// The error of a failed write to `path`.
fn output_error(path: &Path) -> impl Fn(softcap_mcap::Error) -> CaptureError + Copy + '_ {
    move |e| CaptureError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Opens capture.mcap at `path` with its provenance: the capture's settings, command line and
/// input files (hashed).
fn begin_writer(
    path: &Path,
    settings: &CaptureSettings,
    arguments: &[String],
    inputs: &[PathBuf],
) -> Result<Writer> {
    let out = output_error(path);
    let settings_toml = toml::to_string(settings).unwrap_or_default();
    let mut prov = Provenance::new("capture", env!("CARGO_PKG_VERSION"))
        .with_arguments(arguments.iter().cloned())
        .with_settings(settings_toml);
    for input in inputs {
        prov.add_input(input).map_err(&out)?;
    }
    Writer::create(path, &prov).map_err(out)
}

/// Writes the capture result to `path` atomically (`NAME.mcap.PID-N.tmp` → `NAME.mcap`).
pub fn write_capture_mcap(
    path: &Path,
    session: &Session,
    result: &CaptureResult,
    settings: &CaptureSettings,
    arguments: &[String],
) -> Result<PathBuf> {
    let out = output_error(path);
    let mut w = begin_writer(path, settings, arguments, &session_inputs(session))?;
    w.write_static(&topics::SESSION, &session_info(session, result))
        .map_err(out)?;
    let viz_settings = VizSettings::default();
    let markers_viz = viz_topic(topics::MARKERS.name());
    let probe_viz = viz_topic(topics::PROBE.name());

    for f in &result.frames {
        let t = log_time_ns(f.t_camera_s);
        let frame = proto::MarkerFrame {
            frame: f.frame as u64,
            t_camera_s: f.t_camera_s,
            markers: f
                .markers
                .iter()
                .enumerate()
                .filter(|(_, m)| m.state != MarkerState::Missing)
                .map(|(i, m)| proto::Marker {
                    id: i as u32,
                    position_m: Some(vec3(&m.position_m.coords)),
                    visible: m.state == MarkerState::Visible,
                    filled: m.state == MarkerState::Filled,
                    views: m.views as u32,
                    reprojection_error_px: if m.reprojection_rms_px.is_finite() {
                        m.reprojection_rms_px
                    } else {
                        0.0
                    },
                })
                .collect(),
        };
        w.write(&topics::MARKERS, t, &frame).map_err(out)?;
        w.write_foxglove(
            &markers_viz,
            t,
            &viz::markers_scene(&frame, t, &viz_settings),
        )
        .map_err(out)?;
        if let Some(p) = &f.probe {
            let sample = proto::ProbeSample {
                frame: f.frame as u64,
                t_camera_s: f.t_camera_s,
                tip_m: p.tip_m.map(|x| vec3(&x.coords)),
                axis: p.axis.map(|a| vec3(&a)),
                force_n: p.force_n.map(|x| vec3(&x)),
                voltage_v: if p.voltage_v.is_finite() {
                    p.voltage_v
                } else {
                    0.0
                },
            };
            w.write(&topics::PROBE, t, &sample).map_err(out)?;
            w.write_foxglove(&probe_viz, t, &viz::probe_scene(&sample, t, &viz_settings))
                .map_err(out)?;
        }
    }
    if let Some(s) = &result.sync {
        // softcap_mcap's ClockSync uses t_camera = (1 + drift')·t_daq + offset'; the session format
        // (and truth/clock.toml) t_daq = offset + (1 + drift)·t_camera. Convert exactly.
        let k = 1.0 + s.drift;
        let msg = proto::ClockSync {
            offset_s: -s.offset_s / k,
            drift: 1.0 / k - 1.0,
            residual_s: s.residual,
            method: match s.method {
                SyncMethod::Trigger => "trigger-line edges, least-squares line".into(),
                SyncMethod::Data => format!(
                    "data: max correlation of force with probe depth, then least-squares offset + drift \
                     (residual_s = RMS force residual / RMS dF/dt; force residual {:.4} N, correlation {:.4})",
                    s.residual_force_n, s.correlation
                ),
            },
            samples: s.samples as u64,
        };
        w.write_static(&topics::CLOCK_SYNC, &msg).map_err(out)?;
    }
    for c in &result.cameras {
        let msg = proto::CameraStats {
            camera_id: c.id.clone(),
            frames: result.frames.len() as u64,
            detections: c.blobs as u64,
            detections_used: c.used as u64,
            mean_reprojection_error_px: c.mean_reprojection_px,
            rms_reprojection_error_px: c.rms_reprojection_px,
            max_reprojection_error_px: c.max_reprojection_px,
        };
        w.write_static(&topics::CAMERA_STATS, &msg).map_err(out)?;
    }
    w.write_static(&topics::CAPTURE_REPORT, &report(result))
        .map_err(out)?;
    w.finish().map_err(out)
}

/// Writes a dynamic capture (`/capture/session`, `/capture/dynamic`, `/capture/points` with its
/// Foxglove `PointCloud` twin, `/capture/report`) to `path` atomically.
pub fn write_dynamic_capture_mcap(
    path: &Path,
    session: &Session,
    result: &DynamicCapture,
    settings: &CaptureSettings,
    arguments: &[String],
) -> Result<PathBuf> {
    let out = output_error(path);
    let mut w = begin_writer(path, settings, arguments, &dynamic_inputs(session))?;
    let empty = CaptureResult::empty(&session.name);
    w.write_static(&topics::SESSION, &session_info(session, &empty))
        .map_err(out)?;
    w.write_static(
        &topics::DYNAMIC_SESSION,
        &dynamic_session(session, result, settings),
    )
    .map_err(out)?;
    let viz = viz_topic(topics::POINTS.name());
    let flat = |v: &[nalgebra::Vector3<f32>]| -> Vec<f32> {
        v.iter().flat_map(|p| [p.x, p.y, p.z]).collect()
    };
    for f in &result.frames {
        let t = log_time_ns(f.t_camera_s);
        let msg = proto::PointCloudFrame {
            frame: f.frame as u64,
            t_camera_s: f.t_camera_s,
            positions_m: flat(&f.points_m),
            normals: flat(&f.normals),
            camera: f.camera.clone(),
            support_motion: f.support_motion.map(|m| proto::RigidMotion {
                qw: m.rotation.w,
                qx: m.rotation.i,
                qy: m.rotation.j,
                qz: m.rotation.k,
                translation_m: Some(vec3(&m.translation_m)),
            }),
        };
        w.write(&topics::POINTS, t, &msg).map_err(out)?;
        w.write_foxglove(&viz, t, &viz::point_cloud(&msg, t))
            .map_err(out)?;
    }
    w.write_static(&topics::CAPTURE_REPORT, &dynamic_report(result))
        .map_err(out)?;
    w.finish().map_err(out)
}

/// Every input file of a dynamic session (sorted): session.toml, cameras, depth images or PLY
/// clouds, support / interaction files.
fn dynamic_inputs(session: &Session) -> Vec<PathBuf> {
    let mut v = vec![session.root.join("session.toml")];
    if let Some(d) = &session.dynamic {
        v.extend(d.files.iter().cloned());
        let mut files_in = |dir: &Path, ext: &str| {
            if let Ok(rd) = std::fs::read_dir(dir) {
                v.extend(
                    rd.filter_map(|e| e.ok().map(|e| e.path()))
                        .filter(|p| p.extension().is_some_and(|e| e == ext)),
                );
            }
        };
        match &d.source {
            CloudSource::Depth {
                dir,
                cameras,
                cameras_path,
            } => {
                for c in cameras {
                    files_in(&dir.join(&c.camera.id), "png");
                }
                v.push(cameras_path.clone());
            }
            CloudSource::Points { dir } => files_in(dir, "ply"),
        }
    }
    v.sort();
    v.dedup();
    v.retain(|p| p.is_file());
    v
}

/// The `/capture/dynamic` message.
pub fn dynamic_session(
    session: &Session,
    result: &DynamicCapture,
    settings: &CaptureSettings,
) -> proto::DynamicSession {
    let d = session.dynamic.as_ref();
    proto::DynamicSession {
        source: match d.map(|d| &d.source) {
            Some(CloudSource::Points { .. }) => "points",
            _ => "depth",
        }
        .into(),
        cameras: result
            .cameras
            .iter()
            .map(|c| {
                let cam = &c.camera;
                proto::DepthCamera {
                    id: cam.id.clone(),
                    width: cam.width,
                    height: cam.height,
                    fx: cam.intrinsics[0],
                    fy: cam.intrinsics[1],
                    cx: cam.intrinsics[2],
                    cy: cam.intrinsics[3],
                    distortion: cam.distortion.to_vec(),
                    rotation: (0..9).map(|k| cam.rotation[(k / 3, k % 3)]).collect(),
                    translation_m: Some(vec3(&cam.translation_m)),
                    depth_scale_m: c.depth_scale_m,
                    min_depth_m: c.min_depth_m,
                    max_depth_m: c.max_depth_m,
                }
            })
            .collect(),
        support_nodes: d
            .and_then(|d| d.support_nodes.as_ref())
            .map(|n| n.iter().map(|&i| i as u32).collect())
            .unwrap_or_default(),
        interactions: d
            .map(|d| {
                d.interactions
                    .iter()
                    .map(|&(a, b)| proto::Interval {
                        t_start_s: a,
                        t_end_s: b,
                    })
                    .collect()
            })
            .unwrap_or_default(),
        support_moves: d.is_some_and(|d| d.support_motion.is_some()),
        voxel_size_m: settings.depth.voxel_size_m,
        frames: result.frames.len() as u64,
    }
}

/// Summary of a dynamic capture: frames, points per frame, points per camera.
pub fn dynamic_report(r: &DynamicCapture) -> proto::Report {
    use proto::key_value::Value;
    let counts: Vec<usize> = r.frames.iter().map(|f| f.points_m.len()).collect();
    let total: usize = counts.iter().sum();
    let mut e = vec![
        entry("session", Value::Text(r.session.clone()), ""),
        entry("frames", Value::Integer(r.frames.len() as i64), ""),
        entry("points_total", Value::Integer(total as i64), ""),
        entry(
            "points_per_frame_min",
            Value::Integer(counts.iter().copied().min().unwrap_or(0) as i64),
            "",
        ),
        entry(
            "points_per_frame_max",
            Value::Integer(counts.iter().copied().max().unwrap_or(0) as i64),
            "",
        ),
    ];
    for (c, n) in r.cameras.iter().zip(&r.points_per_camera) {
        e.push(entry(
            &format!("points.{}", c.camera.id),
            Value::Integer(*n as i64),
            "",
        ));
    }
    proto::Report {
        title: "capture (dynamic)".into(),
        entries: e,
    }
}

/// The `/capture/session` message: what a later stage needs to interpret the capture without the
/// session folder (marker ids and rest positions, gravity, support, density, probe tip).
pub fn session_info(session: &Session, result: &CaptureResult) -> proto::SessionInfo {
    use crate::session::{SessionKind, TipShape};
    let (tip_shape, tip_radius_m, tip_mesh_path) = match session.probe.as_ref().map(|p| &p.tip) {
        Some(TipShape::Disk { radius_m }) => ("disk", *radius_m, String::new()),
        Some(TipShape::Sphere { radius_m }) => ("sphere", *radius_m, String::new()),
        Some(TipShape::Mesh { path }) => (
            "mesh",
            0.0,
            path.strip_prefix(&session.root)
                .unwrap_or(path)
                .display()
                .to_string(),
        ),
        None => ("", 0.0, String::new()),
    };
    let object_markers = result.object_markers.min(session.markers.len());
    proto::SessionInfo {
        name: session.name.clone(),
        kind: match session.kind {
            SessionKind::Probe => "probe",
            SessionKind::ProbeRobot => "probe-robot",
            SessionKind::Mocap => "mocap",
            SessionKind::Dynamic => "dynamic",
        }
        .into(),
        marker_ids: result.marker_ids.clone(),
        object_markers: object_markers as u32,
        rest_positions_m: session.markers[..object_markers]
            .iter()
            .map(|m| vec3(&m.position_m.coords))
            .collect(),
        gravity_m_s2: Some(vec3(&session.gravity)),
        support: session.support.map(|s| proto::SupportPlane {
            normal: Some(vec3(&s.plane_normal)),
            offset_m: s.plane_offset_m,
            tolerance_m: s.tolerance_m,
        }),
        density_kg_m3: session.density_kg_m3,
        tip_shape: tip_shape.into(),
        tip_radius_m,
        shaft_direction: "handle-to-tip".into(),
        trigger_present: session
            .fsr_samples
            .as_ref()
            .is_some_and(|f| f.trigger_v.is_some()),
        tip_mesh_path,
        metres_per_unit: session.metres_per_unit,
    }
}

fn entry(key: &str, value: proto::key_value::Value, unit: &str) -> proto::KeyValue {
    proto::KeyValue {
        key: key.into(),
        value: Some(value),
        unit: unit.into(),
    }
}

/// The summary report: marker ids (the `id` of `/capture/markers` indexes this list), counts, sync.
pub fn report(r: &CaptureResult) -> proto::Report {
    use proto::key_value::Value;
    let mut e = vec![
        entry("session", Value::Text(r.session.clone()), ""),
        entry(
            "source",
            Value::Text(format!("{:?}", r.source).to_lowercase()),
            "",
        ),
        entry("marker_ids", Value::Text(r.marker_ids.join(",")), ""),
        entry(
            "object_markers",
            Value::Integer(r.object_markers as i64),
            "",
        ),
        entry("frames", Value::Integer(r.frames.len() as i64), ""),
    ];
    let count = |s: MarkerState| {
        r.frames
            .iter()
            .flat_map(|f| &f.markers)
            .filter(|m| m.state == s)
            .count() as i64
    };
    e.push(entry(
        "marker_samples_visible",
        Value::Integer(count(MarkerState::Visible)),
        "",
    ));
    e.push(entry(
        "marker_samples_filled",
        Value::Integer(count(MarkerState::Filled)),
        "",
    ));
    e.push(entry(
        "marker_samples_missing",
        Value::Integer(count(MarkerState::Missing)),
        "",
    ));
    if let Some(s) = &r.sync {
        e.push(entry(
            "clock.t_daq_offset_s",
            Value::Number(s.offset_s),
            "s",
        ));
        e.push(entry("clock.t_daq_drift", Value::Number(s.drift), ""));
        e.push(entry("clock.residual", Value::Number(s.residual), "s"));
        if s.method == SyncMethod::Data {
            e.push(entry(
                "clock.residual_force",
                Value::Number(s.residual_force_n),
                "N",
            ));
            e.push(entry("clock.correlation", Value::Number(s.correlation), ""));
        }
    }
    proto::Report {
        title: "capture".into(),
        entries: e,
    }
}
