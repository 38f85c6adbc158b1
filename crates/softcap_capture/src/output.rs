//! Writing `capture.mcap` through `softcap_mcap`: per-frame markers and probe samples with their
//! `/viz/...` Foxglove twins, the clock sync, per-camera statistics and a summary report.

use std::path::{Path, PathBuf};

use softcap_mcap::{Provenance, VizSettings, Writer, proto, topics, viz, viz_topic};

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

/// Writes the capture result to `path` atomically (`NAME.mcap.tmp` → `NAME.mcap`).
pub fn write_capture_mcap(
    path: &Path,
    session: &Session,
    result: &CaptureResult,
    settings: &CaptureSettings,
    arguments: &[String],
) -> Result<PathBuf> {
    let out = |e: softcap_mcap::Error| CaptureError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let settings_toml = toml::to_string(settings).unwrap_or_default();
    let mut prov = Provenance::new("capture", env!("CARGO_PKG_VERSION"))
        .with_arguments(arguments.iter().cloned())
        .with_settings(settings_toml);
    for input in session_inputs(session) {
        prov.add_input(&input).map_err(out)?;
    }
    let mut w = Writer::create(path, &prov).map_err(out)?;
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
