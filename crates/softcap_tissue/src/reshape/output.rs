//! reshaped.mcap (channels in docs/formats.md):
//!
//! | channel | message | content |
//! |---|---|---|
//! | `/mesh/volume` | `softcap.TetMesh` | the reshaped mesh, m (`inspect export --what volume`) |
//! | `/mesh/surface` | `softcap.TriMesh` | its boundary, m (`inspect export --what surface`) |
//! | `/reshape/template` | `softcap.TetMesh` | the template, m |
//! | `/reshape/plastic_strains` | `softcap.PlasticStrains` | per-tet F_p (eq. 2 order) |
//! | `/reshape/constraints` | `softcap.ReshapeConstraints` | every constraint with its error |
//! | `/reshape/quality` | `softcap.ReshapeQuality` | dihedral angles, inverted tets, aspect ratios |
//! | `/reshape/report` | `softcap.Report` | status, stages, iterations, error statistics |

use nalgebra::Vector3;
use softcap_mcap::proto::{self, KeyValue, key_value::Value};
use softcap_mcap::{Provenance, Writer, topics};
use softcap_mesh::{TetMesh, TetQuality};

use super::problem::ConstraintKind;
use super::run::{ReshapeConfig, ReshapeRun};
use crate::error::{Result, TissueError};
use crate::output::tet_mesh_message;

fn number(key: &str, v: f64, unit: &str) -> KeyValue {
    KeyValue {
        key: key.into(),
        value: Some(Value::Number(v)),
        unit: unit.into(),
    }
}

fn integer(key: &str, v: i64) -> KeyValue {
    KeyValue {
        key: key.into(),
        value: Some(Value::Integer(v)),
        unit: String::new(),
    }
}

fn text(key: &str, v: &str) -> KeyValue {
    KeyValue {
        key: key.into(),
        value: Some(Value::Text(v.into())),
        unit: String::new(),
    }
}

