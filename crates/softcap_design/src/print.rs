//! Multi-material print file of a layered design (thesis §8.4 output, §8.5 "the resulting
//! designs were printed on a multi-material 3D printer"): a 3MF package with one `basematerials`
//! group (one base per library material used) and **one mesh object per material**, holding
//! the closed slab of every layer made of it (layers of one material that are not adjacent are
//! disjoint shells of the same object; adjacent ones are merged into one slab). Written and
//! read with the maintained `threemf` crate (0BSD), units millimetres.

use crate::error::{DesignError, Result};
use std::path::Path;
use threemf::model::{
    Base, BaseMaterials, Build, Item, Mesh, Model, Object, Resources, Triangle, Triangles, Unit,
    Vertex, Vertices,
};

/// Display colours of the bases (sRGB), cycled.
const COLOURS: [&str; 9] = [
    "#E6194BFF",
    "#3CB44BFF",
    "#FFE119FF",
    "#4363D8FF",
    "#F58231FF",
    "#911EB4FF",
    "#46F0F0FF",
    "#F032E6FF",
    "#BCF60CFF",
];

/// One printable part read back from a 3MF: its name, base-material index and closed slabs
/// (z ranges in mm).
#[derive(Clone, Debug, PartialEq)]
pub struct PrintPart {
    /// Object name (`material <index>`).
    pub name: String,
    /// Index into the `basematerials` group (`pindex`).
    pub base_index: usize,
    /// Vertices \[mm\].
    pub vertices: Vec<[f64; 3]>,
    /// Triangles (vertex indices).
    pub triangles: Vec<[usize; 3]>,
}

/// Writes `design` (material index per layer, bottom first) as a block of
/// `block_size_m` with layer thicknesses `layer_thickness_m` to `path` (atomically:
/// `NAME.3mf.PID-N.tmp`, fsync, rename). `material_names` names the library entries.
pub fn write_design_3mf(
    path: &Path,
    design: &[usize],
    layer_thickness_m: &[f64],
    block_size_m: [f64; 3],
    material_names: &[String],
) -> Result<()> {
    if design.is_empty() || design.len() != layer_thickness_m.len() {
        return Err(DesignError::Invalid {
            field: "design / layer thicknesses",
            reason: format!(
                "{} layers but {} thicknesses",
                design.len(),
                layer_thickness_m.len()
            ),
        });
    }
    if let Some(&m) = design.iter().find(|&&m| m >= material_names.len()) {
        return Err(DesignError::Invalid {
            field: "design",
            reason: format!("material {m} but {} names", material_names.len()),
        });
    }
    let mut used: Vec<usize> = design.to_vec();
    used.sort_unstable();
    used.dedup();
    let (w, l) = (block_size_m[0] * 1e3, block_size_m[1] * 1e3);
    // Slabs: maximal runs of equal material, z in mm.
    let mut slabs: Vec<(usize, f64, f64)> = Vec::new();
    let mut z = 0.0;
    for (&m, &t) in design.iter().zip(layer_thickness_m) {
        let z1 = z + t * 1e3;
        match slabs.last_mut() {
            Some((lm, _, top)) if *lm == m => *top = z1,
            _ => slabs.push((m, z, z1)),
        }
        z = z1;
    }
    let mut objects = Vec::new();
    for (k, &m) in used.iter().enumerate() {
        let mut vertex = Vec::new();
        let mut triangle = Vec::new();
        for &(_, z0, z1) in slabs.iter().filter(|s| s.0 == m) {
            let o = vertex.len();
            for (x, y, zz) in [
                (0.0, 0.0, z0),
                (w, 0.0, z0),
                (w, l, z0),
                (0.0, l, z0),
                (0.0, 0.0, z1),
                (w, 0.0, z1),
                (w, l, z1),
                (0.0, l, z1),
            ] {
                vertex.push(Vertex { x, y, z: zz });
            }
            // Outward, counter-clockwise seen from outside.
            for [a, b, c] in [
                [0, 2, 1],
                [0, 3, 2],
                [4, 5, 6],
                [4, 6, 7],
                [0, 1, 5],
                [0, 5, 4],
                [1, 2, 6],
                [1, 6, 5],
                [2, 3, 7],
                [2, 7, 6],
                [3, 0, 4],
                [3, 4, 7],
            ] {
                triangle.push(Triangle {
                    v1: o + a,
                    v2: o + b,
                    v3: o + c,
                });
            }
        }
        objects.push(Object {
            id: k + 2,
            name: Some(format!("material {m}: {}", material_names[m])),
            pid: Some(1),
            pindex: Some(k),
            mesh: Some(Mesh {
                vertices: Vertices { vertex },
                triangles: Triangles { triangle },
            }),
            ..Object::default()
        });
    }
    let model = Model {
        resources: Resources {
            basematerials: Some(vec![BaseMaterials {
                id: 1,
                base: used
                    .iter()
                    .map(|&m| Base {
                        name: material_names[m].clone(),
                        displaycolor: COLOURS[m % COLOURS.len()].into(),
                    })
                    .collect(),
            }]),
            object: objects,
        },
        build: Build {
            item: (0..used.len())
                .map(|k| Item {
                    objectid: k + 2,
                    transform: None,
                    partnumber: None,
                })
                .collect(),
        },
        unit: Unit::Millimeter,
        ..Model::default()
    };
    softcap_app::write_atomic_with(path, |file| {
        threemf::write(file, model).map_err(|e| std::io::Error::other(format!("writing 3MF: {e}")))
    })
    .map_err(|source| DesignError::Io {
        path: path.into(),
        source,
    })
}

/// Reads the mesh objects of a 3MF written by [`write_design_3mf`] (or any 3MF with mesh
/// objects); errors name the file.
pub fn read_design_3mf(path: &Path) -> Result<Vec<PrintPart>> {
    let file = std::fs::File::open(path).map_err(|source| DesignError::Io {
        path: path.into(),
        source,
    })?;
    let models = threemf::read(std::io::BufReader::new(file)).map_err(|e| DesignError::File {
        path: path.into(),
        reason: format!("reading 3MF: {e}"),
    })?;
    let mut out = Vec::new();
    for model in models {
        for o in model.resources.object {
            let Some(mesh) = o.mesh else { continue };
            out.push(PrintPart {
                name: o.name.unwrap_or_default(),
                base_index: o.pindex.unwrap_or(0),
                vertices: mesh
                    .vertices
                    .vertex
                    .iter()
                    .map(|v| [v.x, v.y, v.z])
                    .collect(),
                triangles: mesh
                    .triangles
                    .triangle
                    .iter()
                    .map(|t| [t.v1, t.v2, t.v3])
                    .collect(),
            });
        }
    }
    Ok(out)
}

impl PrintPart {
    /// Enclosed volume \[mm³\] by the divergence theorem (positive for outward triangles).
    pub fn volume_mm3(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i]);
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0]))
                    / 6.0
            })
            .sum()
    }
}
