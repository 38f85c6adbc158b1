//! `softcap inspect export`: channels to CSV, meshes to OBJ / PLY.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use softcap_mcap::proto::{MarkerFrame, ProbeSample, Scalar, SimulatedMarkers, TetMesh, TriMesh};
use softcap_mcap::{Recording, SoftcapMessage, Topic, topics};

use crate::BadInput;

/// Exports `what` (`markers`, `probe`, `simulated`, `surface`, `volume`, or a topic) to `output`.
pub fn export(r: &Recording, what: &str, output: &Path) -> anyhow::Result<()> {
    let topic = match what {
        "markers" => topics::MARKERS.name().to_string(),
        "probe" => topics::PROBE.name().to_string(),
        "simulated" => topics::SIMULATED_MARKERS.name().to_string(),
        "surface" => topics::SURFACE_MESH.name().to_string(),
        "volume" => topics::VOLUME_MESH.name().to_string(),
        t => t.to_string(),
    };
    let channel = r.channel(&topic).ok_or_else(|| {
        BadInput(format!(
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
        markers_csv(&r.read(&Topic::<MarkerFrame>::custom(&topic))?)
    } else if schema == ProbeSample::schema_name() {
        probe_csv(&r.read(&Topic::<ProbeSample>::custom(&topic))?)
    } else if schema == SimulatedMarkers::schema_name() {
        simulated_csv(&r.read(&Topic::<SimulatedMarkers>::custom(&topic))?)
    } else if schema == Scalar::schema_name() {
        scalar_csv(&r.read(&Topic::<Scalar>::custom(&topic))?)
    } else if schema == TriMesh::schema_name() {
        let m = r.read_static(&Topic::<TriMesh>::custom(&topic))?;
        mesh_text(&m.positions_m, &m.triangles, &ext)?
    } else if schema == TetMesh::schema_name() {
        let m = r.read_static(&Topic::<TetMesh>::custom(&topic))?;
        mesh_text(&m.positions_m, &m.surface_triangles, &ext)?
    } else {
        return Err(BadInput(format!(
            "{}: channel `{topic}` has schema `{schema}`, which has no export",
            r.path().display()
        ))
        .into());
    };
    // Atomic: write NAME.tmp then rename.
    let tmp = softcap_mcap::tmp_path(output)
        .ok_or_else(|| BadInput(format!("{}: no file name", output.display())))?;
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, output).with_context(|| format!("renaming to {}", output.display()))?;
    Ok(())
}

/// `frame,id,x,y,z` (metres); markers without a position are left out.
pub fn markers_csv(frames: &[(u64, MarkerFrame)]) -> String {
    let mut s = String::from("frame,id,x,y,z\n");
    for (_, f) in frames {
        for m in &f.markers {
            if let Some(p) = &m.position_m {
                let _ = writeln!(s, "{},{},{},{},{}", f.frame, m.id, p.x, p.y, p.z);
            }
        }
    }
    s
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

/// `log_time_s,value`.
pub fn scalar_csv(samples: &[(u64, Scalar)]) -> String {
    let mut s = String::from("log_time_s,value\n");
    for (t, v) in samples {
        let _ = writeln!(s, "{},{}", *t as f64 * 1e-9, v.value);
    }
    s
}

fn mesh_text(positions_m: &[f64], triangles: &[u32], ext: &str) -> anyhow::Result<String> {
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
            return Err(BadInput(format!(
                "mesh export needs an .obj or .ply output, got `.{ext}`"
            ))
            .into());
        }
    }
    Ok(s)
}
