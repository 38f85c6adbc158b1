//! The TARGET folder of `softcap tissue reshape` (format in docs/reshape.md):
//!
//! ```text
//! TARGET/target.toml      length_unit, file names, free_flying
//! TARGET/landmarks.csv    id,template_x,template_y,template_z,x,y,z
//! TARGET/icp_markers.csv  id,x,y,z
//! TARGET/attachments.csv  node,x,y,z          (optional; required unless free_flying)
//! TARGET/icp_surface.csv  a,b,c               (optional; the boundary triangles ICP markers lie on)
//! TARGET/surface.obj      subject's dense surface (optional; evaluation only)
//! ```
//!
//! Every coordinate — of the TARGET files and of the template mesh — is in `length_unit`
//! (`template_length_unit` may differ for the template). Errors name the file and line.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::Deserialize;
use softcap_mesh::{TetLocator, TetMesh, TriMesh};

use super::problem::{Attachment, IcpMarker, Landmark, MaterialPoint, ReshapeProblem};
use crate::error::{Result, TissueError};

/// `target.toml`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSpec {
    /// "m", "cm" or "mm": the unit of every coordinate in TARGET.
    pub length_unit: String,
    /// Unit of the template mesh's coordinates (default: `length_unit`).
    #[serde(default)]
    pub template_length_unit: Option<String>,
    /// Landmarks file (default `landmarks.csv`; may be absent when there are none).
    #[serde(default = "default_landmarks")]
    pub landmarks: String,
    /// ICP markers file (default `icp_markers.csv`).
    #[serde(default = "default_icp")]
    pub icp_markers: String,
    /// Attachments file (optional).
    #[serde(default)]
    pub attachments: Option<String>,
    /// The subject's dense surface (optional; evaluation only).
    #[serde(default)]
    pub surface: Option<String>,
    /// The part of the template's boundary the ICP markers lie on (optional; default the whole
    /// boundary): a CSV `a,b,c` of template node triples, each a boundary triangle
    /// ([`ReshapeProblem::icp_surface`]).
    #[serde(default)]
    pub icp_surface: Option<String>,
    /// No attachments: solve with the rigid gauge (saito-barbic §3.6).
    #[serde(default)]
    pub free_flying: bool,
}

fn default_landmarks() -> String {
    "landmarks.csv".into()
}

fn default_icp() -> String {
    "icp_markers.csv".into()
}

/// A loaded TARGET: the problem (SI) and the optional evaluation surface (SI).
#[derive(Clone, Debug)]
pub struct LoadedTarget {
    /// The reshape problem.
    pub problem: ReshapeProblem,
    /// `surface.obj` in metres, if given.
    pub surface: Option<TriMesh>,
    /// Metres per unit of the TARGET files.
    pub metres_per_unit: f64,
    /// The template's length unit, metres per unit.
    pub template_metres_per_unit: f64,
    /// Per node of the template file, its index in the solver's mesh.
    pub node_map: Vec<Option<usize>>,
    /// The TARGET data files read (landmarks, ICP markers, attachments, surface).
    pub files: Vec<PathBuf>,
}

/// Metres per unit of "m", "cm", "mm".
pub fn metres_per(unit: &str) -> Option<f64> {
    match unit {
        "m" => Some(1.0),
        "cm" => Some(1e-2),
        "mm" => Some(1e-3),
        _ => None,
    }
}

fn line_error(path: &Path, line: usize, problem: impl Into<String>) -> TissueError {
    TissueError::BadInputLine {
        path: path.to_path_buf(),
        line,
        problem: problem.into(),
    }
}

/// 1-based line of the first line of `text` for which `pred` holds (1 if none).
fn line_of(text: &str, pred: impl Fn(&str) -> bool) -> usize {
    text.lines()
        .position(|l| pred(l.trim_start()))
        .map_or(1, |i| i + 1)
}

