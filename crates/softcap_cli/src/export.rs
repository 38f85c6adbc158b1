//! `softcap inspect export`: channels to CSV, meshes to OBJ / PLY / MSH, a dynamic material's rest
//! shape (`--what rest`) to `node,x,y,z` CSV or MSH.

use std::fmt::Write as _;
use std::path::Path;

use softcap_app::{Context, Error, Result};
use softcap_mcap::proto::{
    DynamicMaterial, MarkerFrame, NodeFrame, PointCloudFrame, ProbeSample, Scalar,
    SimulatedMarkers, TetMesh, TriMesh,
};
use softcap_mcap::{Recording, SoftcapMessage, Topic, topics};

/// Exports `what` (`markers`, `probe`, `simulated`, `surface`, `volume`, `nodes`, `points`, or a
/// topic) to `output`.
pub fn export(r: &Recording, what: &str, output: &Path) -> Result<()> {
    let topic = match what {
        "markers" => topics::MARKERS.name().to_string(),
        "probe" => topics::PROBE.name().to_string(),
        "simulated" => topics::SIMULATED_MARKERS.name().to_string(),
        "surface" => topics::SURFACE_MESH.name().to_string(),
        "volume" => topics::VOLUME_MESH.name().to_string(),
        "nodes" => topics::TRACK_NODES.name().to_string(),
        "points" => topics::POINTS.name().to_string(),
        "rest" => topics::DYNAMIC_MATERIAL.name().to_string(),
        t => t.to_string(),
    };
    let channel = r.channel(&topic).ok_or_else(|| {
        Error::bad_input(format!(
            "{}: no channel `{topic}` (--what {what})",
            r.path().display()
        ))
    })?;
    let schema = channel.schema_name.as_str();
    let ext = output
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let text = if schema == MarkerFrame::schema_name() {
        let frames = r.read(&Topic::<MarkerFrame>::custom(&topic))?;
        let ids = session_marker_ids(r)?;
        markers_csv(&frames, ids.as_deref()).map_err(|id| {
            Error::bad_input(format!(
                "{}: `{topic}` has marker id {id}, but /capture/session lists only {} marker ids",
                r.path().display(),
                ids.as_ref().map_or(0, Vec::len)
            ))
        })?
    } else if schema == ProbeSample::schema_name() {
        probe_csv(&r.read(&Topic::<ProbeSample>::custom(&topic))?)
    } else if schema == SimulatedMarkers::schema_name() {
        simulated_csv(&r.read(&Topic::<SimulatedMarkers>::custom(&topic))?)
    } else if schema == NodeFrame::schema_name() {
        nodes_csv(&r.read(&Topic::<NodeFrame>::custom(&topic))?)
    } else if schema == PointCloudFrame::schema_name() {
        points_csv(&r.read(&Topic::<PointCloudFrame>::custom(&topic))?)
    } else if schema == Scalar::schema_name() {
        scalar_csv(&r.read(&Topic::<Scalar>::custom(&topic))?)
    } else if schema == TriMesh::schema_name() {
        let m = r.read_static(&Topic::<TriMesh>::custom(&topic))?;
        mesh_text(&m.positions_m, &m.triangles, &ext)?
    } else if schema == DynamicMaterial::schema_name() {
        let m = r.read_static(&Topic::<DynamicMaterial>::custom(&topic))?;
        if m.rest_positions_m.is_empty() {
            return Err(Error::bad_input(format!(
                "{}: `{topic}` has no rest shape (rest_positions_m is empty)",
                r.path().display()
            )));
        }
        if ext == "msh" {
            let mut volume = r.read_static(&topics::VOLUME_MESH)?;
            if volume.positions_m.len() != m.rest_positions_m.len() {
                return Err(Error::bad_input(format!(
                    "{}: the rest shape has {} coordinates but /mesh/volume {}",
                    r.path().display(),
                    m.rest_positions_m.len(),
                    volume.positions_m.len()
                )));
            }
            volume.positions_m = m.rest_positions_m;
            tet_msh_text(&volume)?
        } else {
            rest_csv(&m.rest_positions_m)
        }
    } else if schema == TetMesh::schema_name() {
        let m = r.read_static(&Topic::<TetMesh>::custom(&topic))?;
        if ext == "msh" {
            tet_msh_text(&m)?
        } else {
            mesh_text(&m.positions_m, &m.surface_triangles, &ext)?
        }
    } else {
        return Err(Error::bad_input(format!(
            "{}: channel `{topic}` has schema `{schema}`, which has no export",
            r.path().display()
        )));
    };
    softcap_app::write_atomic(output, text.as_bytes())
        .with_context(|| format!("writing {}", output.display()))
}

