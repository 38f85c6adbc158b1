//! Reading the stage inputs: `capture.mcap` (through `softcap_mcap::capture::CaptureData`) into a
//! [`Recording`], and `material.mcap` (through `softcap_mcap::material::MaterialData`:
//! `/mesh/volume` + `/tissue/basis` or `/tissue/element_material`) into the default model.

use crate::recording::{Frame, Recording, SupportPlane, surface_normals};
use crate::{DiagnoseError, Result};
use nalgebra::Vector3;
use softcap_fem::probing::{ElementRbf, StrainSpaceMaterial};
use softcap_fem::{CorotationalModel, LinearParams};
use softcap_mcap::capture::CaptureData;
use softcap_mcap::material::MaterialData;
use softcap_mcap::proto;
use softcap_mesh::TetMesh;
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

/// The default model of a material.mcap.
pub struct MaterialModel {
    /// The fitted mesh (SI).
    pub mesh: TetMesh,
    /// The corotational model (strain-dependent when a basis is present).
    pub model: CorotationalModel,
    /// "strain-space basis" or "mean per-example parameters".
    pub source: &'static str,
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
    if !(basis.tail.is_empty() || basis.tail == "none") {
        return Err(format!(
            "tail '{}' is not supported (only none)",
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
    })
}

/// Reads `material.mcap` through [`MaterialData::read`]: the strain-space basis when present
/// (bickel2009 §3.3), else the mean of the per-example element parameters.
pub fn read_material(path: &Path) -> Result<MaterialModel> {
    let data = MaterialData::read(path).map_err(|source| DiagnoseError::Mcap {
        path: path.to_path_buf(),
        source: Box::new(source),
    })?;
    material_model(&data)
}

/// The default model of already-read material data.
pub fn material_model(data: &MaterialData) -> Result<MaterialModel> {
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
    let nt = mesh.tets.len();
    if let Some(basis) = &data.basis {
        let material =
            strain_space_material(data, basis).map_err(|w| bad(format!("/tissue/basis: {w}")))?;
        let model = Arc::new(material)
            .model(&mesh)
            .map_err(|e| bad(format!("/tissue/basis: {e}")))?;
        return Ok(MaterialModel {
            mesh,
            model,
            source: "strain-space basis",
        });
    }
    if data.element_materials.is_empty() {
        return Err(bad(
            "neither /tissue/basis nor /tissue/element_material present".into(),
        ));
    }
    let count = data.element_materials.len() as f64;
    let mean: Vec<LinearParams> = (0..nt)
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
        .collect();
    let model = CorotationalModel::new(&mesh, mean)
        .map_err(|e| bad(format!("/tissue/element_material: {e}")))?;
    Ok(MaterialModel {
        mesh,
        model,
        source: "mean per-example parameters",
    })
}
