//! Wavefront OBJ: `v`, `vt`, `vn`, and polygonal `f` records.
//!
//! Polygons keep their original structure in [`ObjMesh::polygons`]; [`ObjMesh::triangulate`]
//! ear-clips them (fan for convex polygons) and reports which polygon each triangle came from.
//! The ICT-FaceKit meshes mix quads and triangles. Indices are 1-based in the file (negative
//! indices count back from the last vertex) and 0-based in memory.

use crate::error::{MeshError, Result};
use crate::io::{field, open, write_atomic};
use crate::triangulate::triangulate_polygon;
use crate::types::TriMesh;
use nalgebra::Vector3;
use std::io::{BufRead, Write};
use std::path::Path;

/// The contents of an OBJ file, polygon structure preserved.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ObjMesh {
    /// Vertex positions (`v`), in the file's units.
    pub vertices: Vec<Vector3<f64>>,
    /// Texture coordinates (`vt`): u, v.
    pub texcoords: Vec<[f64; 2]>,
    /// Normals (`vn`).
    pub normals: Vec<Vector3<f64>>,
    /// Faces (`f`) as 0-based vertex indices, in file order.
    pub polygons: Vec<Vec<usize>>,
    /// Per face, its 0-based texture-coordinate indices (empty when the face has none).
    pub polygon_texcoords: Vec<Vec<usize>>,
    /// Per face, its 0-based normal indices (empty when the face has none).
    pub polygon_normals: Vec<Vec<usize>>,
}

impl ObjMesh {
    /// Triangulates every polygon (see [`triangulate_polygon`]); returns the triangle mesh and,
    /// per triangle, the index of the polygon it came from.
    pub fn triangulate(&self) -> (TriMesh, Vec<usize>) {
        let mut triangles = Vec::with_capacity(self.polygons.len() * 2);
        let mut origin = Vec::with_capacity(self.polygons.len() * 2);
        for (p, poly) in self.polygons.iter().enumerate() {
            for t in triangulate_polygon(&self.vertices, poly) {
                triangles.push(t);
                origin.push(p);
            }
        }
        (
            TriMesh {
                vertices: self.vertices.clone(),
                triangles,
            },
            origin,
        )
    }

    /// The triangulated mesh (see [`ObjMesh::triangulate`]).
    pub fn to_tri_mesh(&self) -> TriMesh {
        self.triangulate().0
    }

    /// An OBJ holding a triangle mesh (no texture coordinates or normals).
    pub fn from_tri_mesh(mesh: &TriMesh) -> Self {
        ObjMesh {
            vertices: mesh.vertices.clone(),
            polygons: mesh.triangles.iter().map(|t| t.to_vec()).collect(),
            polygon_texcoords: vec![Vec::new(); mesh.triangles.len()],
            polygon_normals: vec![Vec::new(); mesh.triangles.len()],
            ..Default::default()
        }
    }
}

/// Reads an OBJ file.
pub fn read_obj(path: impl AsRef<Path>) -> Result<ObjMesh> {
    let path = path.as_ref();
    read_obj_from(open(path)?, path)
}

/// Reads an OBJ file and triangulates it (see [`ObjMesh::triangulate`]).
pub fn read_obj_tri_mesh(path: impl AsRef<Path>) -> Result<TriMesh> {
    Ok(read_obj(path)?.to_tri_mesh())
}

/// Reads OBJ text from `reader`; `name` identifies it in errors.
pub fn read_obj_from(mut reader: impl BufRead, name: impl AsRef<Path>) -> Result<ObjMesh> {
    let name = name.as_ref();
    let mut mesh = ObjMesh::default();
    let mut buf = String::new();
    let mut line_no = 0;
    loop {
        buf.clear();
        let n = reader
            .read_line(&mut buf)
            .map_err(|e| MeshError::io(name, e))?;
        if n == 0 {
            break;
        }
        line_no += 1;
        parse_line(&buf, &mut mesh).map_err(|m| MeshError::parse(name, line_no, m))?;
    }
    Ok(mesh)
}