/// The session's marker ids (`/capture/session` `marker_ids`: template/markers.csv ids, then
/// the probe shaft markers), when the recording has that channel.
fn session_marker_ids(r: &Recording) -> Result<Option<Vec<String>>> {
    if r.channel(topics::SESSION.name()).is_none() {
        return Ok(None);
    }
    Ok(Some(r.read_static(&topics::SESSION)?.marker_ids))
}

/// `frame,id,x,y,z` (metres) — the columns of a session's `truth/markers.csv`; markers without
/// a position are left out. `Marker.id` indexes `session_ids` when given (so `id` is the
/// session's marker id, e.g. `m07`), else it is written as the number. An id beyond
/// `session_ids` is returned as the error.
pub fn markers_csv(
    frames: &[(u64, MarkerFrame)],
    session_ids: Option<&[String]>,
) -> std::result::Result<String, u32> {
    let mut s = String::from("frame,id,x,y,z\n");
    for (_, f) in frames {
        for m in &f.markers {
            let Some(p) = &m.position_m else { continue };
            match session_ids {
                Some(ids) => {
                    let id = ids.get(m.id as usize).ok_or(m.id)?;
                    let _ = writeln!(s, "{},{id},{},{},{}", f.frame, p.x, p.y, p.z);
                }
                None => {
                    let _ = writeln!(s, "{},{},{},{},{}", f.frame, m.id, p.x, p.y, p.z);
                }
            }
        }
    }
    Ok(s)
}

/// `frame,t_camera_s,fx,fy,fz,tip_x,tip_y,tip_z` (s, N, m).
pub fn probe_csv(samples: &[(u64, ProbeSample)]) -> String {
    let mut s = String::from("frame,t_camera_s,fx,fy,fz,tip_x,tip_y,tip_z\n");
    for (_, p) in samples {
        let f = p.force_n.unwrap_or_default();
        let t = p.tip_m.unwrap_or_default();
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{}",
            p.frame, p.t_camera_s, f.x, f.y, f.z, t.x, t.y, t.z
        );
    }
    s
}

/// `frame,id,x,y,z` (metres) of simulated markers.
pub fn simulated_csv(frames: &[(u64, SimulatedMarkers)]) -> String {
    let mut s = String::from("frame,id,x,y,z\n");
    for (_, f) in frames {
        for (id, p) in f.ids.iter().zip(&f.positions_m) {
            let _ = writeln!(s, "{},{},{},{},{}", f.frame, id, p.x, p.y, p.z);
        }
    }
    s
}

/// `frame,node,x,y,z` (metres) of tracked node positions.
pub fn nodes_csv(frames: &[(u64, NodeFrame)]) -> String {
    let mut s = String::from("frame,node,x,y,z\n");
    for (_, f) in frames {
        for (i, p) in f.positions_m.chunks_exact(3).enumerate() {
            let _ = writeln!(s, "{},{i},{},{},{}", f.frame, p[0], p[1], p[2]);
        }
    }
    s
}

