//! Reading the stage inputs: `capture.mcap` (through `softcap_mcap::capture::CaptureData`) into a
//! [`Recording`], and `material.mcap` (through `softcap_mcap::material::MaterialData`:
//! `/mesh/volume` + `/tissue/basis` or `/tissue/element_material`) into the default model.

use crate::recording::{Frame, Recording, SupportPlane, surface_normals};
use crate::{DiagnoseError, Result};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_fem::{CorotationalModel, LinearParams};
use softcap_mcap::capture::CaptureData;
use softcap_mcap::material::MaterialData;
use softcap_mcap::proto;
use softcap_mesh::TetMesh;
use softcap_probing::{ElementRbf, FootprintLoad, StrainSpaceMaterial};
use std::path::Path;
use std::sync::Arc;

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

/// The recording of a capture: object markers only (shaft markers dropped), filled (predicted)
/// markers treated as unobserved, missing probe fields carried from the previous frame.
pub fn recording_from_capture(cap: &CaptureData, mesh: &TetMesh) -> Result<Recording> {
    let s = &cap.session;
    let path = &cap.path;
    let bad = |what: String| DiagnoseError::BadInput {
        path: path.clone(),
        what,
    };
    let nm = s.object_markers;
    if nm == 0 || s.rest_positions_m.len() != nm {
        return Err(bad(format!(
            "/capture/session: {} object markers but {} rest positions",
            nm,
            s.rest_positions_m.len()
        )));
    }
    let rest: Vec<Vector3<f64>> = s.rest_positions_m.iter().map(|p| v3(*p)).collect();
    let mut tip = Vector3::zeros();
    let mut axis = -Vector3::z();
    let mut frames = Vec::with_capacity(cap.frames.len());
    for f in &cap.frames {
        let mut force = Vector3::zeros();
        if let Some(p) = &f.probe {
            if let Some(t) = p.tip_m {
                tip = v3(t);
            }
            if let Some(a) = p.axis {
                axis = v3(a);
            }
            if let Some(fv) = p.force_n {
                force = v3(fv);
            }
        }
        let mut markers_m = vec![None; nm];
        for m in &f.markers {
            let id = m.id as usize;
            if id < nm && m.visible && !m.filled {
                markers_m[id] = Some(v3(m.position_m));
            }
        }
        frames.push(Frame {
            frame: f.frame,
            time_s: f.t_camera_s,
            tip_m: tip,
            axis,
            force_n: force,
            markers_m,
        });
    }
    let rec = Recording {
        marker_ids: s.marker_ids.iter().take(nm).cloned().collect(),
        normals: surface_normals(mesh, &rest),
        rest_markers_m: rest,
        gravity_m_s2: v3(s.gravity_m_s2),
        support: s.support.as_ref().map(|p| SupportPlane {
            normal: v3(p.normal),
            offset_m: p.offset_m,
            tolerance_m: p.tolerance_m,
        }),
        tip_radius_m: s.tip_radius_m,
        frames,
    };
    rec.validate().map_err(|e| bad(e.to_string()))?;
    Ok(rec)
}

/// Which of material.mcap's materials is the default model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MaterialSource {
    /// The model that predicts probe locations it was not fitted to best, by the tissue fit's
    /// leave-one-location-out comparison (`heldout.*` of `/tissue/report`,
    /// `softcap_tissue::FitSettings::heldout_comparison`): the strain-space basis (bickel2009's
    /// default model, eq. 8) when its held-out RMS is at most (1 − [`AUTO_MATERIAL_MARGIN`]) ×
    /// the homogeneous baseline's with no more held-out simulations failing, else the
    /// homogeneous baseline. Without the comparison in the report: the homogeneous baseline when
    /// present, else the basis, else the mean per-example parameters.
    ///
    /// Why held-out and not the fitted examples: the basis reproduces the fitted examples better
    /// by construction, and its per-element freedom absorbs effects that act everywhere (with the
    /// basis as the default model the own-rig support-slip and anisotropy sessions were answered
    /// `none`, docs/diagnose.md session 10); a location the material was not built from shows
    /// whether that freedom transfers. The reason of the choice is in the evidence
    /// (`default_model`).
    #[default]
    Auto,
    /// `/tissue/basis` (bickel2009 eq. 8), required.
    Basis,
    /// The homogeneous baseline (`homogeneous.lambda` / `homogeneous.alpha` of `/tissue/report`,
    /// bickel2009 §6 Fig. 8), required.
    Homogeneous,
    /// The element-wise mean of the per-example parameters (`/tissue/element_material`).
    ExampleMean,
}

