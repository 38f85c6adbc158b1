//! Dynamic scenarios (`kind = "dynamic"`): a soft object that swings, falls or is shaken, seen
//! only by depth cameras (wang2015 §4–5, §7). Writes the raw dynamic session of
//! SESSION_FORMAT.md ("Dynamic sessions") and its truth.
//!
//! | module | what |
//! |---|---|
//! | [`settings`] | the `[dynamic]` scenario table: motion, damping, depth cameras, sensor noise |
//! | [`truth`] | implicit neo-Hookean dynamics on the fine truth mesh (wang2015 eq. 3), hand push, floor, shaken clamp |
//! | [`external`] | a third-party truth (FElupe) read instead of simulating |
//! | [`depth`] | camera placement, ray-cast depth images (parry3d), Kinect-like noise, visibility |
//! | `files` | session.toml, rig/depth_cameras.toml, trigger, support motion, interactions, truth/ |
//!
//! The template (`template/volume.msh`) is a coarser box mesh (`object.fit_cells`) whose nodes
//! are carried by the truth to their frame-0 positions: the object as seen in frame 0, not its
//! rest shape. `truth/track_points.csv` follows material points sampled uniformly (by area) on
//! the truth surface, faces held by the clamp excepted; its `seen` column says whether some
//! camera sees the point in that frame.

pub mod depth;
pub mod external;
mod files;
pub mod settings;
pub mod truth;

pub use settings::{DepthCameraSettings, DepthSensorSettings, DynamicSettings, Motion};
pub use truth::{DynamicTruth, RigidMotion, SupportPlane, TruthFrame};

use std::path::Path;

use nalgebra::Vector3;
use rand::Rng;
use softcap_mesh::{SurfaceRayCaster, TetLocator};

use crate::error::{Result, SynthError, io_err};
use crate::scenario::Scenario;
use crate::write::SessionWriter;
use crate::{SynthReport, streams};

/// A material point on the truth surface: barycentric weights on a boundary triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    /// Truth boundary triangle (index into [`DynamicTruth::mesh`]'s boundary faces).
    pub triangle: usize,
    /// Barycentric weights.
    pub weights: [f64; 3],
}

/// What the session's cameras recorded of the truth, frame by frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Observation {
    /// Track point positions per frame, m.
    pub track_points_m: Vec<Vec<Vector3<f64>>>,
    /// Whether each track point is seen by some camera, per frame.
    pub seen: Vec<Vec<bool>>,
    /// Template node positions per frame (carried by the truth), m.
    pub template_nodes_m: Vec<Vec<Vector3<f64>>>,
    /// Valid depth readings per frame (all cameras).
    pub readings: Vec<usize>,
}

impl Observation {
    /// Mean over frames of the fraction of track points no camera sees.
    pub fn unseen_fraction(&self) -> f64 {
        let (mut unseen, mut all) = (0usize, 0usize);
        for s in &self.seen {
            unseen += s.iter().filter(|v| !**v).count();
            all += s.len();
        }
        unseen as f64 / all.max(1) as f64
    }
}

/// Simulates a dynamic scenario (or reads its third-party truth) and writes the session to `out`.
pub fn synthesize(s: &Scenario, out: &Path) -> Result<SynthReport> {
    SessionWriter::check_target(out)?;
    let d = &s.dynamic;
    let truth = match &d.external_truth {
        Some(dir) => external::read(s, Path::new(dir))?,
        None => truth::simulate(s)?,
    };
    let faces = truth.mesh.boundary_faces();
    let track = sample_track_points(&truth, &faces, d.track_points, s.seed);
    let template_embedding = embed_template(&truth)?;
    let cams = depth::rig(d, &aim_point(&truth))?;
    let (mut report, path) = SessionWriter::atomically(out, |w| {
        write_session(s, &truth, &faces, &track, &template_embedding, &cams, w)
    })?;
    report.path = path;
    Ok(report)
}