fn vec3(v: &[f64; 3]) -> proto::Vec3 {
    proto::Vec3 {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

fn quality_message(q: &TetQuality) -> proto::MeshQuality {
    proto::MeshQuality {
        min_dihedral_deg: q.min_dihedral_deg,
        max_dihedral_deg: q.max_dihedral_deg,
        inverted_tets: q.inverted_tets as u32,
        max_aspect_ratio: q.max_aspect_ratio,
        mean_aspect_ratio: q.mean_aspect_ratio,
    }
}

/// (mean, 95th percentile, max) of `values` (0 for none).
pub fn error_stats(values: &[f64]) -> (f64, f64, f64) {
    if values.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let p95 = v[((0.95 * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
    (mean, p95, v[v.len() - 1])
}

/// The `/reshape/report` of a run.
pub fn report_message(run: &ReshapeRun) -> proto::Report {
    let o = &run.outcome;
    let mut entries = vec![
        text("status", run.status_name()),
        integer("tets", o.plastic.len() as i64),
        integer("nodes", o.positions_m.len() as i64),
        integer("free_flying", i64::from(run.free_flying)),
        number("smoothness", o.smoothness, ""),
        number("alpha", o.alpha_m2, "m^2"),
    ];
    if let Some(cv) = &o.cross_validation {
        entries.push(integer("cv.folds", cv.folds as i64));
        entries.push(text("cv.hold_out", cv.hold_out.name()));
        entries.push(text("cv.rule", cv.rule.name()));
        for (k, score) in cv.scores.iter().enumerate() {
            entries.push(number(&format!("cv.{k}.smoothness"), score.smoothness, ""));
            entries.push(number(&format!("cv.{k}.rms"), score.rms_m, "m"));
        }
    }
    for kind in [
        ConstraintKind::Attachment,
        ConstraintKind::Landmark,
        ConstraintKind::Icp,
    ] {
        let errors = o.errors_of(kind);
        let (mean, p95, max) = error_stats(&errors);
        let k = kind.name();
        entries.push(integer(&format!("{k}.count"), errors.len() as i64));
        entries.push(number(&format!("{k}.error.mean"), mean, "m"));
        entries.push(number(&format!("{k}.error.p95"), p95, "m"));
        entries.push(number(&format!("{k}.error.max"), max, "m"));
    }
    for (k, s) in o.stages.iter().enumerate() {
        let p = format!("stage.{k}");
        entries.push(text(&format!("{p}.name"), &s.name));
        entries.push(integer(&format!("{p}.iterations"), s.iterations as i64));
        entries.push(text(&format!("{p}.stop"), s.stop.name()));
        entries.push(number(
            &format!("{p}.objective.start"),
            s.objective_start,
            "m^2",
        ));
        entries.push(number(
            &format!("{p}.objective.end"),
            s.objective_end,
            "m^2",
        ));
        entries.push(number(&format!("{p}.max_error"), s.max_error_m, "m"));
    }
    for (k, h) in o.history.iter().enumerate() {
        let p = format!("iteration.{k}");
        entries.push(text(&format!("{p}.stage"), &h.stage));
        entries.push(number(&format!("{p}.objective"), h.objective, "m^2"));
        entries.push(number(&format!("{p}.max_error"), h.max_error_m, "m"));
        entries.push(number(&format!("{p}.step_length"), h.step_length, ""));
        entries.push(integer(
            &format!("{p}.equilibrium_solves"),
            h.equilibrium_solves as i64,
        ));
        entries.push(integer(
            &format!("{p}.step_iterations"),
            h.step_iterations as i64,
        ));
    }
    if let Some(e) = &run.surface_distance {
        entries.push(number("surface.distance.mean", e.0, "m"));
        entries.push(number("surface.distance.p95", e.1, "m"));
        entries.push(number("surface.distance.max", e.2, "m"));
    }
    proto::Report {
        title: "softcap tissue reshape (saito-barbic)".into(),
        entries,
    }
}

/// Writes reshaped.mcap atomically (the Writer's temporary file is renamed on finish).
pub fn write_reshaped(cfg: &ReshapeConfig, template: &TetMesh, run: &ReshapeRun) -> Result<()> {
    let path = &cfg.output;
    let err = |e: softcap_mcap::Error| TissueError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    let settings_toml = toml::to_string(&cfg.settings).map_err(|e| TissueError::BadSettings {
        field: "settings".into(),
        problem: e.to_string(),
    })?;
    let mut provenance = Provenance::new("tissue reshape", env!("CARGO_PKG_VERSION"))
        .with_arguments(cfg.arguments.iter())
        .with_settings(settings_toml);
    for input in run.inputs.iter() {
        provenance
            .add_input(input)
            .map_err(|e| TissueError::bad_input(input, "file", e.to_string()))?;
    }
    let mut w = Writer::create(path, &provenance).map_err(err)?;
    let reshaped = TetMesh {
        vertices: run.outcome.positions_m.clone(),
        tets: template.tets.clone(),
    };
    w.write_static(&topics::VOLUME_MESH, &tet_mesh_message(&reshaped))
        .map_err(err)?;
    w.write_static(&topics::SURFACE_MESH, &surface_message(&reshaped))
        .map_err(err)?;
    let mut template_msg = tet_mesh_message(template);
    template_msg.name = "template".into();
    w.write_static(&topics::RESHAPE_TEMPLATE, &template_msg)
        .map_err(err)?;
    w.write_static(
        &topics::PLASTIC_STRAINS,
        &proto::PlasticStrains {
            strains: run
                .outcome
                .plastic
                .iter()
                .flat_map(|s| s.iter().copied())
                .collect(),
        },
    )
    .map_err(err)?;
    w.write_static(
        &topics::RESHAPE_CONSTRAINTS,
        &proto::ReshapeConstraints {
            constraints: run
                .outcome
                .errors
                .iter()
                .map(|e| proto::ReshapeConstraint {
                    kind: e.kind.name().into(),
                    id: e.id.clone(),
                    target_m: Some(vec3(&e.target_m)),
                    achieved_m: Some(vec3(&e.achieved_m)),
                    error_m: e.error_m,
                })
                .collect(),
        },
    )
    .map_err(err)?;
    w.write_static(
        &topics::RESHAPE_QUALITY,
        &proto::ReshapeQuality {
            template: Some(quality_message(&run.outcome.template_quality)),
            reshaped: Some(quality_message(&run.outcome.reshaped_quality)),
        },
    )
    .map_err(err)?;
    w.write_static(&topics::RESHAPE_REPORT, &report_message(run))
        .map_err(err)?;
    w.finish().map_err(err)?;
    Ok(())
}

/// The boundary of `mesh` with its own vertex numbering (`/mesh/surface`).
fn surface_message(mesh: &TetMesh) -> proto::TriMesh {
    let map = mesh.surface_map();
    proto::TriMesh {
        name: "surface".into(),
        frame_id: "world".into(),
        positions_m: map
            .surface
            .vertices
            .iter()
            .flat_map(|v: &Vector3<f64>| [v.x, v.y, v.z])
            .collect(),
        triangles: map
            .surface
            .triangles
            .iter()
            .flatten()
            .map(|&i| i as u32)
            .collect(),
    }
}