/// Relative margin of [`MaterialSource::Auto`]: the strain-space material is the default model
/// only when its leave-one-location-out RMS is below (1 − margin) × the homogeneous baseline's.
/// Near-ties keep the two-parameter baseline, so the choice does not hang on the last bits of
/// the fits: a one-ulp change of every marker moves a converged per-example fit's marker RMS by
/// < 0.1 % (softcap_tissue tests/fit_convergence.rs), and fits stopped at an iteration cap
/// differed by ≈ 2 % in cost.
pub const AUTO_MATERIAL_MARGIN: f64 = 0.02;

/// The default model of a material.mcap.
pub struct MaterialModel {
    /// The fitted mesh (SI).
    pub mesh: TetMesh,
    /// The corotational model; with a basis, its parameters are the basis at zero strain p(0)
    /// and the strain dependence is in [`Self::basis`].
    pub model: CorotationalModel,
    /// The strain-space material (bickel2009 eq. 8) when the default model is the basis: the
    /// simulator solves it with the relaxed, continued parameter iteration
    /// (`softcap_probing::StrainSpaceModel::solve_continued`).
    pub basis: Option<Arc<StrainSpaceMaterial>>,
    /// "strain-space basis", "homogeneous baseline" or "mean per-example parameters", with the
    /// reason when `Auto` chose.
    pub source: String,
    /// The footprint load the model was fitted under (`/tissue/report`
    /// `homogeneous.patch.load` for the homogeneous baseline, `examples.patch.load` for the
    /// per-example parameters and their basis); `None` in files that predate the entry (fitted
    /// under the then only load, `FootprintLoad::Lumped`). The force boundary condition of the
    /// replay must be the fit's (`FemSimSettings::patch`, [`crate::run`]).
    pub footprint_load: Option<FootprintLoad>,
}

/// The footprint load named by the text entry `key` of `/tissue/report` (`None` when absent).
fn report_footprint_load(data: &MaterialData, key: &str) -> Result<Option<FootprintLoad>> {
    use proto::key_value::Value;
    let Some(entry) = data
        .report
        .as_ref()
        .and_then(|r| r.entries.iter().find(|e| e.key == key))
    else {
        return Ok(None);
    };
    match &entry.value {
        Some(Value::Text(name)) => {
            FootprintLoad::from_name(name)
                .map(Some)
                .ok_or_else(|| DiagnoseError::BadInput {
                    path: data.path.clone(),
                    what: format!(
                        "/tissue/report {key}: unknown footprint load {name:?} (one of {})",
                        FootprintLoad::ALL.map(FootprintLoad::name).join(", ")
                    ),
                })
        }
        _ => Err(DiagnoseError::BadInput {
            path: data.path.clone(),
            what: format!("/tissue/report {key}: not a text entry"),
        }),
    }
}

fn report_number(data: &MaterialData, key: &str) -> Option<f64> {
    use proto::key_value::Value;
    data.report
        .as_ref()?
        .entries
        .iter()
        .find(|e| e.key == key)
        .and_then(|e| match e.value {
            Some(Value::Number(x)) => Some(x),
            Some(Value::Integer(i)) => Some(i as f64),
            _ => None,
        })
}

