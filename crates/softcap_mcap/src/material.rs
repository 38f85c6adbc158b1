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

/// One tet's strain-space RBF (bickel2009 eq. 8), trimmed to the centres it uses:
/// [`MaterialData::basis_tet`].
#[derive(Debug, Clone, PartialEq)]
pub struct BasisTet<'a> {
    /// Centre strains εᵢ, 6 per centre (Voigt, `softcap_fem::strain_voigt` order).
    pub centers_strain: &'a [f64],
    /// Weights wᵢ = (w_λ, w_α), 2 per centre, Pa.
    pub weights: &'a [f64],
    /// Strain-space sample of each centre (0 = zero-strain reference, k = example k − 1), if known.
    pub center_samples: &'a [u32],
    /// λ floor of the validity clamp, Pa (0 = none).
    pub lambda_floor_pa: f64,
}

/// Checks the array lengths of a `/tissue/basis` message against T tets (see docs/formats.md).
fn validate_basis(path: &Path, b: &proto::StrainSpaceBasis, num_tets: usize) -> Result<()> {
    let topic = "/tissue/basis";
    let t = num_tets;
    let m = b.center_examples.len();
    let check = |ok: bool, field: &str, problem: &str| {
        if ok {
            Ok(())
        } else {
            Err(invalid(path, topic, field.into(), problem))
        }
    };
    check(
        b.elements as usize == t,
        "elements",
        "differs from the number of tets in /mesh/volume",
    )?;
    check(
        b.centers_strain.len() == t * m * 6,
        "centers_strain",
        "length is not elements × M × 6 (M = length of center_examples)",
    )?;
    check(
        b.weights.len() == t * m * 2,
        "weights",
        "length is not elements × M × 2",
    )?;
    check(
        b.centers_per_tet.is_empty() || b.centers_per_tet.len() == t,
        "centers_per_tet",
        "length is neither 0 nor elements",
    )?;
    if let Some(i) = b.centers_per_tet.iter().position(|&c| c as usize > m) {
        return Err(invalid(
            path,
            topic,
            format!("centers_per_tet[{i}]"),
            "larger than M (length of center_examples)",
        ));
    }
    check(
        b.center_samples.is_empty() || b.center_samples.len() == t * m,
        "center_samples",
        "length is neither 0 nor elements × M",
    )?;
    check(
        b.lambda_floor_pa.is_empty() || b.lambda_floor_pa.len() == t,
        "lambda_floor_pa",
        "length is neither 0 nor elements",
    )?;
    check(
        b.lambda_ceiling_pa.is_empty() || b.lambda_ceiling_pa.len() == t,
        "lambda_ceiling_pa",
        "length is neither 0 nor elements",
    )?;
    let k = match b.tail.as_str() {
        "" | "none" => 0,
        "constant" => 1,
        "linear" => 7,
        "quadratic" => 28,
        other => {
            return Err(invalid(
                path,
                topic,
                "tail".into(),
                &format!("'{other}' is not none / constant / linear / quadratic"),
            ));
        }
    };
    check(
        b.tail_coefficients.is_empty() || b.tail_coefficients.len() == t * k * 2,
        "tail_coefficients",
        "length is neither 0 nor elements × K × 2 (K = 1 / 7 / 28 for constant / linear / quadratic)",
    )?;
    if let Some(i) = b
        .centers_strain
        .iter()
        .chain(&b.weights)
        .chain(&b.lambda_floor_pa)
        .chain(&b.lambda_ceiling_pa)
        .chain(&b.tail_coefficients)
        .position(|v| !v.is_finite())
    {
        return Err(invalid(
            path,
            topic,
            format!(
                "centers_strain / weights / lambda_floor_pa / lambda_ceiling_pa / tail_coefficients (value {i})"
            ),
            "not finite",
        ));
    }
    check(
        b.nu_min.is_finite() && b.nu_max.is_finite() && b.nu_min <= b.nu_max && b.nu_max < 0.5,
        "nu_min / nu_max",
        "must be finite with nu_min <= nu_max < 0.5",
    )
}

impl MaterialData {
    /// Tet `e` of the strain-space basis, trimmed to its `centers_per_tet[e]` centres (all M
    /// when the counts are absent); `None` without a basis or for `e` out of range.
    pub fn basis_tet(&self, e: usize) -> Option<BasisTet<'_>> {
        let b = self.basis.as_ref()?;
        if e >= b.elements as usize {
            return None;
        }
        let m = b.center_examples.len();
        let c = b.centers_per_tet.get(e).map_or(m, |&c| c as usize);
        Some(BasisTet {
            centers_strain: &b.centers_strain[e * m * 6..(e * m + c) * 6],
            weights: &b.weights[e * m * 2..(e * m + c) * 2],
            center_samples: if b.center_samples.is_empty() {
                &[]
            } else {
                &b.center_samples[e * m..e * m + c]
            },
            lambda_floor_pa: b.lambda_floor_pa.get(e).copied().unwrap_or(0.0),
        })
    }

    /// Reads and validates a material file: `/mesh/volume` is required; per-example materials
    /// must have one λ and α per tet, positive λ and finite values.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let r = Recording::open(path)?;
        let path = r.path().to_path_buf();
        let VolumeMesh {
            vertices_m, tets, ..
        } = read_volume_mesh(&r)?;
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
            let b = r.read_static(&topics::STRAIN_SPACE_BASIS)?;
            validate_basis(&path, &b, tets.len())?;
            Some(b)
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

/// A validated `/mesh/volume`: [`read_volume_mesh`].
#[derive(Debug, Clone, PartialEq)]
pub struct VolumeMesh {
    /// Vertex positions, m.
    pub vertices_m: Vec<[f64; 3]>,
    /// Tets (vertex indices).
    pub tets: Vec<[usize; 4]>,
    /// Boundary triangles (vertex indices; empty when the file has none).
    pub surface_triangles: Vec<[usize; 3]>,
}

/// Reads `/mesh/volume` of `r`, validated: flat lengths multiples of 3 / 4 / 3, coordinates
/// finite, vertex indices in range.
pub fn read_volume_mesh(r: &Recording) -> Result<VolumeMesh> {
    let path = r.path().to_path_buf();
    let mesh = r.read_static(&topics::VOLUME_MESH)?;
    let mtopic = "/mesh/volume";
    if mesh.positions_m.len() % 3 != 0
        || mesh.tets.len() % 4 != 0
        || mesh.surface_triangles.len() % 3 != 0
    {
        return Err(invalid(
            &path,
            mtopic,
            "positions_m / tets / surface_triangles".into(),
            "length is not a multiple of 3 / 4 / 3",
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
    if let Some(i) = mesh
        .surface_triangles
        .iter()
        .position(|&v| v as usize >= nv)
    {
        return Err(invalid(
            &path,
            mtopic,
            format!("surface_triangles[{i}]"),
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
    let surface_triangles = mesh
        .surface_triangles
        .chunks_exact(3)
        .map(|c| [c[0] as usize, c[1] as usize, c[2] as usize])
        .collect();
    Ok(VolumeMesh {
        vertices_m,
        tets,
        surface_triangles,
    })
}