#[allow(clippy::too_many_arguments)]
fn write_session(
    s: &Scenario,
    truth: &DynamicTruth,
    faces: &[[usize; 3]],
    track: &[SurfacePoint],
    template_embedding: &[softcap_mesh::TetEmbedding],
    cams: &[depth::DepthCamera],
    w: &SessionWriter,
) -> Result<SynthReport> {
    let d = &s.dynamic;
    let template_frame0 = carried(template_embedding, truth, 0);
    files::write_static(s, truth, &template_frame0, cams, w)?;
    let mut obs = Observation::default();
    let mut images = 0;
    for (k, f) in truth.frames.iter().enumerate() {
        let caster = SurfaceRayCaster::new(&f.positions_m, faces)?;
        let mut readings = 0;
        for (c, cam) in cams.iter().enumerate() {
            let mut rng = crate::truth::stream(
                s.seed,
                streams::DEPTH + (c as u64) * 1_000_000 + f.frame as u64,
            );
            let img = depth::render(cam, &caster, &f.positions_m, &d.sensor, &mut rng);
            let counts = img.counts(&d.sensor);
            readings += counts.iter().filter(|&&v| v > 0).count();
            files::write_depth_png(w, &cam.camera.id, f.frame, &img, &counts)?;
            images += 1;
        }
        let (points, seen): (Vec<_>, Vec<_>) = track
            .iter()
            .map(|tp| {
                let tri = faces[tp.triangle].map(|i| f.positions_m[i]);
                let p = tri[0] * tp.weights[0] + tri[1] * tp.weights[1] + tri[2] * tp.weights[2];
                let n = (tri[1] - tri[0]).cross(&(tri[2] - tri[0])).normalize();
                (p, depth::seen_by_any(cams, &caster, &p, &n, &d.sensor))
            })
            .unzip();
        obs.track_points_m.push(points);
        obs.seen.push(seen);
        obs.template_nodes_m
            .push(carried(template_embedding, truth, k));
        obs.readings.push(readings);
    }
    files::write_truth(s, truth, &obs, w)?;
    Ok(SynthReport {
        path: w.target.clone(),
        frames: truth.frames.len(),
        locations: 0,
        truth_tets: truth.mesh.tets.len(),
        fit_tets: truth.template_rest.tets.len(),
        max_axial_force_n: 0.0,
        max_marker_displacement_m: max_displacement(&obs.track_points_m),
        detections: 0,
        images,
        max_iterations: truth.max_iterations,
        depth_readings: obs.readings.iter().sum(),
        unseen_fraction: obs.unseen_fraction(),
    })
}

/// Largest displacement of any track point from its frame-0 position, m.
fn max_displacement(frames: &[Vec<Vector3<f64>>]) -> f64 {
    let Some(first) = frames.first() else {
        return 0.0;
    };
    frames
        .iter()
        .flat_map(|f| f.iter().zip(first).map(|(a, b)| (a - b).norm()))
        .fold(0.0, f64::max)
}

/// Area-uniform samples on the truth surface (seeded), leaving out faces whose three nodes are
/// all held by the support.
pub fn sample_track_points(
    truth: &DynamicTruth,
    faces: &[[usize; 3]],
    count: usize,
    seed: u64,
) -> Vec<SurfacePoint> {
    let x = &truth.mesh.vertices;
    let held: std::collections::BTreeSet<usize> = truth.attached.iter().copied().collect();
    let mut cumulative = Vec::with_capacity(faces.len());
    let mut total = 0.0;
    for f in faces {
        let free = !f.iter().all(|i| held.contains(i));
        if free {
            total += 0.5 * (x[f[1]] - x[f[0]]).cross(&(x[f[2]] - x[f[0]])).norm();
        }
        cumulative.push(total);
    }
    let mut rng = crate::truth::stream(seed, streams::TRACK_POINTS);
    (0..count)
        .map(|_| {
            let a = rng.random::<f64>() * total;
            let triangle = cumulative.partition_point(|&c| c <= a).min(faces.len() - 1);
            let (r1, r2): (f64, f64) = (rng.random(), rng.random());
            let s = r1.sqrt();
            SurfacePoint {
                triangle,
                weights: [1.0 - s, s * (1.0 - r2), s * r2],
            }
        })
        .collect()
}

/// Barycentric embedding of the template's rest nodes in the truth's rest mesh.
fn embed_template(truth: &DynamicTruth) -> Result<Vec<softcap_mesh::TetEmbedding>> {
    let locator = TetLocator::new(&truth.mesh);
    truth
        .template_rest
        .vertices
        .iter()
        .enumerate()
        .map(|(i, p)| {
            locator.locate(p).ok_or_else(|| SynthError::Unsupported {
                scenario: "dynamic".into(),
                message: format!("template node {i} cannot be embedded in the truth mesh"),
            })
        })
        .collect()
}

/// Template node positions carried by truth frame `k`.
fn carried(
    embedding: &[softcap_mesh::TetEmbedding],
    truth: &DynamicTruth,
    k: usize,
) -> Vec<Vector3<f64>> {
    embedding
        .iter()
        .map(|e| e.position(&truth.mesh.tets, &truth.frames[k].positions_m))
        .collect()
}

/// Where the cameras look: the centre of the bounding box of every truth frame.
fn aim_point(truth: &DynamicTruth) -> Vector3<f64> {
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for f in &truth.frames {
        for p in &f.positions_m {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
    }
    0.5 * (lo + hi)
}

pub(crate) fn ensure_dir(path: &Path) -> Result<()> {
    std::fs::create_dir_all(path).map_err(io_err(path))
}