/// The strain-space material of `/tissue/basis` (bickel2009 eq. 8, φ(r) = r, no tail) as a
/// [`StrainSpaceMaterial`]: per tet the M centres εᵢ and weights wᵢ = (w_λ, w_α). The validity
/// clamp follows `StrainBasisSettings::default()` of the fit: λ ≥ ½ of the element's smallest
/// per-example λ (`/tissue/element_material`), else ½ of its λ at zero strain; ν ∈ [0, 0.49].
pub fn strain_space_material(
    data: &MaterialData,
    basis: &proto::StrainSpaceBasis,
) -> std::result::Result<StrainSpaceMaterial, String> {
    let nt = data.tets.len();
    let m = basis.center_examples.len();
    if basis.elements as usize != nt
        || basis.centers_strain.len() != nt * m * 6
        || basis.weights.len() != nt * m * 2
    {
        return Err(format!(
            "{} elements, {} centres: array lengths {} / {} do not match {nt} tets",
            basis.elements,
            m,
            basis.centers_strain.len(),
            basis.weights.len()
        ));
    }
    // tail "constant" (softcap tissue fit since session 4): T × 1 × 2 coefficients.
    let constant = basis.tail == "constant" && basis.tail_coefficients.len() == 2 * nt;
    if !(basis.tail.is_empty() || basis.tail == "none" || constant) {
        return Err(format!(
            "tail '{}' is not supported (only none / constant)",
            basis.tail
        ));
    }
    if !(basis.kernel.is_empty() || basis.kernel == "r") {
        return Err(format!(
            "kernel '{}' is not supported (bickel2009 eq. 8 uses phi(r) = r)",
            basis.kernel
        ));
    }
    if let Some(i) = basis
        .centers_strain
        .iter()
        .chain(&basis.weights)
        .position(|v| !v.is_finite())
    {
        return Err(format!("non-finite value at position {i}"));
    }
    let elements: Vec<ElementRbf> = (0..nt)
        .map(|e| ElementRbf {
            center_samples: basis.center_examples.iter().map(|&c| c as usize).collect(),
            centers: (0..m)
                .map(|i| {
                    let c = &basis.centers_strain[(e * m + i) * 6..(e * m + i) * 6 + 6];
                    [c[0], c[1], c[2], c[3], c[4], c[5]]
                })
                .collect(),
            weights: (0..m)
                .map(|i| {
                    let w = &basis.weights[(e * m + i) * 2..(e * m + i) * 2 + 2];
                    [w[0], w[1]]
                })
                .collect(),
            constant: if constant {
                [
                    basis.tail_coefficients[2 * e],
                    basis.tail_coefficients[2 * e + 1],
                ]
            } else {
                [0.0; 2]
            },
        })
        .collect();
    let lambda_floor_pa = (0..nt)
        .map(|e| {
            let min_sample = data
                .element_materials
                .iter()
                .map(|(_, x)| x.lambda_pa[e])
                .fold(f64::INFINITY, f64::min);
            let l = if min_sample.is_finite() {
                min_sample
            } else {
                elements[e].evaluate(&[0.0; 6])[0]
            };
            0.5 * l.max(1.0)
        })
        .collect();
    Ok(StrainSpaceMaterial {
        elements,
        lambda_floor_pa,
        nu_bounds: (0.0, 0.49),
        lambda_ceiling_pa: basis.lambda_ceiling_pa.clone(),
    })
}

/// Reads `material.mcap` through [`MaterialData::read`] with [`MaterialSource::Auto`].
pub fn read_material(path: &Path) -> Result<MaterialModel> {
    read_material_from(path, MaterialSource::Auto)
}

/// Reads `material.mcap` through [`MaterialData::read`] and builds the default model from `source`.
pub fn read_material_from(path: &Path, source: MaterialSource) -> Result<MaterialModel> {
    let data = MaterialData::read(path).map_err(|source| DiagnoseError::Mcap {
        path: path.to_path_buf(),
        source: Box::new(source),
    })?;
    material_model_from(&data, source)
}

/// The default model of already-read material data ([`MaterialSource::Auto`]).
pub fn material_model(data: &MaterialData) -> Result<MaterialModel> {
    material_model_from(data, MaterialSource::Auto)
}

/// The default model of already-read material data from `source`.
pub fn material_model_from(data: &MaterialData, source: MaterialSource) -> Result<MaterialModel> {
    let bad = |what: String| DiagnoseError::BadInput {
        path: data.path.clone(),
        what,
    };
    let mesh = TetMesh {
        vertices: data.vertices_m.iter().map(|p| v3(*p)).collect(),
        tets: data.tets.clone(),
    };
    if mesh.tets.is_empty() {
        return Err(bad("/mesh/volume: no tets".into()));
    }
    let homogeneous = homogeneous_params(data);
    let (use_source, why) = resolve_source(data, source, homogeneous.is_some());
    let footprint_load = report_footprint_load(
        data,
        if use_source == MaterialSource::Homogeneous {
            "homogeneous.patch.load"
        } else {
            "examples.patch.load"
        },
    )?;
    let nt = mesh.tets.len();
    let (params, basis, name, channel) = match use_source {
        MaterialSource::Basis => {
            let Some(basis) = &data.basis else {
                return Err(bad(
                    "/tissue/basis: missing (material source `basis`)".into()
                ));
            };
            let material = strain_space_material(data, basis)
                .map_err(|w| bad(format!("/tissue/basis: {w}")))?;
            let zero = nalgebra::Vector6::zeros();
            let p0 = (0..nt).map(|e| material.evaluate(e, &zero)).collect();
            (
                p0,
                Some(Arc::new(material)),
                "strain-space basis",
                "/tissue/basis",
            )
        }
        MaterialSource::Homogeneous => {
            let Some(p) = homogeneous else {
                return Err(bad(
                    "/tissue/report: no homogeneous.lambda / homogeneous.alpha (material source `homogeneous`)"
                        .into(),
                ));
            };
            (
                vec![p; nt],
                None,
                "homogeneous baseline",
                "/tissue/report homogeneous",
            )
        }
        MaterialSource::ExampleMean | MaterialSource::Auto => {
            if data.element_materials.is_empty() {
                return Err(bad(
                    "neither /tissue/basis nor /tissue/element_material present".into(),
                ));
            }
            (
                example_mean_params(data, nt),
                None,
                "mean per-example parameters",
                "/tissue/element_material",
            )
        }
    };
    let model =
        CorotationalModel::new(&mesh, params).map_err(|e| bad(format!("{channel}: {e}")))?;
    Ok(MaterialModel {
        mesh,
        model,
        basis,
        source: if why.is_empty() {
            name.to_string()
        } else {
            format!("{name} ({why})")
        },
        footprint_load,
    })
}

