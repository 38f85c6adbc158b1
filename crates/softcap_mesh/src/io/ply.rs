//! PLY (Stanford polygon format), ASCII and binary little/big endian.
//!
//! Reads `vertex` elements (properties `x`, `y`, `z` of any numeric type; others skipped) and
//! `face` elements (list property `vertex_indices` or `vertex_index`); other elements are
//! skipped. Writes doubles for coordinates and `list uchar int vertex_indices` for faces.

use crate::error::{MeshError, Result};
use crate::io::{open, write_atomic};
use crate::triangulate::triangulate_polygon;
use crate::types::TriMesh;
use nalgebra::Vector3;
use std::io::{BufRead, Write};
use std::path::Path;

/// PLY body encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum PlyFormat {
    /// `format ascii 1.0`
    Ascii,
    /// `format binary_little_endian 1.0`
    BinaryLittleEndian,
    /// `format binary_big_endian 1.0`
    BinaryBigEndian,
}

/// Vertices and polygonal faces of a PLY file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlyMesh {
    /// Vertex positions, in the file's units.
    pub vertices: Vec<Vector3<f64>>,
    /// Faces as 0-based vertex indices.
    pub polygons: Vec<Vec<usize>>,
}

impl PlyMesh {
    /// Triangulated mesh (polygons ear-clipped, see [`triangulate_polygon`]).
    pub fn to_tri_mesh(&self) -> TriMesh {
        TriMesh {
            vertices: self.vertices.clone(),
            triangles: self
                .polygons
                .iter()
                .flat_map(|p| triangulate_polygon(&self.vertices, p))
                .collect(),
        }
    }

    /// A PLY mesh holding a triangle mesh.
    pub fn from_tri_mesh(mesh: &TriMesh) -> Self {
        PlyMesh {
            vertices: mesh.vertices.clone(),
            polygons: mesh.triangles.iter().map(|t| t.to_vec()).collect(),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn decode(self, b: &[u8], little: bool) -> f64 {
        macro_rules! conv {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                (if little {
                    <$t>::from_le_bytes(a)
                } else {
                    <$t>::from_be_bytes(a)
                }) as f64
            }};
        }
        match self {
            Scalar::I8 => conv!(i8, 1),
            Scalar::U8 => conv!(u8, 1),
            Scalar::I16 => conv!(i16, 2),
            Scalar::U16 => conv!(u16, 2),
            Scalar::I32 => conv!(i32, 4),
            Scalar::U32 => conv!(u32, 4),
            Scalar::F32 => conv!(f32, 4),
            Scalar::F64 => conv!(f64, 8),
        }
    }
}

