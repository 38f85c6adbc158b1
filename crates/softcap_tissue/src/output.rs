//! material.mcap: writing the fit and reading it back as a simulation-ready material.
//!
//! | channel | message | content |
//! |---|---|---|
//! | `/mesh/volume` | `softcap.TetMesh` | the fitted mesh, m (rest = capture frame 0) |
//! | `/tissue/element_material` | `softcap.ElementMaterial` | per example: (λ_e, α_e), ε_e, RMS residual |
//! | `/tissue/basis` | `softcap.StrainSpaceBasis` | p_e(ε) of eq. 8, per-tet centre counts, validity clamp |
//! | `/tissue/report` | `softcap.Report` | errors of the homogeneous, per-example and strain-space models |
//!
//! With `homogeneous_only` (`FitSettings::homogeneous_only`) only `/mesh/volume`, the rest
//! markers of `/tissue/simulated_markers` and `/tissue/report` (the baseline and its errors,
//! `fit = "homogeneous-only"`) are written.

use std::path::Path;
use std::sync::Arc;

use nalgebra::Vector3;
use softcap_mcap::material::MaterialData;
use softcap_mcap::proto::{self, KeyValue, key_value::Value};
use softcap_mcap::{Provenance, Writer, topics};
use softcap_mesh::TetMesh;
use softcap_probing::StrainSpaceMaterial;

use crate::error::{Result, TissueError};
use crate::fit::{ExampleSummary, FitConfig, SessionFit};
use crate::session::PreparedSession;

fn out_err(path: &Path) -> impl Fn(softcap_mcap::Error) -> TissueError + '_ {
    move |e| TissueError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

/// `softcap.TetMesh` of a mesh in metres (with its boundary triangles).
pub fn tet_mesh_message(mesh: &TetMesh) -> proto::TetMesh {
    proto::TetMesh {
        name: "volume".into(),
        frame_id: "world".into(),
        positions_m: mesh.vertices.iter().flat_map(|v| [v.x, v.y, v.z]).collect(),
        tets: mesh.tets.iter().flatten().map(|&i| i as u32).collect(),
        surface_triangles: mesh
            .boundary_faces()
            .iter()
            .flatten()
            .map(|&i| i as u32)
            .collect(),
    }
}

/// The `/tissue/basis` message of a strain-space material: padded T × M layout with per-tet
/// counts (docs/formats.md), φ(r) = r, tail "constant" (T × 1 × 2 coefficients) when any
/// element has a constant term, else "none"; validity clamp (floor, ceiling, ν bounds).
pub fn basis_message(material: &StrainSpaceMaterial) -> proto::StrainSpaceBasis {
    let t = material.elements.len();
    let m = material
        .elements
        .iter()
        .map(|e| e.centers.len())
        .max()
        .unwrap_or(0);
    let mut centers_strain = Vec::with_capacity(t * m * 6);
    let mut weights = Vec::with_capacity(t * m * 2);
    let mut center_samples = Vec::with_capacity(t * m);
    for el in &material.elements {
        for c in 0..m {
            match (el.centers.get(c), el.weights.get(c)) {
                (Some(cs), Some(w)) => {
                    centers_strain.extend_from_slice(cs);
                    weights.extend_from_slice(w);
                    center_samples.push(el.center_samples.get(c).copied().unwrap_or(0) as u32);
                }
                _ => {
                    centers_strain.extend_from_slice(&[0.0; 6]);
                    weights.extend_from_slice(&[0.0; 2]);
                    center_samples.push(0);
                }
            }
        }
    }
    let constant = material.elements.iter().any(|e| e.constant != [0.0; 2]);
    proto::StrainSpaceBasis {
        elements: t as u32,
        kernel: "r".into(),
        tail: if constant { "constant" } else { "none" }.into(),
        center_examples: (0..m as u32).collect(),
        centers_strain,
        weights,
        tail_coefficients: if constant {
            material.elements.iter().flat_map(|e| e.constant).collect()
        } else {
            Vec::new()
        },
        centers_per_tet: material
            .elements
            .iter()
            .map(|e| e.centers.len() as u32)
            .collect(),
        center_samples,
        lambda_floor_pa: material.lambda_floor_pa.clone(),
        nu_min: material.nu_bounds.0,
        nu_max: material.nu_bounds.1,
        lambda_ceiling_pa: material.lambda_ceiling_pa.clone(),
    }
}