/// The tissue fit's homogeneous baseline (`homogeneous.lambda`, `homogeneous.alpha` of its
/// report), when present and valid.
fn homogeneous_params(data: &MaterialData) -> Option<LinearParams> {
    match (
        report_number(data, "homogeneous.lambda"),
        report_number(data, "homogeneous.alpha"),
    ) {
        (Some(l), Some(a)) if l.is_finite() && a.is_finite() && a > 0.0 => Some(LinearParams {
            lambda: l,
            alpha: a,
        }),
        _ => None,
    }
}

/// The leave-one-location-out comparison of the tissue fit's report (`heldout.*`, m and counts):
/// (homogeneous RMS, its failures, material RMS, its failures), when complete.
fn report_heldout(data: &MaterialData) -> Option<(f64, f64, f64, f64)> {
    Some((
        report_number(data, "heldout.homogeneous_rms")?,
        report_number(data, "heldout.homogeneous_failures")?,
        report_number(data, "heldout.material_rms")?,
        report_number(data, "heldout.material_failures")?,
    ))
}

/// The material source `source` stands for, and why when it was chosen automatically
/// ([`MaterialSource::Auto`]: by the held-out comparison of the report when it has one).
fn resolve_source(
    data: &MaterialData,
    source: MaterialSource,
    has_homogeneous: bool,
) -> (MaterialSource, String) {
    if source != MaterialSource::Auto {
        return (source, String::new());
    }
    let heldout = report_heldout(data);
    match (has_homogeneous, data.basis.is_some(), heldout) {
        (true, has_basis, Some((hom, hom_failed, mat, mat_failed))) => {
            let bound = (1.0 - AUTO_MATERIAL_MARGIN) * hom;
            let numbers = format!(
                "held-out RMS (leave one probe location out) material {:.4} mm ({mat_failed} failed), homogeneous {:.4} mm ({hom_failed} failed)",
                1e3 * mat,
                1e3 * hom
            );
            // `<=` on finite numbers only: a NaN or infinite RMS never selects the material.
            if has_basis && mat.is_finite() && mat <= bound && mat_failed <= hom_failed {
                (
                    MaterialSource::Basis,
                    format!(
                        "auto: strain-space material, {numbers}: at least {:.0} % below the homogeneous",
                        100.0 * AUTO_MATERIAL_MARGIN
                    ),
                )
            } else {
                (
                    MaterialSource::Homogeneous,
                    format!(
                        "auto: homogeneous baseline, {numbers}: the material is not {:.0} % below it{}",
                        100.0 * AUTO_MATERIAL_MARGIN,
                        if has_basis { "" } else { " (no basis)" }
                    ),
                )
            }
        }
        (true, _, None) => (
            MaterialSource::Homogeneous,
            "auto: homogeneous baseline (no held-out comparison in the report)".into(),
        ),
        (false, true, _) => (
            MaterialSource::Basis,
            "auto: basis (no homogeneous baseline in the report)".into(),
        ),
        (false, false, _) => (
            MaterialSource::ExampleMean,
            "auto: mean per-example parameters (no basis or homogeneous fit)".into(),
        ),
    }
}