/// Reads TARGET/ and the template mesh into a [`LoadedTarget`].
pub fn load_target(template: &Path, target_dir: &Path) -> Result<LoadedTarget> {
    let toml_path = target_dir.join("target.toml");
    let text = std::fs::read_to_string(&toml_path)
        .map_err(|e| TissueError::bad_input(&toml_path, "file", e.to_string()))?;
    if let Some(bad) = softcap_app::non_finite(&text) {
        return Err(line_error(&toml_path, bad.line, bad.to_string()));
    }
    let spec: TargetSpec = toml::from_str(&text).map_err(|e| {
        let line = e.span().map_or(1, |s| {
            text[..s.start.min(text.len())].lines().count().max(1)
        });
        line_error(&toml_path, line, e.message().to_string())
    })?;
    let unit_line = line_of(&text, |l| l.starts_with("length_unit"));
    let unit = metres_per(&spec.length_unit).ok_or_else(|| {
        line_error(
            &toml_path,
            unit_line,
            format!(
                "length_unit = {:?}: expected \"m\", \"cm\" or \"mm\"",
                spec.length_unit
            ),
        )
    })?;
    let template_unit = match &spec.template_length_unit {
        None => unit,
        Some(u) => metres_per(u).ok_or_else(|| {
            line_error(
                &toml_path,
                line_of(&text, |l| l.starts_with("template_length_unit")),
                format!("template_length_unit = {u:?}: expected \"m\", \"cm\" or \"mm\""),
            )
        })?,
    };
    // TARGET may only name files inside its folder (softcap_app::path_inside).
    for (key, name) in [
        ("landmarks", Some(&spec.landmarks)),
        ("icp_markers", Some(&spec.icp_markers)),
        ("attachments", spec.attachments.as_ref()),
        ("surface", spec.surface.as_ref()),
        ("icp_surface", spec.icp_surface.as_ref()),
    ] {
        if let Some(name) = name {
            softcap_app::path_inside(target_dir, name).map_err(|m| {
                let line = line_of(&text, |l| l.starts_with(key));
                line_error(&toml_path, line, format!("{key}: {m}"))
            })?;
        }
    }
    let (mesh, node_map) = crate::session::read_volume_mesh_mapped(template, template_unit)?;
    let landmarks_path = target_dir.join(&spec.landmarks);
    let landmarks = if landmarks_path.exists() {
        read_landmarks(&landmarks_path, unit, &mesh)?
    } else {
        Vec::new()
    };
    let icp_path = target_dir.join(&spec.icp_markers);
    let icp_markers = if icp_path.exists() {
        read_icp(&icp_path, unit)?
    } else {
        Vec::new()
    };
    let attachments = match &spec.attachments {
        Some(name) => read_attachments(&target_dir.join(name), unit, &node_map)?,
        None => Vec::new(),
    };
    check_attachments(&toml_path, &text, &spec, &attachments, &mesh)?;
    if landmarks.is_empty() && icp_markers.is_empty() {
        return Err(TissueError::bad_input(
            target_dir,
            "landmarks / icp_markers",
            format!(
                "no landmarks ({}) and no ICP markers ({}): nothing to reshape to",
                landmarks_path.display(),
                icp_path.display()
            ),
        ));
    }
    if spec.free_flying && landmarks.len() < 3 {
        return Err(line_error(
            &toml_path,
            line_of(&text, |l| l.starts_with("free_flying")),
            "free_flying = true needs at least three landmarks (the initial rigid alignment)",
        ));
    }
    check_units(
        &toml_path,
        unit_line,
        &spec,
        &mesh,
        &landmarks,
        &icp_markers,
    )?;
    let surface = match &spec.surface {
        Some(name) => Some(read_surface(&target_dir.join(name), unit)?),
        None => None,
    };
    let icp_surface = match &spec.icp_surface {
        Some(name) => Some(read_icp_surface(&target_dir.join(name), &node_map, &mesh)?),
        None => None,
    };
    let files = [
        Some(&spec.landmarks),
        Some(&spec.icp_markers),
        spec.attachments.as_ref(),
        spec.surface.as_ref(),
        spec.icp_surface.as_ref(),
    ]
    .into_iter()
    .flatten()
    .map(|name| target_dir.join(name))
    .filter(|p| p.exists())
    .collect();
    Ok(LoadedTarget {
        problem: ReshapeProblem {
            template: mesh,
            landmarks,
            icp_markers,
            attachments,
            free_flying: spec.free_flying,
            icp_surface,
        },
        surface,
        metres_per_unit: unit,
        template_metres_per_unit: template_unit,
        node_map,
        files,
    })
}

/// A CSV reader over `path` that checks the header against `columns`.
fn csv_records(path: &Path, columns: &[&str]) -> Result<Vec<(usize, Vec<String>)>> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_path(path)
        .map_err(|e| TissueError::bad_input(path, "file", e.to_string()))?;
    let header: Vec<String> = reader
        .headers()
        .map_err(|e| line_error(path, 1, e.to_string()))?
        .iter()
        .map(str::to_string)
        .collect();
    if header != columns {
        return Err(line_error(
            path,
            1,
            format!(
                "header {:?}, expected {}",
                header.join(","),
                columns.join(",")
            ),
        ));
    }
    let mut out = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| {
            let line = e.position().map_or(0, |p| p.line() as usize);
            line_error(path, line, e.to_string())
        })?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        if record.len() != columns.len() {
            return Err(line_error(
                path,
                line,
                format!("{} fields, expected {}", record.len(), columns.len()),
            ));
        }
        out.push((line, record.iter().map(str::to_string).collect()));
    }
    Ok(out)
}

