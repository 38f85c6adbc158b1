//! Reading the stage inputs: `capture.mcap` (through `softcap_mcap::capture::CaptureData`) into a
//! [`Recording`], and `material.mcap` (`/mesh/volume` + `/tissue/basis` or
//! `/tissue/element_material`) into the default model.

use crate::recording::{Frame, Recording, SupportPlane, surface_normals};
use crate::{DiagnoseError, Result};
use nalgebra::{Vector3, Vector6};
use softcap_fem::{CorotationalModel, LinearParams};
use softcap_mcap::capture::CaptureData;
use softcap_mcap::{proto, topics};
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

/// Per-element strain-space RBF read from `/tissue/basis` (bickel2009 eq. 8): p_e(ε) = Σᵢ wᵢ φ(‖ε −
/// εᵢ‖), φ(r) = r or r³, no polynomial tail; evaluated parameters are kept valid (λ ≥ 1 % of the
/// element's value at zero strain, ν = α/λ ∈ [0, 0.49]).
#[derive(Clone, Debug)]
pub struct StrainBasis {
    cubic: bool,
    m: usize,
    centers: Vec<f64>,
    weights: Vec<f64>,
    lambda_floor_pa: Vec<f64>,
}

impl StrainBasis {
    fn raw(&self, e: usize, strain: &[f64; 6]) -> [f64; 2] {
        let mut out = [0.0; 2];
        for i in 0..self.m {
            let c = &self.centers[(e * self.m + i) * 6..(e * self.m + i) * 6 + 6];
            let r = c
                .iter()
                .zip(strain)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt();
            let phi = if self.cubic { r * r * r } else { r };
            out[0] += self.weights[(e * self.m + i) * 2] * phi;
            out[1] += self.weights[(e * self.m + i) * 2 + 1] * phi;
        }
        out
    }
}

impl softcap_fem::StrainDependentParams for StrainBasis {
    fn params(&self, element: usize, strain: &Vector6<f64>) -> LinearParams {
        let s = [
            strain[0], strain[1], strain[2], strain[3], strain[4], strain[5],
        ];
        let [l, a] = self.raw(element, &s);
        let lambda = l.max(self.lambda_floor_pa[element]);
        let alpha = a.clamp(0.0, 0.49 * lambda);
        LinearParams { lambda, alpha }
    }
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

/// Reads `material.mcap`.
pub fn read_material(path: &Path) -> Result<MaterialModel> {
    let mcap = |source: softcap_mcap::Error| DiagnoseError::Mcap {
        path: path.to_path_buf(),
        source: Box::new(source),
    };
    let bad = |what: String| DiagnoseError::BadInput {
        path: path.to_path_buf(),
        what,
    };
    let r = softcap_mcap::Recording::open(path).map_err(mcap)?;
    let vm: proto::TetMesh = r
        .read_static(&topics::VOLUME_MESH)
        .map_err(|e| bad(format!("/mesh/volume: {e}")))?;
    if !vm.positions_m.len().is_multiple_of(3)
        || !vm.tets.len().is_multiple_of(4)
        || vm.tets.is_empty()
    {
        return Err(bad(
            "/mesh/volume: positions/tets lengths are not multiples of 3/4".into(),
        ));
    }
    let nv = vm.positions_m.len() / 3;
    let mesh = TetMesh {
        vertices: vm
            .positions_m
            .chunks(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect(),
        tets: vm
            .tets
            .chunks(4)
            .map(|c| [c[0] as usize, c[1] as usize, c[2] as usize, c[3] as usize])
            .collect(),
    };
    if let Some((t, _)) = mesh
        .tets
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&v| v >= nv))
    {
        return Err(bad(format!(
            "/mesh/volume: tet {t} references a missing vertex"
        )));
    }
    if mesh
        .vertices
        .iter()
        .any(|v| !v.iter().all(|c| c.is_finite()))
    {
        return Err(bad("/mesh/volume: non-finite vertex".into()));
    }
    let nt = mesh.tets.len();
    let examples: Vec<proto::ElementMaterial> =
        if r.channel(topics::ELEMENT_MATERIAL.name()).is_some() {
            r.read(&topics::ELEMENT_MATERIAL)
                .map_err(mcap)?
                .into_iter()
                .map(|x| x.1)
                .collect()
        } else {
            Vec::new()
        };
    // mean per-example parameters: the fallback and the zero-strain reference of the clamp
    let mut mean = vec![
        LinearParams {
            lambda: 0.0,
            alpha: 0.0
        };
        nt
    ];
    let mut count = 0usize;
    for ex in &examples {
        if ex.lambda_pa.len() != nt || ex.alpha_pa.len() != nt {
            return Err(bad(format!(
                "/tissue/element_material example {}: {} λ for {nt} tets",
                ex.example,
                ex.lambda_pa.len()
            )));
        }
        for e in 0..nt {
            mean[e].lambda += ex.lambda_pa[e];
            mean[e].alpha += ex.alpha_pa[e];
        }
        count += 1;
    }
    if r.channel(topics::STRAIN_SPACE_BASIS.name()).is_some() {
        let b: proto::StrainSpaceBasis =
            r.read_static(&topics::STRAIN_SPACE_BASIS).map_err(mcap)?;
        let m = b.center_examples.len();
        if b.elements as usize != nt
            || b.centers_strain.len() != nt * m * 6
            || b.weights.len() != nt * m * 2
        {
            return Err(bad(format!(
                "/tissue/basis: {} elements, {} centres: array lengths do not match",
                b.elements, m
            )));
        }
        if !(b.tail.is_empty() || b.tail == "none") {
            return Err(bad(format!(
                "/tissue/basis: tail '{}' is not supported (only none)",
                b.tail
            )));
        }
        let cubic = match b.kernel.as_str() {
            "r" | "" => false,
            "r3" => true,
            k => return Err(bad(format!("/tissue/basis: unknown kernel '{k}'"))),
        };
        let mut basis = StrainBasis {
            cubic,
            m,
            centers: b.centers_strain,
            weights: b.weights,
            lambda_floor_pa: vec![0.0; nt],
        };
        let mut p0 = Vec::with_capacity(nt);
        for e in 0..nt {
            let [l, a] = basis.raw(e, &[0.0; 6]);
            let l = if l > 0.0 {
                l
            } else {
                mean[e].lambda / count.max(1) as f64
            };
            basis.lambda_floor_pa[e] = 0.01 * l.max(1.0);
            p0.push(LinearParams {
                lambda: l.max(1.0),
                alpha: a.clamp(0.0, 0.49 * l.max(1.0)),
            });
        }
        let model = CorotationalModel::new(&mesh, p0)
            .map_err(|e| bad(format!("/tissue/basis: {e}")))?
            .with_strain_dependence(Arc::new(basis));
        return Ok(MaterialModel {
            mesh,
            model,
            source: "strain-space basis",
        });
    }
    if count == 0 {
        return Err(bad(
            "neither /tissue/basis nor /tissue/element_material present".into(),
        ));
    }
    for p in &mut mean {
        p.lambda /= count as f64;
        p.alpha /= count as f64;
    }
    let model = CorotationalModel::new(&mesh, mean)
        .map_err(|e| bad(format!("/tissue/element_material: {e}")))?;
    Ok(MaterialModel {
        mesh,
        model,
        source: "mean per-example parameters",
    })
}