/// The mean of the per-example element parameters, per element.
fn example_mean_params(data: &MaterialData, nt: usize) -> Vec<LinearParams> {
    let count = data.element_materials.len() as f64;
    (0..nt)
        .map(|e| {
            let (l, a) = data
                .element_materials
                .iter()
                .fold((0.0, 0.0), |acc, (_, x)| {
                    (acc.0 + x.lambda_pa[e], acc.1 + x.alpha_pa[e])
                });
            LinearParams {
                lambda: l / count,
                alpha: a / count,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::key_value::Value;

    /// One tet with a homogeneous baseline and `extra` report entries.
    fn material(extra: Vec<proto::KeyValue>) -> MaterialData {
        let number = |key: &str, x: f64| proto::KeyValue {
            key: key.into(),
            value: Some(Value::Number(x)),
            unit: "Pa".into(),
        };
        let mut entries = vec![
            number("homogeneous.lambda", 1.0e5),
            number("homogeneous.alpha", 2.0e4),
        ];
        entries.extend(extra);
        MaterialData {
            path: "material.mcap".into(),
            vertices_m: vec![
                [0.0; 3],
                [0.01, 0.0, 0.0],
                [0.0, 0.01, 0.0],
                [0.0, 0.0, 0.01],
            ],
            tets: vec![[0, 1, 2, 3]],
            element_materials: Vec::new(),
            basis: None,
            report: Some(proto::Report {
                title: "test".into(),
                entries,
            }),
        }
    }

    fn text(key: &str, v: Value) -> proto::KeyValue {
        proto::KeyValue {
            key: key.into(),
            value: Some(v),
            unit: String::new(),
        }
    }

    /// The replay's footprint load is the one the tissue fit recorded; files without the entry
    /// give `None` (the settings' load); an unknown name or a non-text entry is bad input.
    #[test]
    fn footprint_load_is_read_from_the_fit_report() {
        let read = |extra| material_model_from(&material(extra), MaterialSource::Homogeneous);
        let m = read(vec![text(
            "homogeneous.patch.load",
            Value::Text("flat-punch".into()),
        )])
        .unwrap();
        assert_eq!(m.footprint_load, Some(FootprintLoad::FlatPunch));
        assert_eq!(read(Vec::new()).unwrap().footprint_load, None);
        // The per-example entry belongs to the other default models.
        let m = read(vec![text(
            "examples.patch.load",
            Value::Text("consistent".into()),
        )])
        .unwrap();
        assert_eq!(m.footprint_load, None);
        for bad in [Value::Text("punch".into()), Value::Number(1.0)] {
            let e = read(vec![text("homogeneous.patch.load", bad)])
                .err()
                .unwrap();
            assert!(
                matches!(&e, DiagnoseError::BadInput { what, .. } if what.contains("homogeneous.patch.load")),
                "{e}"
            );
        }
    }

    /// `Auto` takes the strain-space material when its leave-one-location-out RMS is at least
    /// [`AUTO_MATERIAL_MARGIN`] below the homogeneous baseline's with no more failures, else the
    /// baseline; a report without the comparison keeps the baseline.
    #[test]
    fn auto_picks_the_material_by_its_heldout_error() {
        let number = |key: &str, x: f64| proto::KeyValue {
            key: key.into(),
            value: Some(Value::Number(x)),
            unit: String::new(),
        };
        let pick = |heldout: Option<(f64, f64, f64, f64)>, basis: bool| {
            let extra = heldout.map_or(Vec::new(), |(h, hf, m, mf)| {
                vec![
                    number("heldout.homogeneous_rms", h),
                    number("heldout.homogeneous_failures", hf),
                    number("heldout.material_rms", m),
                    number("heldout.material_failures", mf),
                ]
            });
            let mut data = material(extra);
            data.basis = basis.then(proto::StrainSpaceBasis::default);
            resolve_source(&data, MaterialSource::Auto, true)
        };
        let basis = MaterialSource::Basis;
        let homogeneous = MaterialSource::Homogeneous;
        // 1.25e-4 m homogeneous: the bound is 1.225e-4 m.
        assert_eq!(pick(Some((1.25e-4, 0.0, 1.0e-4, 0.0)), true).0, basis);
        assert_eq!(pick(Some((1.25e-4, 0.0, 1.2249e-4, 0.0)), true).0, basis);
        let (s, why) = pick(Some((1.25e-4, 0.0, 1.2251e-4, 0.0)), true);
        assert_eq!(s, homogeneous);
        assert!(
            why.contains("0.1225 mm") && why.contains("0.1250 mm"),
            "{why}"
        );
        // More failed held-out simulations, a non-finite RMS, no basis, no comparison.
        assert_eq!(pick(Some((1.25e-4, 0.0, 1.0e-4, 1.0)), true).0, homogeneous);
        assert_eq!(pick(Some((1.25e-4, 1.0, 1.0e-4, 1.0)), true).0, basis);
        assert_eq!(
            pick(Some((1.25e-4, 0.0, f64::NAN, 0.0)), true).0,
            homogeneous
        );
        assert_eq!(
            pick(Some((1.25e-4, 0.0, 1.0e-4, 0.0)), false).0,
            homogeneous
        );
        assert_eq!(pick(None, true).0, homogeneous);
        // An explicit source is taken as given.
        let data = material(Vec::new());
        assert_eq!(resolve_source(&data, basis, true), (basis, String::new()));
    }
}