/// The report entries `example.{k}.*` that a homogeneous-only fit has as well: frame, location,
/// force and the homogeneous fit's RMS error.
fn example_entries(k: usize, e: &ExampleSummary) -> [KeyValue; 4] {
    let p = format!("example.{k}");
    [
        KeyValue::integer(format!("{p}.frame"), e.frame as i64, ""),
        KeyValue::integer(format!("{p}.location"), e.location as i64, ""),
        KeyValue::number(format!("{p}.force"), e.force_n, "N"),
        KeyValue::number(format!("{p}.rms.homogeneous"), e.homogeneous_rms_m, "m"),
    ]
}

/// The `/tissue/report` of a fit.
pub fn report_message(fit: &SessionFit) -> proto::Report {
    let o = &fit.outcome;
    let mut entries = vec![
        KeyValue::integer("tets", o.tets as i64, ""),
        KeyValue::integer("locations", o.locations as i64, ""),
        KeyValue::integer("examples", o.examples.len() as i64, ""),
        KeyValue::number("homogeneous.young", o.homogeneous_young_pa, "Pa"),
        KeyValue::number("homogeneous.nu", o.homogeneous_nu, ""),
        KeyValue::number("homogeneous.lambda", o.homogeneous.lambda, "Pa"),
        KeyValue::number("homogeneous.alpha", o.homogeneous.alpha, "Pa"),
        KeyValue::number("rms.homogeneous", o.homogeneous_rms_m, "m"),
    ];
    if o.homogeneous_only {
        entries.extend([
            KeyValue::number("mean_error.homogeneous", o.homogeneous_mean_error_m, "m"),
            KeyValue::text("fit", "homogeneous-only"),
        ]);
        for (k, e) in o.examples.iter().enumerate() {
            entries.extend(example_entries(k, e));
        }
        return proto::Report {
            title: "softcap tissue fit (bickel2009 §6 homogeneous baseline only)".into(),
            entries,
        };
    }
    entries.extend([
        KeyValue::number("rms.per_example", o.example_rms_m, "m"),
        KeyValue::number("rms.material", o.material_rms_m, "m"),
        KeyValue::integer("material.failures", o.material_failures as i64, ""),
        KeyValue::integer(
            "examples.unconverged",
            o.examples.iter().filter(|e| !e.stop.converged()).count() as i64,
            "",
        ),
        KeyValue::number("mean_error.homogeneous", o.homogeneous_mean_error_m, "m"),
        KeyValue::number("mean_error.material", o.material_mean_error_m, "m"),
        KeyValue::number("basis.mean_centers", o.mean_centers, ""),
        KeyValue::number("gamma_prior", o.gamma_prior, ""),
    ]);
    for (k, g) in o.gamma_prior_scores.iter().enumerate() {
        let p = format!("gamma_prior.candidate.{k}");
        entries.push(KeyValue::number(
            format!("{p}.gamma_prior"),
            g.gamma_prior,
            "",
        ));
        entries.push(KeyValue::number(
            format!("{p}.heldout_rms"),
            g.heldout_rms_m,
            "m",
        ));
        entries.push(KeyValue::integer(
            format!("{p}.heldout_failures"),
            g.heldout_failures as i64,
            "",
        ));
        entries.push(KeyValue::number(
            format!("{p}.example_rms"),
            g.example_rms_m,
            "m",
        ));
    }
    if let Some(h) = &o.heldout {
        entries.push(KeyValue::number(
            "heldout.homogeneous_rms",
            h.homogeneous_rms_m,
            "m",
        ));
        entries.push(KeyValue::integer(
            "heldout.homogeneous_failures",
            h.homogeneous_failures as i64,
            "",
        ));
        entries.push(KeyValue::number(
            "heldout.material_rms",
            h.material_rms_m,
            "m",
        ));
        entries.push(KeyValue::integer(
            "heldout.material_failures",
            h.material_failures as i64,
            "",
        ));
    }
    for s in &o.basis_curve {
        entries.push(KeyValue::number(
            format!("basis.error.m{}", s.num_centers),
            s.relative_rms_error,
            "",
        ));
    }
    for (k, e) in o.examples.iter().enumerate() {
        entries.extend(example_entries(k, e));
        let p = format!("example.{k}");
        entries.push(KeyValue::number(
            format!("{p}.rms.per_example"),
            e.example_rms_m,
            "m",
        ));
        entries.push(KeyValue::number(
            format!("{p}.rms.material"),
            e.material_rms_m,
            "m",
        ));
        entries.push(KeyValue::integer(
            format!("{p}.iterations"),
            e.iterations as i64,
            "",
        ));
        entries.push(KeyValue::text(format!("{p}.stop"), e.stop.name()));
    }
    proto::Report {
        title: "softcap tissue fit (bickel2009 §4)".into(),
        entries,
    }
}