#[derive(Debug)]
enum Property {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// Reads a PLY file.
pub fn read_ply(path: impl AsRef<Path>) -> Result<PlyMesh> {
    let path = path.as_ref();
    read_ply_from(open(path)?, path)
}

/// Reads a PLY file and triangulates its faces.
pub fn read_ply_tri_mesh(path: impl AsRef<Path>) -> Result<TriMesh> {
    Ok(read_ply(path)?.to_tri_mesh())
}

/// Reads PLY from `reader`; `name` identifies it in errors. ASCII errors carry line numbers;
/// binary errors name the element and row.
pub fn read_ply_from(mut reader: impl BufRead, name: impl AsRef<Path>) -> Result<PlyMesh> {
    let name = name.as_ref();
    let perr = |line: usize, m: String| MeshError::parse(name, line, m);
    let line_no = std::cell::Cell::new(0usize);
    let mut buf = String::new();
    let next_line = |reader: &mut dyn BufRead, buf: &mut String| -> Result<usize> {
        buf.clear();
        let n = reader.read_line(buf).map_err(|e| MeshError::io(name, e))?;
        line_no.set(line_no.get() + 1);
        if n == 0 {
            return Err(MeshError::parse(
                name,
                line_no.get(),
                "unexpected end of file",
            ));
        }
        Ok(line_no.get())
    };
    let l = next_line(&mut reader, &mut buf)?;
    if buf.trim_end() != "ply" {
        return Err(perr(
            l,
            format!("expected magic \"ply\", found {:?}", buf.trim_end()),
        ));
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let l = next_line(&mut reader, &mut buf)?;
        let mut t = buf.split_whitespace();
        match t.next() {
            Some("format") => {
                format = Some(match (t.next(), t.next()) {
                    (Some("ascii"), Some("1.0")) => PlyFormat::Ascii,
                    (Some("binary_little_endian"), Some("1.0")) => PlyFormat::BinaryLittleEndian,
                    (Some("binary_big_endian"), Some("1.0")) => PlyFormat::BinaryBigEndian,
                    _ => return Err(perr(l, format!("unsupported format line {:?}", buf.trim()))),
                })
            }
            Some("comment") | Some("obj_info") | None => {}
            Some("element") => {
                let (Some(ename), Some(count)) = (t.next(), t.next()) else {
                    return Err(perr(l, "element line needs a name and a count".into()));
                };
                let count = count
                    .parse()
                    .map_err(|_| perr(l, format!("cannot parse element count from {count:?}")))?;
                elements.push(Element {
                    name: ename.to_string(),
                    count,
                    properties: Vec::new(),
                });
            }
            Some("property") => {
                let Some(el) = elements.last_mut() else {
                    return Err(perr(l, "property before any element".into()));
                };
                let ty = |s: Option<&str>| {
                    s.and_then(Scalar::parse).ok_or_else(|| {
                        perr(l, format!("unknown property type in {:?}", buf.trim()))
                    })
                };
                let prop = match t.next() {
                    Some("list") => {
                        let ct = ty(t.next())?;
                        let it = ty(t.next())?;
                        let pname = t
                            .next()
                            .ok_or_else(|| perr(l, "list property needs a name".into()))?;
                        Property::List(pname.to_string(), ct, it)
                    }
                    s => {
                        let st = ty(s)?;
                        let pname = t
                            .next()
                            .ok_or_else(|| perr(l, "property needs a name".into()))?;
                        Property::Scalar(pname.to_string(), st)
                    }
                };
                el.properties.push(prop);
            }
            Some("end_header") => break,
            Some(other) => return Err(perr(l, format!("unknown header keyword {other:?}"))),
        }
    }
    let format = format.ok_or_else(|| MeshError::format(name, "header has no format line"))?;
    let mut mesh = PlyMesh::default();
    for el in &elements {
        let is_vertex = el.name == "vertex";
        let is_face = el.name == "face";
        let xyz: [Option<usize>; 3] = ["x", "y", "z"].map(|c| {
            el.properties
                .iter()
                .position(|p| matches!(p, Property::Scalar(n, _) if n == c))
        });
        if is_vertex && xyz.iter().any(Option::is_none) {
            return Err(MeshError::format(name, "vertex element lacks x, y or z"));
        }
        let face_prop = el.properties.iter().position(
            |p| matches!(p, Property::List(n, _, _) if n == "vertex_indices" || n == "vertex_index"),
        );
        if is_face && face_prop.is_none() {
            return Err(MeshError::format(name, "face element lacks vertex_indices"));
        }
        for row in 0..el.count {
            // values[p] = scalar value, or the list.
            let mut scalars = vec![0.0; el.properties.len()];
            let mut list: Vec<f64> = Vec::new();
            match format {
                PlyFormat::Ascii => {
                    let l = next_line(&mut reader, &mut buf)?;
                    let mut t = buf.split_whitespace();
                    let mut num = |what: &str| -> Result<f64> {
                        let tok = t
                            .next()
                            .ok_or_else(|| perr(l, format!("{} {row}: missing {what}", el.name)))?;
                        tok.parse::<f64>().map_err(|_| {
                            perr(
                                l,
                                format!("{} {row}: cannot parse {what} from {tok:?}", el.name),
                            )
                        })
                    };
                    for (pi, p) in el.properties.iter().enumerate() {
                        match p {
                            Property::Scalar(n, _) => scalars[pi] = num(n)?,
                            Property::List(n, _, _) => {
                                let c = num(&format!("{n} count"))?;
                                if c < 0.0 || c.fract() != 0.0 {
                                    return Err(perr(
                                        l,
                                        format!("{} {row}: bad list count {c}", el.name),
                                    ));
                                }
                                let vals: Result<Vec<f64>> =
                                    (0..c as usize).map(|_| num(n)).collect();
                                if Some(pi) == face_prop {
                                    list = vals?;
                                } else {
                                    vals?;
                                }
                            }
                        }
                    }
                    if let Some(tok) = t.next() {
                        return Err(perr(
                            l,
                            format!("{} {row}: unexpected extra value {tok:?}", el.name),
                        ));
                    }
                }
                PlyFormat::BinaryLittleEndian | PlyFormat::BinaryBigEndian => {
                    let little = format == PlyFormat::BinaryLittleEndian;
                    let mut read = |s: Scalar| -> Result<f64> {
                        let mut b = [0u8; 8];
                        reader.read_exact(&mut b[..s.size()]).map_err(|e| {
                            MeshError::format(
                                name,
                                format!("{} {row}: truncated binary data ({e})", el.name),
                            )
                        })?;
                        Ok(s.decode(&b, little))
                    };
                    for (pi, p) in el.properties.iter().enumerate() {
                        match p {
                            Property::Scalar(_, s) => scalars[pi] = read(*s)?,
                            Property::List(_, ct, it) => {
                                let c = read(*ct)?;
                                if c < 0.0 {
                                    return Err(MeshError::format(
                                        name,
                                        format!("{} {row}: negative list count", el.name),
                                    ));
                                }
                                let vals: Result<Vec<f64>> =
                                    (0..c as usize).map(|_| read(*it)).collect();
                                if Some(pi) == face_prop {
                                    list = vals?;
                                } else {
                                    vals?;
                                }
                            }
                        }
                    }
                }
            }
            let err_at = |m: String| match format {
                PlyFormat::Ascii => perr(line_no.get(), m),
                _ => MeshError::format(name, m),
            };
            if is_vertex {
                let [x, y, z] = xyz.map(|i| scalars[i.unwrap_or(0)]);
                let p = Vector3::new(x, y, z);
                crate::io::obj::finite(&p, &format!("vertex {row}")).map_err(err_at)?;
                mesh.vertices.push(p);
            } else if is_face {
                if list.len() < 3 {
                    return Err(err_at(format!(
                        "face {row} has {} vertices, need at least 3",
                        list.len()
                    )));
                }
                let mut poly = Vec::with_capacity(list.len());
                for v in list {
                    if v < 0.0 || v.fract() != 0.0 {
                        return Err(err_at(format!("face {row}: invalid vertex index {v}")));
                    }
                    poly.push(v as usize);
                }
                mesh.polygons.push(poly);
            }
        }
    }
    let nv = mesh.vertices.len();
    for (f, poly) in mesh.polygons.iter().enumerate() {
        if let Some(&v) = poly.iter().find(|&&v| v >= nv) {
            return Err(MeshError::format(
                name,
                format!("face {f} refers to vertex {v}, but there are only {nv} vertices"),
            ));
        }
    }
    Ok(mesh)
}

/// Writes a PLY file (atomically).
pub fn write_ply(path: impl AsRef<Path>, mesh: &PlyMesh, format: PlyFormat) -> Result<()> {
    write_atomic(path.as_ref(), |w| write_ply_to(w, mesh, format))
}

/// Writes a triangle mesh as PLY (atomically).
pub fn write_tri_mesh_ply(path: impl AsRef<Path>, mesh: &TriMesh, format: PlyFormat) -> Result<()> {
    write_ply(path, &PlyMesh::from_tri_mesh(mesh), format)
}

/// Writes PLY with `double` coordinates and `list uchar int vertex_indices` faces.
/// Fails with `InvalidInput` for polygons of more than 255 vertices or indices beyond `i32`.
pub fn write_ply_to(w: &mut impl Write, mesh: &PlyMesh, format: PlyFormat) -> std::io::Result<()> {
    let fmt = match format {
        PlyFormat::Ascii => "ascii",
        PlyFormat::BinaryLittleEndian => "binary_little_endian",
        PlyFormat::BinaryBigEndian => "binary_big_endian",
    };
    let bad = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, m);
    for (f, p) in mesh.polygons.iter().enumerate() {
        if p.len() > 255 {
            return Err(bad(format!(
                "face {f} has {} vertices; PLY uchar counts allow 255",
                p.len()
            )));
        }
    }
    if mesh.vertices.len() > i32::MAX as usize {
        return Err(bad("too many vertices for int indices".into()));
    }
    write!(
        w,
        "ply\nformat {fmt} 1.0\ncomment written by softcap_mesh\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.polygons.len()
    )?;
    match format {
        PlyFormat::Ascii => {
            for v in &mesh.vertices {
                writeln!(w, "{} {} {}", v.x, v.y, v.z)?;
            }
            for p in &mesh.polygons {
                write!(w, "{}", p.len())?;
                for i in p {
                    write!(w, " {i}")?;
                }
                writeln!(w)?;
            }
        }
        PlyFormat::BinaryLittleEndian | PlyFormat::BinaryBigEndian => {
            let le = format == PlyFormat::BinaryLittleEndian;
            for v in &mesh.vertices {
                for c in [v.x, v.y, v.z] {
                    w.write_all(&if le { c.to_le_bytes() } else { c.to_be_bytes() })?;
                }
            }
            for p in &mesh.polygons {
                w.write_all(&[p.len() as u8])?;
                for &i in p {
                    let i = i as i32;
                    w.write_all(&if le { i.to_le_bytes() } else { i.to_be_bytes() })?;
                }
            }
        }
    }
    Ok(())
}
