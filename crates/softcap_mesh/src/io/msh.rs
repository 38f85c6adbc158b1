//! Gmsh MSH 4.1 (read with the `mshio` crate; ASCII and binary), and ASCII 4.1 writing.
//!
//! Linear tets (`Tet4`) and triangles (`Tri3`) are kept, with the tag of the geometric entity
//! each belongs to; points, lines and other element types are skipped. Coordinates are returned
//! as stored (the file's units).

use crate::error::{MeshError, Result};
use crate::io::write_atomic;
use crate::types::{TetMesh, TriMesh};
use mshio::{ElementType, MshFile};
use nalgebra::Vector3;
use std::collections::{BTreeSet, HashMap};
use std::io::{Read, Write};
use std::path::Path;

/// The linear elements of a Gmsh mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MshMesh {
    /// Node positions in the file's units, in the file's node order.
    pub vertices: Vec<Vector3<f64>>,
    /// Gmsh node tag of each vertex.
    pub node_tags: Vec<u64>,
    /// Linear tetrahedra (0-based vertex indices), in file order.
    pub tets: Vec<[usize; 4]>,
    /// Geometric entity tag of each tet.
    pub tet_entities: Vec<i32>,
    /// Linear triangles (0-based vertex indices), in file order.
    pub triangles: Vec<[usize; 3]>,
    /// Geometric entity tag of each triangle.
    pub triangle_entities: Vec<i32>,
}

impl MshMesh {
    /// The tetrahedral mesh (all vertices, all tets).
    pub fn tet_mesh(&self) -> TetMesh {
        TetMesh {
            vertices: self.vertices.clone(),
            tets: self.tets.clone(),
        }
    }

    /// The triangles of the file as a surface mesh (all vertices).
    pub fn tri_mesh(&self) -> TriMesh {
        TriMesh {
            vertices: self.vertices.clone(),
            triangles: self.triangles.clone(),
        }
    }

    /// A file holding `mesh`'s tets in entity 1 (and optionally `boundary` triangles in entity 1).
    pub fn from_tet_mesh(mesh: &TetMesh, boundary: Option<&[[usize; 3]]>) -> Self {
        let triangles = boundary.map(<[_]>::to_vec).unwrap_or_default();
        MshMesh {
            vertices: mesh.vertices.clone(),
            node_tags: (1..=mesh.vertices.len() as u64).collect(),
            tet_entities: vec![1; mesh.tets.len()],
            tets: mesh.tets.clone(),
            triangle_entities: vec![1; triangles.len()],
            triangles,
        }
    }
}

/// Reads a Gmsh 4.1 file (ASCII or binary).
pub fn read_msh(path: impl AsRef<Path>) -> Result<MshMesh> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| MeshError::io(path, e))?;
    parse_msh_bytes(&bytes, path)
}

/// Reads a Gmsh 4.1 file from `reader`; `name` identifies it in errors.
pub fn read_msh_from(mut reader: impl Read, name: impl AsRef<Path>) -> Result<MshMesh> {
    let name = name.as_ref();
    let mut bytes = Vec::new();
    reader
        .read_to_end(&mut bytes)
        .map_err(|e| MeshError::io(name, e))?;
    parse_msh_bytes(&bytes, name)
}

/// Parses MSH 4.1 bytes. Parse errors report the line where `mshio` stopped (for ASCII files)
/// and its chain of error contexts.
pub fn parse_msh_bytes(bytes: &[u8], name: impl AsRef<Path>) -> Result<MshMesh> {
    let name = name.as_ref();
    // mshio still has a few `expect`s on malformed input; a panic there is a bad file, not a bug here.
    let parsed = std::panic::catch_unwind(|| {
        mshio::parse_msh_bytes(bytes).map_err(|e| {
            let offset = e
                .backtrace
                .first()
                .map(|(rest, _)| (rest.as_ptr() as usize).saturating_sub(bytes.as_ptr() as usize))
                .unwrap_or(0)
                .min(bytes.len());
            let line = 1 + bytes[..offset].iter().filter(|&&b| b == b'\n').count();
            let mut msgs: Vec<String> = e.filter_msh_errors().map(|(_, k)| k.to_string()).collect();
            msgs.reverse();
            if msgs.is_empty() {
                msgs.push("malformed MSH content".into());
            }
            (line, msgs.join(": "))
        })
    });
    let file = match parsed {
        Ok(Ok(f)) => f,
        Ok(Err((line, msg))) => {
            let binary = bytes.windows(6).take(64).any(|w| w == b"4.1 1 ");
            return Err(if binary {
                MeshError::format(name, msg)
            } else {
                MeshError::parse(name, line, msg)
            });
        }
        Err(_) => return Err(MeshError::format(name, "the MSH parser rejected the file")),
    };
    convert(file, name)
}