/// Writes material.mcap atomically (`NAME.mcap.PID-N.tmp`, fsync, rename): nothing is left behind
/// on error.
pub fn write_material(cfg: &FitConfig, prepared: &PreparedSession, fit: &SessionFit) -> Result<()> {
    let path = &cfg.output;
    let err = out_err(path);
    let settings_toml = toml::to_string(&cfg.settings).map_err(|e| TissueError::BadSettings {
        field: "settings".into(),
        problem: e.to_string(),
    })?;
    let mut provenance = Provenance::new("tissue fit", env!("CARGO_PKG_VERSION"))
        .with_arguments(cfg.arguments.iter())
        .with_settings(settings_toml)
        .with_input(&cfg.capture)
        .map_err(|e| TissueError::ReadMcap {
            path: cfg.capture.clone(),
            source: Box::new(e),
        })?;
    if let Some(m) = &cfg.mesh {
        provenance.add_input(m).map_err(|e| TissueError::ReadMcap {
            path: m.clone(),
            source: Box::new(e),
        })?;
    }
    let mut w = Writer::create(path, &provenance).map_err(&err)?;
    w.write_static(
        &topics::VOLUME_MESH,
        &tet_mesh_message(&prepared.setup.mesh),
    )
    .map_err(&err)?;
    for (k, (ex, f)) in fit.examples.iter().zip(&fit.fits).enumerate() {
        let msg = proto::ElementMaterial {
            example: k as u32,
            frame: ex.example.frame,
            lambda_pa: f.params.iter().map(|p| p.lambda).collect(),
            alpha_pa: f.params.iter().map(|p| p.alpha).collect(),
            strain: f.strains.iter().flat_map(|s| s.iter().copied()).collect(),
            residual_m: f.rms_m,
        };
        w.write(&topics::ELEMENT_MATERIAL, ex.log_time_ns, &msg)
            .map_err(&err)?;
    }
    // Rest positions of every marker (frame 0), then the material's re-simulation of each
    // example beside the measured markers, at the example's time.
    let rest = prepared
        .setup
        .marker_positions(&prepared.setup.mesh.vertices);
    let v = |p: &Vector3<f64>| proto::Vec3 {
        x: p.x,
        y: p.y,
        z: p.z,
    };
    w.write(
        &topics::SIMULATED_MARKERS,
        0,
        &proto::SimulatedMarkers {
            frame: 0,
            example: 0,
            load_step: 0,
            ids: (0..rest.len() as u32).collect(),
            positions_m: rest.iter().map(v).collect(),
            measured_m: Vec::new(),
        },
    )
    .map_err(&err)?;
    for (k, (ex, x)) in fit
        .examples
        .iter()
        .zip(&fit.material_positions_m)
        .enumerate()
    {
        let Some(x) = x else { continue };
        let sim = prepared.setup.marker_positions(x);
        let obs = &ex.example.observed;
        w.write(
            &topics::SIMULATED_MARKERS,
            ex.log_time_ns.max(1),
            &proto::SimulatedMarkers {
                frame: ex.example.frame,
                example: k as u32,
                load_step: 0,
                ids: obs.iter().map(|o| o.marker as u32).collect(),
                positions_m: obs.iter().map(|o| v(&sim[o.marker])).collect(),
                measured_m: obs.iter().map(|o| v(&o.position_m)).collect(),
            },
        )
        .map_err(&err)?;
    }
    if let Some(material) = &fit.material {
        w.write_static(&topics::STRAIN_SPACE_BASIS, &basis_message(material))
            .map_err(&err)?;
    }
    let mut report = report_message(fit);
    let used =
        crate::fit::effective_settings(&cfg.settings, &prepared.tip_shape, prepared.tip_radius_m);
    let sp = prepared.support;
    report.entries.extend([
        KeyValue::number("support.normal.x", sp.normal[0], ""),
        KeyValue::number("support.normal.y", sp.normal[1], ""),
        KeyValue::number("support.normal.z", sp.normal[2], ""),
        KeyValue::number("support.offset", sp.offset_m, "m"),
        KeyValue::number("support.tolerance", sp.tolerance_m, "m"),
        KeyValue::number("tip.radius", prepared.tip_radius_m, "m"),
        // The footprint loads the fits used (`softcap_probing::FootprintLoad::name`): the diagnosis
        // replays its default model with the load it was fitted under.
        KeyValue::text("homogeneous.patch.load", used.homogeneous.patch.load.name()),
        KeyValue::text("examples.patch.load", used.example_fit.patch.load.name()),
    ]);
    w.write_static(&topics::TISSUE_REPORT, &report)
        .map_err(&err)?;
    w.finish().map_err(&err)?;
    Ok(())
}

