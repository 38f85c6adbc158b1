//! track.mcap: the template (`/mesh/volume`, frame 0), the material used
//! (`/tissue/dynamic_material`), the capture's `/capture/session` and `/capture/dynamic` (its
//! `support_nodes` replaced by every node the tracker held, so `tissue fit-dynamic` knows the
//! support, gravity and interactions from the track alone), per frame `/tissue/track/nodes` with its `/viz` mesh twin and
//! `/tissue/track/status`, and `/tissue/track/report`. Written atomically; nothing here depends
//! on timing, so the same inputs give the same content digest.

use softcap_mcap::{Provenance, Writer, proto, topics, viz, viz_topic};
use softcap_mesh::TetMesh;

use super::{TrackConfig, TrackMaterial, TrackOutcome};
use crate::error::{Result, TissueError};
use crate::output::tet_mesh_message;

fn log_time_ns(t: f64) -> u64 {
    if t.is_finite() && t > 0.0 {
        (t * 1e9).round() as u64
    } else {
        0
    }
}

/// The `/tissue/dynamic_material` message of a tracker material (rest shape as used).
pub fn material_message(m: &TrackMaterial) -> proto::DynamicMaterial {
    let homogeneous = m.young_pa.windows(2).all(|w| w[0] == w[1]);
    proto::DynamicMaterial {
        element: "corotational".into(),
        young_pa: if homogeneous {
            m.young_pa.first().copied().into_iter().collect()
        } else {
            m.young_pa.clone()
        },
        poisson: m.poisson,
        density_kg_m3: m.density_kg_m3,
        rayleigh_alpha_per_s: m.damping.alpha_per_s,
        rayleigh_beta_s: m.damping.beta_s,
        rest_positions_m: m
            .rest_m
            .iter()
            .flatten()
            .flat_map(|v| [v.x, v.y, v.z])
            .collect(),
    }
}

/// Writes track.mcap for `outcome`.
pub fn write_track(
    cfg: &TrackConfig,
    mesh: &TetMesh,
    material: &TrackMaterial,
    outcome: &TrackOutcome,
    held_nodes: &[usize],
) -> Result<()> {
    let path = &cfg.output;
    let err = |e: softcap_mcap::Error| TissueError::Output {
        path: path.clone(),
        reason: e.to_string(),
    };
    let settings = toml::to_string(&cfg.settings).map_err(|e| TissueError::BadSettings {
        field: "settings".into(),
        problem: e.to_string(),
    })?;
    let mut provenance = Provenance::new("tissue track", env!("CARGO_PKG_VERSION"))
        .with_arguments(cfg.arguments.iter())
        .with_settings(settings);
    let inputs = [
        Some(&cfg.capture),
        Some(&cfg.mesh),
        cfg.material.as_ref(),
        cfg.attach.as_ref(),
    ];
    for p in inputs.into_iter().flatten() {
        provenance.add_input(p).map_err(|e| TissueError::ReadMcap {
            path: p.clone(),
            source: Box::new(e),
        })?;
    }
    let read = |e: softcap_mcap::Error| TissueError::ReadMcap {
        path: cfg.capture.clone(),
        source: Box::new(e),
    };
    let capture = softcap_mcap::Recording::open(&cfg.capture).map_err(read)?;
    let session = capture.read_static(&topics::SESSION).map_err(read)?;
    let mut dynamic = capture
        .read_static(&topics::DYNAMIC_SESSION)
        .map_err(read)?;
    dynamic.support_nodes = held_nodes.iter().map(|&i| i as u32).collect();
    let mut w = Writer::create(path, &provenance).map_err(err)?;
    w.write_static(&topics::SESSION, &session).map_err(err)?;
    w.write_static(&topics::DYNAMIC_SESSION, &dynamic)
        .map_err(err)?;
    let volume = tet_mesh_message(mesh);
    w.write_static(&topics::VOLUME_MESH, &volume).map_err(err)?;
    w.write_static(&topics::DYNAMIC_MATERIAL, &material_message(material))
        .map_err(err)?;
    let viz_nodes = viz_topic(topics::TRACK_NODES.name());
    for f in &outcome.frames {
        let t = log_time_ns(f.t_camera_s);
        let positions_m: Vec<f64> = f.positions_m.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
        w.write(
            &topics::TRACK_NODES,
            t,
            &proto::NodeFrame {
                frame: f.frame,
                t_camera_s: f.t_camera_s,
                positions_m: positions_m.clone(),
            },
        )
        .map_err(err)?;
        w.write_foxglove(
            &viz_nodes,
            t,
            &viz::deformed_tetmesh_scene(&volume, &positions_m, t),
        )
        .map_err(err)?;
        w.write(
            &topics::TRACK_STATUS,
            t,
            &proto::TrackStatus {
                frame: f.frame,
                t_camera_s: f.t_camera_s,
                status: f.status.into(),
                residual_m: f.residual_m,
                sigma_m: f.sigma_m,
                outlier_fraction: f.outlier_fraction,
                em_iterations: f.em_iterations as u32,
                newton_iterations: f.newton_iterations as u32,
                points: f.points as u32,
                visible_samples: f.visible_samples as u32,
                detail: f.detail.clone(),
            },
        )
        .map_err(err)?;
    }
    w.write_static(&topics::TRACK_REPORT, &report(outcome))
        .map_err(err)?;
    w.finish().map_err(err)?;
    Ok(())
}

/// The summary report.
pub fn report(o: &TrackOutcome) -> proto::Report {
    use proto::key_value::Value;
    let kv = |key: &str, value: Value, unit: &str| proto::KeyValue {
        key: key.into(),
        value: Some(value),
        unit: unit.into(),
    };
    let [c, m, d, n] = o.status_counts();
    let finite_mean = |f: &dyn Fn(&super::tracker::FrameTrack) -> f64| {
        let v: Vec<f64> = o.frames.iter().map(f).filter(|v| v.is_finite()).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    proto::Report {
        title: "tissue track (wang2015 §5)".into(),
        entries: vec![
            kv("frames", Value::Integer(o.frames.len() as i64), ""),
            kv("frames_converged", Value::Integer(c as i64), ""),
            kv("frames_max_iterations", Value::Integer(m as i64), ""),
            kv("frames_diverged", Value::Integer(d as i64), ""),
            kv("frames_without_points", Value::Integer(n as i64), ""),
            kv("mean_residual", Value::Number(o.mean_residual_m()), "m"),
            kv(
                "mean_sigma",
                Value::Number(finite_mean(&|f| f.sigma_m)),
                "m",
            ),
            kv(
                "mean_outlier_fraction",
                Value::Number(finite_mean(&|f| f.outlier_fraction)),
                "",
            ),
            kv("nodes", Value::Integer(o.nodes as i64), ""),
            kv("tets", Value::Integer(o.tets as i64), ""),
            kv("surface_samples", Value::Integer(o.samples as i64), ""),
            kv("material", Value::Text(o.material_source.clone()), ""),
            kv("rest_shape", Value::Text(o.rest_shape.clone()), ""),
        ],
    }
}