/// Parses finite coordinates `fields[from..from + 3]`, named `names`.
fn point(
    path: &Path,
    line: usize,
    fields: &[String],
    from: usize,
    names: &[&str],
) -> Result<Vector3<f64>> {
    let mut v = Vector3::zeros();
    for k in 0..3 {
        let s = &fields[from + k];
        v[k] = s
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| {
                line_error(
                    path,
                    line,
                    format!("{} = {s:?} is not a finite number", names[k]),
                )
            })?;
    }
    Ok(v)
}

fn unique_id(path: &Path, line: usize, id: &str, seen: &mut BTreeSet<String>) -> Result<()> {
    if id.is_empty() {
        return Err(line_error(path, line, "empty id"));
    }
    if !seen.insert(id.to_string()) {
        return Err(line_error(path, line, format!("duplicate id {id:?}")));
    }
    Ok(())
}

/// `landmarks.csv`: template points embedded in the template (a point farther than 1 % of the
/// template's size outside it is an error), targets in metres.
fn read_landmarks(path: &Path, unit: f64, mesh: &TetMesh) -> Result<Vec<Landmark>> {
    let columns = [
        "id",
        "template_x",
        "template_y",
        "template_z",
        "x",
        "y",
        "z",
    ];
    let records = csv_records(path, &columns)?;
    let locator = TetLocator::new(mesh);
    let tolerance = 0.01 * bounding_diagonal(&mesh.vertices);
    let mut seen = BTreeSet::new();
    let mut out = Vec::with_capacity(records.len());
    for (line, f) in records {
        unique_id(path, line, &f[0], &mut seen)?;
        let at = point(path, line, &f, 1, &columns[1..4])? * unit;
        let target = point(path, line, &f, 4, &columns[4..7])? * unit;
        let embedding = locator
            .locate(&at)
            .ok_or_else(|| line_error(path, line, "the template has no valid tet"))?;
        if embedding.distance > tolerance {
            return Err(line_error(
                path,
                line,
                format!(
                    "landmark {:?}: template point ({}, {}, {}) lies {:.4} {} outside the template \
                     (tolerance {:.4})",
                    f[0],
                    f[1],
                    f[2],
                    f[3],
                    embedding.distance / unit,
                    unit_name(unit),
                    tolerance / unit
                ),
            ));
        }
        out.push(Landmark {
            id: f[0].clone(),
            point: MaterialPoint {
                nodes: mesh.tets[embedding.tet],
                weights: embedding.weights,
            },
            target_m: target,
        });
    }
    Ok(out)
}

fn unit_name(unit: f64) -> &'static str {
    if unit == 1.0 {
        "m"
    } else if unit == 1e-2 {
        "cm"
    } else {
        "mm"
    }
}

/// `icp_markers.csv`.
fn read_icp(path: &Path, unit: f64) -> Result<Vec<IcpMarker>> {
    let columns = ["id", "x", "y", "z"];
    let mut seen = BTreeSet::new();
    csv_records(path, &columns)?
        .into_iter()
        .map(|(line, f)| {
            unique_id(path, line, &f[0], &mut seen)?;
            Ok(IcpMarker {
                id: f[0].clone(),
                position_m: point(path, line, &f, 1, &columns[1..4])? * unit,
            })
        })
        .collect()
}

/// `attachments.csv`: `node` is the 0-based index of a node in the template file's `$Nodes`.
fn read_attachments(path: &Path, unit: f64, node_map: &[Option<usize>]) -> Result<Vec<Attachment>> {
    let columns = ["node", "x", "y", "z"];
    let mut seen = BTreeSet::new();
    csv_records(path, &columns)?
        .into_iter()
        .map(|(line, f)| {
            unique_id(path, line, &f[0], &mut seen)?;
            let node = template_node(path, line, &f[0], node_map)?;
            Ok(Attachment {
                id: f[0].clone(),
                node,
                target_m: point(path, line, &f, 1, &columns[1..4])? * unit,
            })
        })
        .collect()
}