fn convert(file: MshFile<u64, i32, f64>, name: &Path) -> Result<MshMesh> {
    let mut out = MshMesh::default();
    let nodes = file
        .data
        .nodes
        .ok_or_else(|| MeshError::format(name, "no $Nodes section"))?;
    let mut tag_to_index: HashMap<u64, usize> = HashMap::new();
    // Dense tags: mshio drops them; nodes are numbered consecutively from min_node_tag.
    let mut next_tag = nodes.min_node_tag;
    for block in &nodes.node_blocks {
        let mut block_tags = vec![0u64; block.nodes.len()];
        match &block.node_tags {
            Some(map) => {
                for (&tag, &i) in map {
                    if let Some(slot) = block_tags.get_mut(i) {
                        *slot = tag;
                    }
                }
            }
            None => {
                for t in block_tags.iter_mut() {
                    *t = next_tag;
                    next_tag += 1;
                }
            }
        }
        for (node, tag) in block.nodes.iter().zip(block_tags) {
            let p = Vector3::new(node.x, node.y, node.z);
            crate::io::obj::finite(&p, &format!("node {tag}"))
                .map_err(|m| MeshError::format(name, m))?;
            if tag_to_index.insert(tag, out.vertices.len()).is_some() {
                return Err(MeshError::format(
                    name,
                    format!("node tag {tag} defined twice"),
                ));
            }
            out.vertices.push(p);
            out.node_tags.push(tag);
        }
    }
    let Some(elements) = file.data.elements else {
        return Ok(out);
    };
    for block in &elements.element_blocks {
        let n = match block.element_type {
            ElementType::Tet4 => 4,
            ElementType::Tri3 => 3,
            _ => continue,
        };
        for el in &block.elements {
            if el.nodes.len() < n {
                return Err(MeshError::format(
                    name,
                    format!(
                        "element {} has {} nodes, expected {n}",
                        el.element_tag,
                        el.nodes.len()
                    ),
                ));
            }
            let mut idx = [0usize; 4];
            for c in 0..n {
                let tag = el.nodes[c];
                idx[c] = *tag_to_index.get(&tag).ok_or_else(|| {
                    MeshError::format(
                        name,
                        format!("element {} refers to undefined node {tag}", el.element_tag),
                    )
                })?;
            }
            if n == 4 {
                out.tets.push(idx);
                out.tet_entities.push(block.entity_tag);
            } else {
                out.triangles.push([idx[0], idx[1], idx[2]]);
                out.triangle_entities.push(block.entity_tag);
            }
        }
    }
    Ok(out)
}

/// Reads the tets of a Gmsh file as a [`TetMesh`] (file units, file orientation).
pub fn read_msh_tet_mesh(path: impl AsRef<Path>) -> Result<TetMesh> {
    Ok(read_msh(path)?.tet_mesh())
}

/// Writes an ASCII MSH 4.1 file (atomically).
pub fn write_msh(path: impl AsRef<Path>, mesh: &MshMesh) -> Result<()> {
    write_atomic(path.as_ref(), |w| write_msh_to(w, mesh))
}

/// Writes ASCII MSH 4.1: one volume entity per distinct tet entity tag, one surface entity per
/// distinct triangle entity tag; all nodes in the first entity. Node tags are 1..=N in vertex
/// order; floats use shortest round-trip formatting.
pub fn write_msh_to(w: &mut impl Write, mesh: &MshMesh) -> std::io::Result<()> {
    let vol_tags: BTreeSet<i32> = mesh.tet_entities.iter().copied().collect();
    let surf_tags: BTreeSet<i32> = mesh.triangle_entities.iter().copied().collect();
    let (mut lo, mut hi) = (Vector3::repeat(0.0), Vector3::repeat(0.0));
    if let Some(first) = mesh.vertices.first() {
        lo = *first;
        hi = *first;
        for v in &mesh.vertices {
            lo = lo.inf(v);
            hi = hi.sup(v);
        }
    }
    let bbox = format!("{} {} {} {} {} {}", lo.x, lo.y, lo.z, hi.x, hi.y, hi.z);
    writeln!(w, "$MeshFormat\n4.1 0 8\n$EndMeshFormat")?;
    writeln!(w, "$Entities\n0 0 {} {}", surf_tags.len(), vol_tags.len())?;
    for t in &surf_tags {
        writeln!(w, "{t} {bbox} 0 0")?;
    }
    for t in &vol_tags {
        writeln!(w, "{t} {bbox} 0 0")?;
    }
    writeln!(w, "$EndEntities")?;
    let n = mesh.vertices.len();
    let (node_dim, node_entity) = match (vol_tags.first(), surf_tags.first()) {
        (Some(&t), _) => (3, t),
        (None, Some(&t)) => (2, t),
        (None, None) => (3, 1),
    };
    writeln!(w, "$Nodes")?;
    if n == 0 {
        writeln!(w, "0 0 0 0")?;
    } else {
        writeln!(w, "1 {n} 1 {n}\n{node_dim} {node_entity} 0 {n}")?;
        for i in 1..=n {
            writeln!(w, "{i}")?;
        }
        for v in &mesh.vertices {
            writeln!(w, "{} {} {}", v.x, v.y, v.z)?;
        }
    }
    writeln!(w, "$EndNodes")?;
    let total = mesh.tets.len() + mesh.triangles.len();
    let blocks = vol_tags.len() + surf_tags.len();
    writeln!(w, "$Elements")?;
    writeln!(w, "{blocks} {total} {} {total}", total.min(1))?;
    let mut tag = 1usize;
    for &ent in &surf_tags {
        let members: Vec<&[usize; 3]> = mesh
            .triangles
            .iter()
            .zip(&mesh.triangle_entities)
            .filter(|(_, e)| **e == ent)
            .map(|(t, _)| t)
            .collect();
        writeln!(w, "2 {ent} 2 {}", members.len())?;
        for t in members {
            writeln!(w, "{tag} {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
            tag += 1;
        }
    }
    for &ent in &vol_tags {
        let members: Vec<&[usize; 4]> = mesh
            .tets
            .iter()
            .zip(&mesh.tet_entities)
            .filter(|(_, e)| **e == ent)
            .map(|(t, _)| t)
            .collect();
        writeln!(w, "3 {ent} 4 {}", members.len())?;
        for t in members {
            writeln!(
                w,
                "{tag} {} {} {} {}",
                t[0] + 1,
                t[1] + 1,
                t[2] + 1,
                t[3] + 1
            )?;
            tag += 1;
        }
    }
    writeln!(w, "$EndElements")?;
    Ok(())
}