/// A material read back from material.mcap: the mesh (m) and the strain-space material.
#[derive(Clone, Debug)]
pub struct LoadedMaterial {
    /// The fitted mesh.
    pub mesh: TetMesh,
    /// p_e(ε) (bickel2009 eq. 8).
    pub material: Arc<StrainSpaceMaterial>,
    /// Rest positions of the markers (`/tissue/simulated_markers` at frame 0), m.
    pub markers_rest_m: Vec<Vector3<f64>>,
    /// The support plane the material was fitted with (`support.*` of `/tissue/report`).
    pub support: Option<softcap_mcap::SupportPlane>,
    /// Tip radius of the probe used for fitting, m (0 if unknown).
    pub tip_radius_m: f64,
    /// The raw file contents.
    pub data: MaterialData,
}

fn report_number(report: &Option<proto::Report>, key: &str) -> Option<f64> {
    report.as_ref()?.entries.iter().find_map(|e| match e.value {
        Some(Value::Number(v)) if e.key == key => Some(v),
        _ => None,
    })
}

/// Reads material.mcap into a [`StrainSpaceMaterial`] (needs `/tissue/basis` with kernel `r`
/// and no tail, as `softcap tissue fit` writes it).
pub fn read_material(path: &Path) -> Result<LoadedMaterial> {
    let data = MaterialData::read(path).map_err(|e| TissueError::ReadMcap {
        path: path.to_path_buf(),
        source: Box::new(e),
    })?;
    let mesh = TetMesh {
        vertices: data.vertices_m.iter().map(|v| Vector3::from(*v)).collect(),
        tets: data.tets.clone(),
    };
    let Some(b) = &data.basis else {
        return Err(TissueError::bad_input(
            path,
            "/tissue/basis",
            "missing: the file holds no strain-space material",
        ));
    };
    if !(b.kernel == "r" || b.kernel.is_empty())
        || !(b.tail == "none" || b.tail.is_empty() || b.tail == "constant")
    {
        return Err(TissueError::bad_input(
            path,
            "/tissue/basis kernel / tail",
            format!(
                "'{}' / '{}' unsupported (bickel2009 eq. 8: r / none or constant)",
                b.kernel, b.tail
            ),
        ));
    }
    let nu_bounds = if b.nu_min == 0.0 && b.nu_max == 0.0 {
        (0.0, 0.49)
    } else {
        (b.nu_min, b.nu_max)
    };
    let material = StrainSpaceMaterial::from_flat(
        data.tets.len(),
        b.center_examples.len(),
        &b.centers_strain,
        &b.weights,
        &b.tail_coefficients,
        &b.centers_per_tet,
        &b.center_samples,
        &b.lambda_floor_pa,
        &b.lambda_ceiling_pa,
        nu_bounds,
    )
    .map_err(|e| TissueError::bad_input(path, "/tissue/basis", e.to_string()))?;
    let material = Arc::new(material);
    let rec = softcap_mcap::Recording::open(path).map_err(|e| TissueError::ReadMcap {
        path: path.to_path_buf(),
        source: Box::new(e),
    })?;
    let mut markers_rest_m = Vec::new();
    if rec.channel(topics::SIMULATED_MARKERS.name()).is_some() {
        let msgs = rec
            .read(&topics::SIMULATED_MARKERS)
            .map_err(|e| TissueError::ReadMcap {
                path: path.to_path_buf(),
                source: Box::new(e),
            })?;
        if let Some((_, m)) = msgs.iter().find(|(_, m)| m.frame == 0) {
            markers_rest_m = m
                .positions_m
                .iter()
                .map(|p| Vector3::new(p.x, p.y, p.z))
                .collect();
            if let Some(i) = markers_rest_m
                .iter()
                .position(|p| !p.iter().all(|c| c.is_finite()))
            {
                return Err(TissueError::bad_input(
                    path,
                    format!("/tissue/simulated_markers frame 0 positions_m[{i}]"),
                    "not finite",
                ));
            }
        }
    }
    let num = |k: &str| report_number(&data.report, k);
    let support = match (
        num("support.normal.x"),
        num("support.normal.y"),
        num("support.normal.z"),
        num("support.offset"),
        num("support.tolerance"),
    ) {
        (Some(x), Some(y), Some(z), Some(offset_m), Some(tolerance_m))
            if (x * x + y * y + z * z) > 0.0 && offset_m.is_finite() =>
        {
            let n = (x * x + y * y + z * z).sqrt();
            Some(softcap_mcap::SupportPlane {
                normal: [x / n, y / n, z / n],
                offset_m,
                tolerance_m,
            })
        }
        _ => None,
    };
    let tip_radius_m = num("tip.radius").unwrap_or(0.0);
    Ok(LoadedMaterial {
        mesh,
        material,
        markers_rest_m,
        support,
        tip_radius_m,
        data,
    })
}