/// The solver's node for `field`, a 0-based node index of the template file (`$Nodes` order).
fn template_node(
    path: &Path,
    line: usize,
    field: &str,
    node_map: &[Option<usize>],
) -> Result<usize> {
    let file_node: usize = field
        .parse()
        .map_err(|_| line_error(path, line, format!("node = {field:?} is not a node index")))?;
    node_map.get(file_node).copied().flatten().ok_or_else(|| {
        line_error(
            path,
            line,
            format!(
                "node {file_node} is not a node of a tet of the template ({} nodes)",
                node_map.len()
            ),
        )
    })
}

/// `icp_surface.csv`: rows `a,b,c` of 0-based template node indices (`$Nodes` order), each a
/// boundary triangle of the template (taken with the template's orientation).
fn read_icp_surface(
    path: &Path,
    node_map: &[Option<usize>],
    mesh: &TetMesh,
) -> Result<Vec<[usize; 3]>> {
    let boundary: std::collections::BTreeMap<[usize; 3], [usize; 3]> = mesh
        .boundary_faces()
        .into_iter()
        .map(|f| {
            let mut key = f;
            key.sort_unstable();
            (key, f)
        })
        .collect();
    let records = csv_records(path, &["a", "b", "c"])?;
    if records.is_empty() {
        return Err(line_error(path, 1, "no triangles"));
    }
    let mut seen = BTreeSet::new();
    records
        .into_iter()
        .map(|(line, f)| {
            let mut key = [0; 3];
            for (k, field) in f.iter().enumerate() {
                key[k] = template_node(path, line, field, node_map)?;
            }
            key.sort_unstable();
            let face = boundary.get(&key).copied().ok_or_else(|| {
                line_error(
                    path,
                    line,
                    format!(
                        "({}, {}, {}) is not a boundary triangle of the template",
                        f[0], f[1], f[2]
                    ),
                )
            })?;
            if !seen.insert(key) {
                return Err(line_error(path, line, "duplicate triangle"));
            }
            Ok(face)
        })
        .collect()
}

/// An attached object needs ≥ 3 non-collinear attached nodes (else its equilibrium has rigid
/// motions); a free-flying one none.
fn check_attachments(
    toml_path: &Path,
    text: &str,
    spec: &TargetSpec,
    attachments: &[Attachment],
    mesh: &TetMesh,
) -> Result<()> {
    let line = line_of(text, |l| l.starts_with("free_flying"));
    if spec.free_flying {
        if !attachments.is_empty() {
            return Err(line_error(
                toml_path,
                line,
                "free_flying = true but attachments are given",
            ));
        }
        return Ok(());
    }
    let p: Vec<Vector3<f64>> = attachments.iter().map(|a| mesh.vertices[a.node]).collect();
    // Collinear iff every point is on the line through the first point and the one farthest
    // from it.
    let (mut spread, mut area) = (0.0f64, 0.0f64);
    if let Some(a) = p.first() {
        let b = p
            .iter()
            .copied()
            .max_by(|u, v| (u - a).norm().total_cmp(&(v - a).norm()))
            .unwrap_or(*a);
        spread = (b - a).norm();
        area = p
            .iter()
            .map(|c| (b - a).cross(&(c - a)).norm())
            .fold(0.0, f64::max);
    }
    if p.len() < 3 || area <= 1e-6 * spread * spread {
        return Err(line_error(
            toml_path,
            line,
            format!(
                "an attached object needs at least three non-collinear attachments (got {}); set \
                 free_flying = true for an object without attachments",
                p.len()
            ),
        ));
    }
    Ok(())
}

/// Inconsistent units: the target points' extent must be within 10× of the template's.
fn check_units(
    toml_path: &Path,
    line: usize,
    spec: &TargetSpec,
    mesh: &TetMesh,
    landmarks: &[Landmark],
    icp: &[IcpMarker],
) -> Result<()> {
    let targets: Vec<Vector3<f64>> = landmarks
        .iter()
        .map(|l| l.target_m)
        .chain(icp.iter().map(|m| m.position_m))
        .collect();
    if targets.len() < 2 {
        return Ok(());
    }
    let template = bounding_diagonal(&mesh.vertices);
    let target = bounding_diagonal(&targets);
    let ratio = target / template;
    if !(0.1..=10.0).contains(&ratio) {
        return Err(line_error(
            toml_path,
            line,
            format!(
                "length_unit = {:?}: the target points span {:.4} m but the template spans {:.4} m \
                 ({ratio:.3}×) — inconsistent units between the template and TARGET?",
                spec.length_unit, target, template
            ),
        ));
    }
    Ok(())
}