fn parse_line(line: &str, mesh: &mut ObjMesh) -> std::result::Result<(), String> {
    let content = line.split('#').next().unwrap_or("");
    let mut tokens = content.split_whitespace();
    let Some(keyword) = tokens.next() else {
        return Ok(());
    };
    match keyword {
        "v" => {
            let x = field(&mut tokens, "vertex x")?;
            let y = field(&mut tokens, "vertex y")?;
            let z = field(&mut tokens, "vertex z")?;
            // Optional w or per-vertex colour: must still be numbers.
            for t in tokens {
                t.parse::<f64>()
                    .map_err(|_| format!("unexpected token {t:?} after vertex coordinates"))?;
            }
            let p = Vector3::new(x, y, z);
            finite(&p, "vertex")?;
            mesh.vertices.push(p);
        }
        "vt" => {
            let u = field(&mut tokens, "texture u")?;
            let v = match tokens.next() {
                Some(t) => t
                    .parse()
                    .map_err(|_| format!("cannot parse texture v from {t:?}"))?,
                None => 0.0,
            };
            mesh.texcoords.push([u, v]);
        }
        "vn" => {
            let x = field(&mut tokens, "normal x")?;
            let y = field(&mut tokens, "normal y")?;
            let z = field(&mut tokens, "normal z")?;
            let n = Vector3::new(x, y, z);
            finite(&n, "normal")?;
            mesh.normals.push(n);
        }
        "f" => {
            let mut v = Vec::new();
            let mut vt = Vec::new();
            let mut vn = Vec::new();
            for (corner, tok) in tokens.enumerate() {
                let mut parts = tok.split('/');
                let pv = parts.next().unwrap_or("");
                let pt = parts.next().unwrap_or("");
                let pn = parts.next().unwrap_or("");
                if parts.next().is_some() {
                    return Err(format!("face corner {tok:?} has more than three indices"));
                }
                v.push(resolve(pv, mesh.vertices.len(), "vertex", corner)?);
                if !pt.is_empty() {
                    vt.push(resolve(pt, mesh.texcoords.len(), "texture", corner)?);
                }
                if !pn.is_empty() {
                    vn.push(resolve(pn, mesh.normals.len(), "normal", corner)?);
                }
            }
            if v.len() < 3 {
                return Err(format!("face has {} vertices, need at least 3", v.len()));
            }
            if !vt.is_empty() && vt.len() != v.len() {
                return Err("face gives texture indices for some corners only".into());
            }
            if !vn.is_empty() && vn.len() != v.len() {
                return Err("face gives normal indices for some corners only".into());
            }
            mesh.polygons.push(v);
            mesh.polygon_texcoords.push(vt);
            mesh.polygon_normals.push(vn);
        }
        // Grouping, materials, smoothing, lines and points carry no geometry we use.
        "o" | "g" | "s" | "usemtl" | "mtllib" | "l" | "p" | "vp" => {}
        other => return Err(format!("unknown OBJ statement {other:?}")),
    }
    Ok(())
}

/// Rejects NaN or infinite coordinates.
pub(crate) fn finite(p: &Vector3<f64>, what: &str) -> std::result::Result<(), String> {
    match p.iter().position(|c| !c.is_finite()) {
        Some(a) => Err(format!(
            "{what} coordinate {} is {}",
            ["x", "y", "z"][a],
            p[a]
        )),
        None => Ok(()),
    }
}

/// Resolves a 1-based (or negative, relative) OBJ index against `count` defined items.
fn resolve(
    tok: &str,
    count: usize,
    what: &str,
    corner: usize,
) -> std::result::Result<usize, String> {
    let i: i64 = tok
        .parse()
        .map_err(|_| format!("face corner {corner}: cannot parse {what} index from {tok:?}"))?;
    let resolved = if i > 0 {
        i - 1
    } else if i < 0 {
        count as i64 + i
    } else {
        return Err(format!(
            "face corner {corner}: {what} index 0 (OBJ indices start at 1)"
        ));
    };
    if resolved < 0 || resolved >= count as i64 {
        return Err(format!(
            "face corner {corner}: {what} index {i} out of range ({count} defined so far)"
        ));
    }
    Ok(resolved as usize)
}

/// Writes an OBJ file (atomically), polygons as stored.
pub fn write_obj(path: impl AsRef<Path>, mesh: &ObjMesh) -> Result<()> {
    let path = path.as_ref();
    write_atomic(path, |w| write_obj_to(w, mesh))
}

/// Writes a triangle mesh as OBJ (atomically).
pub fn write_tri_mesh_obj(path: impl AsRef<Path>, mesh: &TriMesh) -> Result<()> {
    write_obj(path, &ObjMesh::from_tri_mesh(mesh))
}

/// Writes OBJ text. Coordinates use Rust's shortest round-trip float formatting, so reading
/// the output back reproduces every coordinate bit for bit.
pub fn write_obj_to(w: &mut impl Write, mesh: &ObjMesh) -> std::io::Result<()> {
    writeln!(w, "# written by softcap_mesh")?;
    for v in &mesh.vertices {
        writeln!(w, "v {} {} {}", v.x, v.y, v.z)?;
    }
    for t in &mesh.texcoords {
        writeln!(w, "vt {} {}", t[0], t[1])?;
    }
    for n in &mesh.normals {
        writeln!(w, "vn {} {} {}", n.x, n.y, n.z)?;
    }
    for (p, poly) in mesh.polygons.iter().enumerate() {
        let vt = mesh
            .polygon_texcoords
            .get(p)
            .filter(|t| t.len() == poly.len());
        let vn = mesh
            .polygon_normals
            .get(p)
            .filter(|t| t.len() == poly.len());
        write!(w, "f")?;
        for (c, &v) in poly.iter().enumerate() {
            match (vt, vn) {
                (None, None) => write!(w, " {}", v + 1)?,
                (Some(t), None) => write!(w, " {}/{}", v + 1, t[c] + 1)?,
                (None, Some(n)) => write!(w, " {}//{}", v + 1, n[c] + 1)?,
                (Some(t), Some(n)) => write!(w, " {}/{}/{}", v + 1, t[c] + 1, n[c] + 1)?,
            }
        }
        writeln!(w)?;
    }
    Ok(())
}
