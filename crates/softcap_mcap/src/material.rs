//! Typed reading of a `material.mcap` (the output of `softcap tissue fit`): the fitted volume
//! mesh (SI), the per-example per-tet (λ, α), the strain-space basis and the fit report, so a
//! later stage (diagnose, `tissue simulate`) needs no `--mesh`.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::proto;
use crate::reader::Recording;
use crate::topics;

/// A material read into memory: [`MaterialData::read`].
#[derive(Debug, Clone, PartialEq)]
pub struct MaterialData {
    /// The file read.
    pub path: PathBuf,
    /// `/mesh/volume`: vertex positions (m) and tets (validated: finite, indices in range).
    pub vertices_m: Vec<[f64; 3]>,
    /// Tets (vertex indices).
    pub tets: Vec<[usize; 4]>,
    /// `/tissue/element_material`: one per example, in file order, with its log time (ns).
    pub element_materials: Vec<(u64, proto::ElementMaterial)>,
    /// `/tissue/basis`, if present.
    pub basis: Option<proto::StrainSpaceBasis>,
    /// `/tissue/report`, if present.
    pub report: Option<proto::Report>,
}

fn invalid(path: &Path, topic: &str, field: String, problem: &str) -> Error {
    Error::Invalid {
        path: path.to_path_buf(),
        topic: topic.into(),
        field,
        problem: problem.into(),
    }
}

impl MaterialData {
    /// Reads and validates a material file: `/mesh/volume` is required; per-example materials
    /// must have one λ and α per tet, positive λ and finite values.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let r = Recording::open(path)?;
        let path = r.path().to_path_buf();
        let mesh = r.read_static(&topics::VOLUME_MESH)?;
        let mtopic = "/mesh/volume";
        if mesh.positions_m.len() % 3 != 0 || mesh.tets.len() % 4 != 0 {
            return Err(invalid(
                &path,
                mtopic,
                "positions_m / tets".into(),
                "length is not a multiple of 3 / 4",
            ));
        }
        if let Some(i) = mesh.positions_m.iter().position(|v| !v.is_finite()) {
            return Err(invalid(
                &path,
                mtopic,
                format!("positions_m[{i}]"),
                "not finite",
            ));
        }
        let nv = mesh.positions_m.len() / 3;
        if let Some(i) = mesh.tets.iter().position(|&v| v as usize >= nv) {
            return Err(invalid(
                &path,
                mtopic,
                format!("tets[{i}]"),
                "vertex index out of range",
            ));
        }
        let vertices_m = mesh
            .positions_m
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let tets: Vec<[usize; 4]> = mesh
            .tets
            .chunks_exact(4)
            .map(|c| [c[0] as usize, c[1] as usize, c[2] as usize, c[3] as usize])
            .collect();
        let etopic = "/tissue/element_material";
        let element_materials = if r.channel(etopic).is_some() {
            r.read(&topics::ELEMENT_MATERIAL)?
        } else {
            Vec::new()
        };
        for (_, m) in &element_materials {
            let ex = m.example;
            if m.lambda_pa.len() != tets.len() || m.alpha_pa.len() != tets.len() {
                return Err(invalid(
                    &path,
                    etopic,
                    format!("example {ex} lambda_pa / alpha_pa"),
                    "length differs from the number of tets in /mesh/volume",
                ));
            }
            if let Some(i) = m
                .lambda_pa
                .iter()
                .zip(&m.alpha_pa)
                .position(|(l, a)| !(l.is_finite() && a.is_finite() && *l > 0.0))
            {
                return Err(invalid(
                    &path,
                    etopic,
                    format!("example {ex} lambda_pa[{i}]"),
                    "must be finite and positive (alpha finite)",
                ));
            }
        }
        let basis = if r.channel(topics::STRAIN_SPACE_BASIS.name()).is_some() {
            Some(r.read_static(&topics::STRAIN_SPACE_BASIS)?)
        } else {
            None
        };
        let report = if r.channel(topics::TISSUE_REPORT.name()).is_some() {
            Some(r.read_static(&topics::TISSUE_REPORT)?)
        } else {
            None
        };
        Ok(Self {
            path,
            vertices_m,
            tets,
            element_materials,
            basis,
            report,
        })
    }
}