/// `surface.obj` (evaluation only): triangulated, metres; rejected when an edge is shared by
/// more than two faces or twice in the same direction (non-manifold / inconsistently oriented).
fn read_surface(path: &Path, unit: f64) -> Result<TriMesh> {
    let obj = softcap_mesh::read_obj(path).map_err(|e| TissueError::ReadMesh {
        path: path.to_path_buf(),
        source: Box::new(e),
    })?;
    let (mut mesh, origin) = obj.triangulate();
    let mut edges: std::collections::BTreeMap<(usize, usize), usize> = Default::default();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            let directed = edges.entry((a, b)).or_insert(0);
            *directed += 1;
            let twice = *directed > 1;
            let shared =
                edges.get(&(a, b)).copied().unwrap_or(0) + edges.get(&(b, a)).copied().unwrap_or(0);
            if twice || shared > 2 {
                let face = origin[t];
                let text = std::fs::read_to_string(path).unwrap_or_default();
                let line = text
                    .lines()
                    .enumerate()
                    .filter(|(_, l)| l.trim_start().starts_with("f "))
                    .nth(face)
                    .map_or(0, |(i, _)| i + 1);
                return Err(line_error(
                    path,
                    line,
                    format!(
                        "face {} makes edge ({}, {}) non-manifold (shared by more than two faces or \
                         twice in the same direction)",
                        face + 1,
                        a + 1,
                        b + 1
                    ),
                ));
            }
        }
    }
    mesh.scale(unit);
    Ok(mesh)
}

fn bounding_diagonal(points: &[Vector3<f64>]) -> f64 {
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    (hi - lo).norm()
}

/// Writes `problem` as a TARGET folder `dir/target` (coordinates in `unit`: "m", "cm" or "mm")
/// and its template as `dir/template.msh` in the same unit: the format [`load_target`] reads.
pub fn write_target(dir: &Path, problem: &ReshapeProblem, unit: &str) -> Result<()> {
    let per = metres_per(unit).ok_or_else(|| {
        TissueError::bad_input(dir, "unit", format!("{unit:?}: expected m, cm or mm"))
    })?;
    let xyz = |v: &Vector3<f64>| format!("{},{},{}", v.x / per, v.y / per, v.z / per);
    let target = dir.join("target");
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |e: std::io::Error| TissueError::Output {
            path,
            reason: e.to_string(),
        }
    };
    std::fs::create_dir_all(&target).map_err(io(&target))?;
    let mut template = problem.template.clone();
    template.scale(1.0 / per);
    let msh = dir.join("template.msh");
    softcap_mesh::write_msh(&msh, &softcap_mesh::MshMesh::from_tet_mesh(&template, None)).map_err(
        |e| TissueError::Output {
            path: msh.clone(),
            reason: e.to_string(),
        },
    )?;
    let mut toml = format!("length_unit = \"{unit}\"\n");
    if problem.free_flying {
        toml += "free_flying = true\n";
    } else {
        toml += "attachments = \"attachments.csv\"\n";
    }
    let mut landmarks = String::from("id,template_x,template_y,template_z,x,y,z\n");
    for l in &problem.landmarks {
        let x = l.point.at(&problem.template.vertices);
        landmarks += &format!("{},{},{}\n", l.id, xyz(&x), xyz(&l.target_m));
    }
    let mut icp = String::from("id,x,y,z\n");
    for m in &problem.icp_markers {
        icp += &format!("{},{}\n", m.id, xyz(&m.position_m));
    }
    let mut files = vec![
        ("target.toml", toml),
        ("landmarks.csv", landmarks),
        ("icp_markers.csv", icp),
    ];
    if !problem.free_flying {
        let mut attachments = String::from("node,x,y,z\n");
        for a in &problem.attachments {
            attachments += &format!("{},{}\n", a.node, xyz(&a.target_m));
        }
        files.push(("attachments.csv", attachments));
    }
    if let Some(faces) = &problem.icp_surface {
        files[0].1 += "icp_surface = \"icp_surface.csv\"\n";
        let mut csv = String::from("a,b,c\n");
        for f in faces {
            csv += &format!("{},{},{}\n", f[0], f[1], f[2]);
        }
        files.push(("icp_surface.csv", csv));
    }
    for (name, text) in files {
        let path = target.join(name);
        std::fs::write(&path, text).map_err(io(&path))?;
    }
    Ok(())
}
