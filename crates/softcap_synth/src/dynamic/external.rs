//! A third-party truth rendered by the virtual rig instead of softcap's own simulation, so the
//! tracker is checked against physics softcap did not compute (`scripts/felupe_dynamic_truth.py`
//! writes one with FElupe). A folder with
//!
//! - `truth.toml`: `solver` (one line), `cells = [nx, ny, nz]`, `min_mm`, `max_mm` (the
//!   reference box), `young_pa`, `poisson`, `density_kg_m3`, `rayleigh_alpha_per_s`,
//!   `rayleigh_beta_s`, `gravity_m_s2`, `clamped_at_x_min` (bool), `interactions` (`[[t0, t1]…]`,
//!   s), `motion` (one line);
//! - `positions.csv`: `frame,t_s,node,x,y,z` (mm), every node of the structured grid of
//!   (nx+1)(ny+1)(nz+1) nodes numbered `i + (nx+1)(j + (ny+1)k)` in every frame, frames 0, 1, …
//!   at the camera rate.
//!
//! The truth surface is the grid's boundary, triangulated as `softcap_mesh::box_tet_mesh`'s
//! (node numbering is the same), so between nodes the rendered surface is piecewise linear.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::Deserialize;
use softcap_mesh::box_tet_mesh;

use super::truth::{DynamicTruth, RigidMotion, SupportPlane, TruthFrame, TruthMaterial};
use crate::error::{Result, SynthError};
use crate::scenario::Scenario;

const MM: f64 = 1e-3;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TruthToml {
    solver: String,
    cells: [usize; 3],
    min_mm: [f64; 3],
    max_mm: [f64; 3],
    young_pa: f64,
    poisson: f64,
    density_kg_m3: f64,
    rayleigh_alpha_per_s: f64,
    rayleigh_beta_s: f64,
    gravity_m_s2: [f64; 3],
    clamped_at_x_min: bool,
    #[serde(default)]
    interactions: Vec<[f64; 2]>,
    motion: String,
}

fn bad(path: &Path, message: impl Into<String>) -> SynthError {
    SynthError::Scenario {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Reads the third-party truth in `dir` (the scenario's `dynamic.external_truth`, already
/// resolved against the scenario file's folder).
pub fn read(s: &Scenario, dir: &Path) -> Result<DynamicTruth> {
    let toml_path = dir.join("truth.toml");
    let text = std::fs::read_to_string(&toml_path).map_err(|source| SynthError::Io {
        path: toml_path.clone(),
        source,
    })?;
    let t: TruthToml = toml::from_str(&text).map_err(|e| bad(&toml_path, e.message().trim()))?;
    if t.cells.contains(&0) {
        return Err(bad(&toml_path, "cells must be ≥ 1 in every direction"));
    }
    let [nx, ny, nz] = t.cells;
    let nodes = (nx + 1) * (ny + 1) * (nz + 1);
    let (min, max) = (t.min_mm.map(|v| v * MM), t.max_mm.map(|v| v * MM));
    let mesh = box_tet_mesh(min, max, t.cells);
    let template_rest = box_tet_mesh(min, max, s.object.fit_cells);
    let csv_path = dir.join("positions.csv");
    let frames = read_positions(&csv_path, nodes)?;
    let support = t.clamped_at_x_min.then(|| SupportPlane {
        normal: Vector3::x(),
        offset_m: min[0],
        tolerance_m: 1e-6 * (max[0] - min[0]),
    });
    let attached = match &support {
        Some(p) => (0..nodes)
            .filter(|&i| p.attaches(&mesh.vertices[i]))
            .collect(),
        None => Vec::new(),
    };
    Ok(DynamicTruth {
        material: TruthMaterial {
            young_pa: t.young_pa,
            poisson: t.poisson,
            density_kg_m3: t.density_kg_m3,
            rayleigh_alpha_per_s: t.rayleigh_alpha_per_s,
            rayleigh_beta_s: t.rayleigh_beta_s,
            gravity_m_s2: t.gravity_m_s2,
        },
        support_motion: vec![RigidMotion::identity(); frames.len()],
        mesh,
        template_rest,
        support,
        attached,
        frames,
        interactions: t.interactions.iter().map(|i| (i[0], i[1])).collect(),
        retried_steps: 0,
        max_iterations: 0,
        solver: t.solver,
        motion_note: Some(t.motion),
    })
}

/// `positions.csv` → frames of `nodes` positions (m); every frame must list every node once.
fn read_positions(path: &Path, nodes: usize) -> Result<Vec<TruthFrame>> {
    let text = std::fs::read_to_string(path).map_err(|source| SynthError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut lines = text.lines().enumerate();
    let header = lines.next().map(|(_, l)| l.trim()).unwrap_or("");
    if header != "frame,t_s,node,x,y,z" {
        return Err(bad(
            path,
            format!("line 1: expected header `frame,t_s,node,x,y,z`, got `{header}`"),
        ));
    }
    let mut frames: Vec<TruthFrame> = Vec::new();
    let mut filled: Vec<bool> = Vec::new();
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let at = |m: String| bad(path, format!("line {}: {m}", i + 1));
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 6 {
            return Err(at(format!("expected 6 fields, got {}", f.len())));
        }
        let num = |k: usize| -> Result<f64> {
            f[k].trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| at(format!("field {k}: not a finite number: `{}`", f[k])))
        };
        let frame = f[0]
            .trim()
            .parse::<usize>()
            .map_err(|_| at("frame: not an index".into()))?;
        let node = f[2]
            .trim()
            .parse::<usize>()
            .map_err(|_| at("node: not an index".into()))?;
        if node >= nodes {
            return Err(at(format!("node {node} ≥ {nodes} grid nodes")));
        }
        if frame == frames.len() {
            if let Some(k) = filled.iter().position(|v| !v) {
                return Err(at(format!("frame {} lacks node {k}", frame - 1)));
            }
            frames.push(TruthFrame {
                frame,
                t_s: num(1)?,
                positions_m: vec![Vector3::zeros(); nodes],
            });
            filled = vec![false; nodes];
        } else if frame + 1 != frames.len() {
            return Err(at(format!("frame {frame} out of order")));
        }
        frames[frame].positions_m[node] = Vector3::new(num(3)?, num(4)?, num(5)?) * MM;
        filled[node] = true;
    }
    if let Some(k) = filled.iter().position(|v| !v) {
        return Err(bad(path, format!("last frame lacks node {k}")));
    }
    if frames.len() < 2 {
        return Err(bad(path, "needs at least two frames"));
    }
    Ok(frames)
}

/// `dynamic.external_truth` resolved against the folder of the scenario file.
pub fn resolve(scenario_path: &Path, dir: &str) -> PathBuf {
    let p = Path::new(dir);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        scenario_path.parent().unwrap_or(Path::new(".")).join(p)
    }
}
