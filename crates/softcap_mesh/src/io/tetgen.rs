//! TetGen `.node` / `.ele` files.
//!
//! `.node`: header `<#points> 3 <#attributes> <#boundary markers (0|1)>`, then
//! `<index> x y z [attributes…] [marker]`. `.ele`: header `<#tets> <4|10> <#attributes>`, then
//! `<index> n0 n1 n2 n3 [n4…n9] [attributes…]`. `#` starts a comment. Point numbering may start
//! at 0 or 1; tets refer to points by their number. Only the 4 corner nodes of 10-node tets
//! are kept; attributes and markers are skipped.

use crate::error::{MeshError, Result};
use crate::io::{field, open, write_atomic};
use crate::types::TetMesh;
use nalgebra::Vector3;
use std::collections::HashMap;
use std::io::{BufRead, Write};
use std::path::Path;

/// Content lines of a TetGen file: (1-based line number, text without comment).
fn content_lines(mut reader: impl BufRead, name: &Path) -> Result<Vec<(usize, String)>> {
    let mut out = Vec::new();
    let mut buf = String::new();
    let mut line_no = 0;
    loop {
        buf.clear();
        if reader
            .read_line(&mut buf)
            .map_err(|e| MeshError::io(name, e))?
            == 0
        {
            break;
        }
        line_no += 1;
        let text = buf.split('#').next().unwrap_or("").trim();
        if !text.is_empty() {
            out.push((line_no, text.to_string()));
        }
    }
    Ok(out)
}

/// Reads `NAME.node` and `NAME.ele`.
pub fn read_tetgen(node_path: impl AsRef<Path>, ele_path: impl AsRef<Path>) -> Result<TetMesh> {
    let (np, ep) = (node_path.as_ref(), ele_path.as_ref());
    read_tetgen_from(open(np)?, np, open(ep)?, ep)
}

/// Reads TetGen `.node` and `.ele` text from readers; the names identify them in errors.
pub fn read_tetgen_from(
    node_reader: impl BufRead,
    node_name: impl AsRef<Path>,
    ele_reader: impl BufRead,
    ele_name: impl AsRef<Path>,
) -> Result<TetMesh> {
    let (node_name, ele_name) = (node_name.as_ref(), ele_name.as_ref());
    let lines = content_lines(node_reader, node_name)?;
    let Some((hline, header)) = lines.first() else {
        return Err(MeshError::format(node_name, "empty .node file"));
    };
    let perr = |line: usize, m: String| MeshError::parse(node_name, line, m);
    let mut t = header.split_whitespace();
    let n: usize = field(&mut t, "number of points").map_err(|m| perr(*hline, m))?;
    let dim: usize = field(&mut t, "dimension").map_err(|m| perr(*hline, m))?;
    if dim != 3 {
        return Err(perr(
            *hline,
            format!("dimension {dim}, only 3 is supported"),
        ));
    }
    let nattr: usize = t
        .next()
        .map(|s| {
            s.parse()
                .map_err(|_| format!("cannot parse number of attributes from {s:?}"))
        })
        .transpose()
        .map_err(|m| perr(*hline, m))?
        .unwrap_or(0);
    let nmark: usize = t
        .next()
        .map(|s| {
            s.parse()
                .map_err(|_| format!("cannot parse number of markers from {s:?}"))
        })
        .transpose()
        .map_err(|m| perr(*hline, m))?
        .unwrap_or(0);
    if lines.len() - 1 < n {
        return Err(MeshError::format(
            node_name,
            format!(
                "header announces {n} points but the file has {}",
                lines.len() - 1
            ),
        ));
    }
    let mut vertices = Vec::with_capacity(n);
    let mut number_to_index = HashMap::with_capacity(n);
    for (line, text) in &lines[1..=n] {
        let parse = || -> std::result::Result<(i64, Vector3<f64>), String> {
            let mut t = text.split_whitespace();
            let id: i64 = field(&mut t, "point number")?;
            let x = field(&mut t, "x")?;
            let y = field(&mut t, "y")?;
            let z = field(&mut t, "z")?;
            let rest = t.count();
            if rest != nattr + nmark {
                return Err(format!(
                    "expected {} attribute/marker values after the coordinates, found {rest}",
                    nattr + nmark
                ));
            }
            let p = Vector3::new(x, y, z);
            crate::io::obj::finite(&p, "point")?;
            Ok((id, p))
        };
        let (id, p) = parse().map_err(|m| perr(*line, m))?;
        if number_to_index.insert(id, vertices.len()).is_some() {
            return Err(perr(*line, format!("point number {id} appears twice")));
        }
        vertices.push(p);
    }

    let lines = content_lines(ele_reader, ele_name)?;
    let perr = |line: usize, m: String| MeshError::parse(ele_name, line, m);
    let Some((hline, header)) = lines.first() else {
        return Err(MeshError::format(ele_name, "empty .ele file"));
    };
    let mut t = header.split_whitespace();
    let m: usize = field(&mut t, "number of tets").map_err(|e| perr(*hline, e))?;
    let per: usize = field(&mut t, "nodes per tet").map_err(|e| perr(*hline, e))?;
    if per != 4 && per != 10 {
        return Err(perr(
            *hline,
            format!("{per} nodes per tet, expected 4 or 10"),
        ));
    }
    if lines.len() - 1 < m {
        return Err(MeshError::format(
            ele_name,
            format!(
                "header announces {m} tets but the file has {}",
                lines.len() - 1
            ),
        ));
    }
    let mut tets = Vec::with_capacity(m);
    for (line, text) in &lines[1..=m] {
        let mut t = text.split_whitespace();
        let _id: i64 = field(&mut t, "tet number").map_err(|e| perr(*line, e))?;
        let mut tet = [0usize; 4];
        for c in 0..per {
            let num: i64 = field(&mut t, &format!("node {c}")).map_err(|e| perr(*line, e))?;
            if c < 4 {
                tet[c] = *number_to_index.get(&num).ok_or_else(|| {
                    perr(
                        *line,
                        format!("node {c} refers to point {num}, which is not in the .node file"),
                    )
                })?;
            }
        }
        tets.push(tet);
    }
    Ok(TetMesh { vertices, tets })
}

/// Writes `mesh` as TetGen `.node` and `.ele` files (atomically), numbering points from 1.
pub fn write_tetgen(
    node_path: impl AsRef<Path>,
    ele_path: impl AsRef<Path>,
    mesh: &TetMesh,
) -> Result<()> {
    write_atomic(node_path.as_ref(), |w| write_tetgen_node_to(w, mesh))?;
    write_atomic(ele_path.as_ref(), |w| write_tetgen_ele_to(w, mesh))
}

/// Writes the `.node` part (points numbered from 1, no attributes or markers).
pub fn write_tetgen_node_to(w: &mut impl Write, mesh: &TetMesh) -> std::io::Result<()> {
    writeln!(w, "{} 3 0 0", mesh.vertices.len())?;
    for (i, v) in mesh.vertices.iter().enumerate() {
        writeln!(w, "{} {} {} {}", i + 1, v.x, v.y, v.z)?;
    }
    writeln!(w, "# written by softcap_mesh")
}

/// Writes the `.ele` part (tets numbered from 1, referring to points numbered from 1).
pub fn write_tetgen_ele_to(w: &mut impl Write, mesh: &TetMesh) -> std::io::Result<()> {
    writeln!(w, "{} 4 0", mesh.tets.len())?;
    for (i, t) in mesh.tets.iter().enumerate() {
        writeln!(
            w,
            "{} {} {} {} {}",
            i + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        )?;
    }
    writeln!(w, "# written by softcap_mesh")
}