/// `frame,x,y,z,nx,ny,nz` (metres, unit normals; the normal columns empty when the cloud has
/// none).
pub fn points_csv(frames: &[(u64, PointCloudFrame)]) -> String {
    let mut s = String::from("frame,x,y,z,nx,ny,nz\n");
    for (_, f) in frames {
        let with_normals = f.normals.len() == f.positions_m.len();
        for (i, p) in f.positions_m.chunks_exact(3).enumerate() {
            if with_normals {
                let n = &f.normals[3 * i..3 * i + 3];
                let _ = writeln!(
                    s,
                    "{},{},{},{},{},{},{}",
                    f.frame, p[0], p[1], p[2], n[0], n[1], n[2]
                );
            } else {
                let _ = writeln!(s, "{},{},{},{},,,", f.frame, p[0], p[1], p[2]);
            }
        }
    }
    s
}

/// `log_time_s,value`.
pub fn scalar_csv(samples: &[(u64, Scalar)]) -> String {
    let mut s = String::from("log_time_s,value\n");
    for (t, v) in samples {
        let _ = writeln!(s, "{},{}", *t as f64 * 1e-9, v.value);
    }
    s
}

/// A tet mesh as Gmsh 4.1 ASCII (metres; tets and, if present, its boundary triangles).
/// `node,x,y,z` (metres) of a rest shape.
pub fn rest_csv(flat: &[f64]) -> String {
    let mut s = String::from("node,x,y,z\n");
    for (i, p) in flat.chunks_exact(3).enumerate() {
        let _ = writeln!(s, "{i},{},{},{}", p[0], p[1], p[2]);
    }
    s
}

fn tet_msh_text(m: &TetMesh) -> Result<String> {
    let corners = |flat: &[u32]| flat.iter().map(|&v| v as usize).collect::<Vec<usize>>();
    let mesh = softcap_mesh::TetMesh {
        vertices: m
            .positions_m
            .chunks_exact(3)
            .map(|p| softcap_mesh::nalgebra::Vector3::new(p[0], p[1], p[2]))
            .collect(),
        tets: corners(&m.tets)
            .chunks_exact(4)
            .map(|t| [t[0], t[1], t[2], t[3]])
            .collect(),
    };
    let boundary: Vec<[usize; 3]> = corners(&m.surface_triangles)
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let msh = softcap_mesh::MshMesh::from_tet_mesh(&mesh, Some(&boundary));
    let mut bytes = Vec::new();
    softcap_mesh::io::msh::write_msh_to(&mut bytes, &msh)
        .map_err(|e| Error::failure(format!("formatting the .msh text: {e}")))?;
    String::from_utf8(bytes).map_err(|e| Error::failure(format!("the .msh text: {e}")))
}

fn mesh_text(positions_m: &[f64], triangles: &[u32], ext: &str) -> Result<String> {
    let nv = positions_m.len() / 3;
    let nt = triangles.len() / 3;
    let mut s = String::new();
    match ext {
        "obj" => {
            let _ = writeln!(s, "# softcap export: {nv} vertices (m), {nt} triangles");
            for p in positions_m.chunks_exact(3) {
                let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
            }
            for t in triangles.chunks_exact(3) {
                let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
            }
        }
        "ply" => {
            let _ = write!(
                s,
                "ply\nformat ascii 1.0\nelement vertex {nv}\nproperty double x\nproperty double y\nproperty double z\nelement face {nt}\nproperty list uchar uint vertex_indices\nend_header\n"
            );
            for p in positions_m.chunks_exact(3) {
                let _ = writeln!(s, "{} {} {}", p[0], p[1], p[2]);
            }
            for t in triangles.chunks_exact(3) {
                let _ = writeln!(s, "3 {} {} {}", t[0], t[1], t[2]);
            }
        }
        _ => {
            return Err(Error::bad_input(format!(
                "mesh export needs an .obj or .ply output (or .msh for a tet mesh), got `.{ext}`"
            )));
        }
    }
    Ok(s)
}
