//! Tracking error against the truth of a synthetic dynamic session (for tests, benches and the
//! comparison scripts — the tracker itself never reads `truth/`).
//!
//! The truth's track points (`truth/track_points.csv`) are material points on the surface. Each
//! is embedded at frame 0 on the template's surface (closest point on its boundary triangles,
//! barycentric weights) and carried by the tracked node positions; the error of a frame is the
//! distance between the carried point and the true one. The same embedding applied to the truth's
//! own template nodes (`truth/template_nodes.csv`) gives the floor the template can reach.

use std::path::Path;

use nalgebra::Vector3;
use softcap_mesh::{TetMesh, TriEmbedding, TriLocator, TriMesh};

use crate::error::{Result, TissueError};

/// Error statistics of carried surface points, m.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfacePointError {
    /// RMS over every frame and point.
    pub rms_m: f64,
    /// RMS over the (frame, point) pairs some camera sees.
    pub rms_seen_m: f64,
    /// RMS over the pairs no camera sees.
    pub rms_unseen_m: f64,
    /// Largest error.
    pub max_m: f64,
    /// RMS per frame.
    pub per_frame_rms_m: Vec<f64>,
    /// Fraction of (frame, point) pairs no camera sees.
    pub unseen_fraction: f64,
}

/// The truth of a synthetic dynamic session: track points per frame and whether each is seen.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackTruth {
    /// Positions per frame, m.
    pub points_m: Vec<Vec<Vector3<f64>>>,
    /// Seen by some camera, per frame.
    pub seen: Vec<Vec<bool>>,
}

fn read(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| TissueError::bad_input(path, "file", e.to_string()))
}

/// Rows `frame,id,x,y,z[,…]` grouped by frame (ids 0..n in order within each frame), lengths
/// scaled by `metres_per_unit`; the optional `seen` column (0/1) is returned too.
fn read_frame_table(
    path: &Path,
    id_column: &str,
    metres_per_unit: f64,
) -> Result<(Vec<Vec<Vector3<f64>>>, Vec<Vec<bool>>)> {
    let text = read(path)?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let header: Vec<&str> = lines
        .next()
        .map(|(_, l)| l.split(',').map(str::trim).collect())
        .unwrap_or_default();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .ok_or_else(|| TissueError::bad_input(path, "line 1", format!("no `{name}` column")))
    };
    let (cf, ci, cx, cy, cz) = (
        col("frame")?,
        col(id_column)?,
        col("x")?,
        col("y")?,
        col("z")?,
    );
    let cs = header.iter().position(|h| *h == "seen");
    let mut points: Vec<Vec<Vector3<f64>>> = Vec::new();
    let mut seen: Vec<Vec<bool>> = Vec::new();
    for (i, line) in lines {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let bad =
            |what: &str| TissueError::bad_input(path, format!("line {}", i + 1), what.to_string());
        let get = |c: usize| f.get(c).copied().ok_or_else(|| bad("too few fields"));
        let num =
            |c: usize| -> Result<f64> { get(c)?.parse::<f64>().map_err(|_| bad("not a number")) };
        let frame: usize = get(cf)?.parse().map_err(|_| bad("bad frame"))?;
        let id: usize = get(ci)?.parse().map_err(|_| bad("bad id"))?;
        if frame == points.len() {
            points.push(Vec::new());
            seen.push(Vec::new());
        }
        if frame + 1 != points.len() || id != points[frame].len() {
            return Err(bad("rows must be sorted by frame, then id from 0"));
        }
        points[frame].push(Vector3::new(num(cx)?, num(cy)?, num(cz)?) * metres_per_unit);
        seen[frame].push(match cs {
            Some(c) => get(c)? == "1",
            None => true,
        });
    }
    Ok((points, seen))
}

/// Reads `truth/track_points.csv` of a synthetic session (mm unless `metres_per_unit` says).
pub fn read_track_points(path: &Path, metres_per_unit: f64) -> Result<TrackTruth> {
    let (points_m, seen) = read_frame_table(path, "id", metres_per_unit)?;
    Ok(TrackTruth { points_m, seen })
}

/// Reads node trajectories `frame,node,x,y,z` (m unless `metres_per_unit` says): the export of
/// `softcap inspect export track.mcap --what nodes`, `truth/template_nodes.csv` (mm) or another
/// tracker's output.
pub fn read_node_trajectories(path: &Path, metres_per_unit: f64) -> Result<Vec<Vec<Vector3<f64>>>> {
    Ok(read_frame_table(path, "node", metres_per_unit)?.0)
}

/// Embeds the frame-0 track points on the boundary of `mesh` (its frame-0 shape).
pub fn embed_on_surface(
    mesh: &TetMesh,
    points_m: &[Vector3<f64>],
) -> (Vec<[usize; 3]>, Vec<TriEmbedding>) {
    let faces = mesh.boundary_faces();
    let surface = TriMesh {
        vertices: mesh.vertices.clone(),
        triangles: faces.clone(),
    };
    let locator = TriLocator::new(&surface);
    let emb = points_m
        .iter()
        .map(|p| {
            locator
                .locate(p)
                .expect("a tet mesh has boundary triangles")
        })
        .collect();
    (faces, emb)
}

/// Error of node trajectories `tracked` (one position list per frame, the mesh's node order)
/// against the truth, with the track points embedded on `mesh` at frame 0. Frames beyond the
/// shorter of the two are ignored.
pub fn surface_point_error(
    mesh: &TetMesh,
    tracked: &[Vec<Vector3<f64>>],
    truth: &TrackTruth,
) -> SurfacePointError {
    let (faces, emb) = embed_on_surface(mesh, &truth.points_m[0]);
    let frames = tracked.len().min(truth.points_m.len());
    let (mut all, mut seen, mut unseen) = ((0.0, 0usize), (0.0, 0usize), (0.0, 0usize));
    let mut max_m: f64 = 0.0;
    let mut per_frame = Vec::with_capacity(frames);
    for k in 0..frames {
        let mut sum = 0.0;
        for (i, e) in emb.iter().enumerate() {
            let p = e.position(&faces, &tracked[k]);
            let d2 = (p - truth.points_m[k][i]).norm_squared();
            sum += d2;
            max_m = max_m.max(d2.sqrt());
            all = (all.0 + d2, all.1 + 1);
            if truth.seen[k][i] {
                seen = (seen.0 + d2, seen.1 + 1);
            } else {
                unseen = (unseen.0 + d2, unseen.1 + 1);
            }
        }
        per_frame.push((sum / emb.len().max(1) as f64).sqrt());
    }
    let rms = |(s, n): (f64, usize)| {
        if n > 0 {
            (s / n as f64).sqrt()
        } else {
            f64::NAN
        }
    };
    SurfacePointError {
        rms_m: rms(all),
        rms_seen_m: rms(seen),
        rms_unseen_m: rms(unseen),
        max_m,
        per_frame_rms_m: per_frame,
        unseen_fraction: unseen.1 as f64 / all.1.max(1) as f64,
    }
}
