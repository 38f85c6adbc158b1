//! Typed reading of dynamic recordings (wang2015): the point clouds of a dynamic `capture.mcap`
//! ([`DynamicCaptureData::read`]), a dynamic material ([`read_dynamic_material`]) and the
//! output of `softcap tissue track` ([`read_track`]), validated so a stage can use them without
//! re-checking (every error names file, channel and field).
//!
//! ```
//! use softcap_mcap::dynamic::DynamicCaptureData;
//! use softcap_mcap::{proto, topics, Provenance, Writer};
//! # fn main() -> Result<(), softcap_mcap::Error> {
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("capture.mcap");
//! let mut w = Writer::create(&path, &Provenance::new("capture", "0"))?;
//! w.write_static(&topics::SESSION, &proto::SessionInfo {
//!     name: "bar".into(), kind: "dynamic".into(), ..Default::default()
//! })?;
//! w.write_static(&topics::DYNAMIC_SESSION, &proto::DynamicSession {
//!     source: "points".into(), frames: 1, ..Default::default()
//! })?;
//! w.write(&topics::POINTS, 0, &proto::PointCloudFrame {
//!     frame: 0, positions_m: vec![0.0, 0.0, 0.5, 0.01, 0.0, 0.5], ..Default::default()
//! })?;
//! w.finish()?;
//! let capture = DynamicCaptureData::read(&path)?;
//! assert_eq!(capture.frames[0].points_m.len(), 2);
//! # Ok(()) }
//! ```

use std::path::{Path, PathBuf};

use crate::capture::SessionInfo;
use crate::error::{Error, Result};
use crate::material::{VolumeMesh, read_volume_mesh};
use crate::proto;
use crate::reader::Recording;
use crate::topics;

/// A rigid motion p' = R p + t (R as a unit quaternion `[w, x, y, z]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidMotion {
    /// Unit quaternion `[w, x, y, z]`.
    pub quaternion_wxyz: [f64; 4],
    /// Translation, m.
    pub translation_m: [f64; 3],
}

/// One frame's cloud.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudFrameData {
    /// Frame index.
    pub frame: u64,
    /// Camera time, s.
    pub t_camera_s: f64,
    /// Points, m, world frame.
    pub points_m: Vec<[f64; 3]>,
    /// Unit normals (empty when the capture had none).
    pub normals: Vec<[f64; 3]>,
    /// Camera index per point (empty for fused PLY input).
    pub camera: Vec<u32>,
    /// Motion of the attached region relative to frame 0.
    pub support_motion: Option<RigidMotion>,
}

/// A dynamic capture read into memory.
#[derive(Debug, Clone, PartialEq)]
pub struct DynamicCaptureData {
    /// The file read.
    pub path: PathBuf,
    /// `/capture/session` (kind `dynamic`).
    pub session: SessionInfo,
    /// Metres per length unit of the session files (1 when the capture does not say).
    pub metres_per_unit: f64,
    /// `/capture/dynamic`.
    pub dynamic: proto::DynamicSession,
    /// Frames in increasing frame order.
    pub frames: Vec<CloudFrameData>,
}

fn invalid(path: &Path, topic: &str, field: impl Into<String>, problem: &str) -> Error {
    Error::Invalid {
        path: path.to_path_buf(),
        topic: topic.to_string(),
        field: field.into(),
        problem: problem.to_string(),
    }
}

fn triples(path: &Path, topic: &str, field: &str, flat: &[f32]) -> Result<Vec<[f64; 3]>> {
    if !flat.len().is_multiple_of(3) {
        return Err(invalid(path, topic, field, "length is not a multiple of 3"));
    }
    if flat.iter().any(|v| !v.is_finite()) {
        return Err(invalid(path, topic, field, "not finite"));
    }
    Ok(flat
        .chunks_exact(3)
        .map(|c| [f64::from(c[0]), f64::from(c[1]), f64::from(c[2])])
        .collect())
}

impl DynamicCaptureData {
    /// Reads and validates a dynamic capture: `/capture/session` of kind `dynamic`,
    /// `/capture/dynamic` and `/capture/points` (frames strictly increasing, coordinates finite,
    /// normals and camera indices absent or one per point, camera indices in range).
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let r = Recording::open(path)?;
        let raw_session = r.read_static(&topics::SESSION)?;
        let session = SessionInfo::from_proto(path, &raw_session)?;
        if session.kind != "dynamic" {
            return Err(invalid(
                path,
                topics::SESSION.name(),
                "kind",
                &format!("`{}` is not a dynamic capture", session.kind),
            ));
        }
        let dynamic = r.read_static(&topics::DYNAMIC_SESSION)?;
        let points_topic = topics::POINTS;
        let topic = points_topic.name();
        let mut frames: Vec<CloudFrameData> = Vec::new();
        for (_, m) in r.read(&topics::POINTS)? {
            let at = |f: &str| format!("frame {}: {f}", m.frame);
            if frames.last().is_some_and(|p| p.frame >= m.frame) {
                return Err(invalid(path, topic, at("frame"), "frames must increase"));
            }
            let points_m = triples(path, topic, &at("positions_m"), &m.positions_m)?;
            let normals = triples(path, topic, &at("normals"), &m.normals)?;
            if !normals.is_empty() && normals.len() != points_m.len() {
                return Err(invalid(path, topic, at("normals"), "not one per point"));
            }
            if !m.camera.is_empty() && m.camera.len() != points_m.len() {
                return Err(invalid(path, topic, at("camera"), "not one per point"));
            }
            if m.camera
                .iter()
                .any(|&c| c as usize >= dynamic.cameras.len())
            {
                return Err(invalid(
                    path,
                    topic,
                    at("camera"),
                    "index past the cameras of /capture/dynamic",
                ));
            }
            let support_motion = match &m.support_motion {
                None => None,
                Some(s) => {
                    let q = [s.qw, s.qx, s.qy, s.qz];
                    let t = s.translation_m.unwrap_or_default();
                    let qn = q.iter().map(|v| v * v).sum::<f64>().sqrt();
                    if !((qn - 1.0).abs() < 1e-6 && [t.x, t.y, t.z].iter().all(|v| v.is_finite())) {
                        return Err(invalid(
                            path,
                            topic,
                            at("support_motion"),
                            "quaternion not unit or translation not finite",
                        ));
                    }
                    Some(RigidMotion {
                        quaternion_wxyz: q,
                        translation_m: [t.x, t.y, t.z],
                    })
                }
            };
            frames.push(CloudFrameData {
                frame: m.frame,
                t_camera_s: m.t_camera_s,
                points_m,
                normals,
                camera: m.camera,
                support_motion,
            });
        }
        if frames.is_empty() {
            return Err(invalid(path, topic, "frames", "no point cloud frames"));
        }
        for (k, c) in dynamic.cameras.iter().enumerate() {
            let finite = [c.fx, c.fy, c.cx, c.cy]
                .iter()
                .chain(&c.distortion)
                .chain(&c.rotation)
                .all(|v| v.is_finite());
            if !(finite
                && c.rotation.len() == 9
                && c.distortion.len() == 5
                && c.fx > 0.0
                && c.fy > 0.0)
            {
                return Err(invalid(
                    path,
                    topics::DYNAMIC_SESSION.name(),
                    format!("cameras[{k}]"),
                    "needs finite positive fx, fy, 5 distortion and 9 rotation entries",
                ));
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            session,
            metres_per_unit: if raw_session.metres_per_unit > 0.0 {
                raw_session.metres_per_unit
            } else {
                1.0
            },
            dynamic,
            frames,
        })
    }
}

/// Reads `/tissue/dynamic_material` from `path`, checking E > 0 (one value or `tets` values),
/// ν ∈ (−1, 0.5), ρ > 0, α, β ≥ 0 and a rest shape of 3 × `nodes` coordinates (or none).
pub fn read_dynamic_material(
    path: impl AsRef<Path>,
    tets: usize,
    nodes: usize,
) -> Result<proto::DynamicMaterial> {
    let path = path.as_ref();
    let m = Recording::open(path)?.read_static(&topics::DYNAMIC_MATERIAL)?;
    validate_dynamic_material(path, m, tets, nodes)
}

/// The checks of [`read_dynamic_material`] on a decoded message.
fn validate_dynamic_material(
    path: &Path,
    m: proto::DynamicMaterial,
    tets: usize,
    nodes: usize,
) -> Result<proto::DynamicMaterial> {
    let material_topic = topics::DYNAMIC_MATERIAL;
    let topic = material_topic.name();
    if !(m.young_pa.len() == 1 || m.young_pa.len() == tets) {
        return Err(invalid(
            path,
            topic,
            "young_pa",
            &format!(
                "{} values for a mesh of {tets} tets (need 1 or {tets})",
                m.young_pa.len()
            ),
        ));
    }
    if m.young_pa.iter().any(|e| !(e.is_finite() && *e > 0.0)) {
        return Err(invalid(path, topic, "young_pa", "must be positive"));
    }
    if !(m.poisson > -1.0 && m.poisson < 0.5) {
        return Err(invalid(path, topic, "poisson", "must be in (−1, 0.5)"));
    }
    if !(m.density_kg_m3 > 0.0 && m.density_kg_m3.is_finite()) {
        return Err(invalid(path, topic, "density_kg_m3", "must be positive"));
    }
    for (v, f) in [
        (m.rayleigh_alpha_per_s, "rayleigh_alpha_per_s"),
        (m.rayleigh_beta_s, "rayleigh_beta_s"),
    ] {
        if !(v >= 0.0 && v.is_finite()) {
            return Err(invalid(path, topic, f, "must be ≥ 0"));
        }
    }
    if !(m.rest_positions_m.is_empty() || m.rest_positions_m.len() == 3 * nodes) {
        return Err(invalid(
            path,
            topic,
            "rest_positions_m",
            &format!(
                "{} coordinates for a mesh of {nodes} nodes",
                m.rest_positions_m.len()
            ),
        ));
    }
    if m.rest_positions_m.iter().any(|v| !v.is_finite()) {
        return Err(invalid(path, topic, "rest_positions_m", "not finite"));
    }
    Ok(m)
}

/// One tracked frame of a track.mcap (`/tissue/track/nodes` with its `/tissue/track/status`).
#[derive(Debug, Clone, PartialEq)]
pub struct TrackedFrame {
    /// Frame index of the capture.
    pub frame: u64,
    /// Camera time, s.
    pub t_camera_s: f64,
    /// Tracked positions of the template's nodes, m, world frame, in `/mesh/volume` order.
    pub positions_m: Vec<[f64; 3]>,
    /// The tracker's state after this frame (`status` is one of [`TRACK_STATUSES`]).
    pub status: proto::TrackStatus,
}

impl TrackedFrame {
    /// Whether the tracker trusted this frame (`converged` or `max-iterations`): a `diverged`
    /// frame was restarted from the previous one, a `no-points` frame only predicted.
    pub fn is_tracked(&self) -> bool {
        matches!(self.status.status.as_str(), "converged" | "max-iterations")
    }
}

/// The values `/tissue/track/status` `status` takes.
pub const TRACK_STATUSES: [&str; 4] = ["converged", "max-iterations", "diverged", "no-points"];

/// A track.mcap read into memory: [`read_track`].
#[derive(Debug, Clone, PartialEq)]
pub struct TrackRecording {
    /// The file read.
    pub path: PathBuf,
    /// `/mesh/volume`: the template mesh at frame 0 (its node order indexes every frame).
    pub mesh: VolumeMesh,
    /// `/tissue/dynamic_material`: the material the tracker used (rest shape included when solved).
    pub material: proto::DynamicMaterial,
    /// Tracked frames in increasing frame order.
    pub frames: Vec<TrackedFrame>,
    /// `/tissue/track/report`, if present.
    pub report: Option<proto::Report>,
}

/// Reads and validates the output of `softcap tissue track`: `/mesh/volume`,
/// `/tissue/dynamic_material` (checked as by [`read_dynamic_material`]), `/tissue/track/nodes`
/// (frames strictly increasing, one finite position per template node) and
/// `/tissue/track/status` (exactly one per node frame, same frame numbers, a known status).
///
/// ```
/// use softcap_mcap::dynamic::read_track;
/// use softcap_mcap::{proto, topics, Provenance, Writer};
/// # fn main() -> Result<(), softcap_mcap::Error> {
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("track.mcap");
/// let mut w = Writer::create(&path, &Provenance::new("tissue track", "0"))?;
/// let x = vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
/// w.write_static(&topics::VOLUME_MESH, &proto::TetMesh {
///     positions_m: x.clone(), tets: vec![0, 1, 2, 3], ..Default::default()
/// })?;
/// w.write_static(&topics::DYNAMIC_MATERIAL, &proto::DynamicMaterial {
///     young_pa: vec![1e5], poisson: 0.4, density_kg_m3: 1000.0, ..Default::default()
/// })?;
/// w.write(&topics::TRACK_NODES, 0, &proto::NodeFrame { frame: 0, positions_m: x, ..Default::default() })?;
/// w.write(&topics::TRACK_STATUS, 0, &proto::TrackStatus {
///     frame: 0, status: "converged".into(), ..Default::default()
/// })?;
/// w.finish()?;
/// let track = read_track(&path)?;
/// assert_eq!(track.frames[0].positions_m[1], [1.0, 0.0, 0.0]);
/// assert!(track.frames[0].is_tracked());
/// # Ok(()) }
/// ```
pub fn read_track(path: impl AsRef<Path>) -> Result<TrackRecording> {
    let path = path.as_ref();
    let r = Recording::open(path)?;
    let mesh = read_volume_mesh(&r)?;
    let nodes = mesh.vertices_m.len();
    let material = validate_dynamic_material(
        path,
        r.read_static(&topics::DYNAMIC_MATERIAL)?,
        mesh.tets.len(),
        nodes,
    )?;
    let nodes_topic = topics::TRACK_NODES;
    let ntopic = nodes_topic.name();
    let node_frames = r.read(&topics::TRACK_NODES)?;
    if node_frames.is_empty() {
        return Err(invalid(path, ntopic, "frames", "no tracked frames"));
    }
    let status_topic = topics::TRACK_STATUS;
    let stopic = status_topic.name();
    let statuses = r.read(&topics::TRACK_STATUS)?;
    if statuses.len() != node_frames.len() {
        return Err(invalid(
            path,
            stopic,
            "frames",
            &format!(
                "{} status messages for {} node frames (need one per frame)",
                statuses.len(),
                node_frames.len()
            ),
        ));
    }
    let mut frames: Vec<TrackedFrame> = Vec::with_capacity(node_frames.len());
    for ((_, n), (_, status)) in node_frames.into_iter().zip(statuses) {
        let at = |f: &str| format!("frame {}: {f}", n.frame);
        if frames.last().is_some_and(|p| p.frame >= n.frame) {
            return Err(invalid(path, ntopic, at("frame"), "frames must increase"));
        }
        if n.positions_m.len() != 3 * nodes {
            return Err(invalid(
                path,
                ntopic,
                at("positions_m"),
                &format!(
                    "{} coordinates for a template of {nodes} nodes",
                    n.positions_m.len()
                ),
            ));
        }
        if let Some(i) = n.positions_m.iter().position(|v| !v.is_finite()) {
            return Err(invalid(
                path,
                ntopic,
                at(&format!("positions_m[{i}]")),
                "not finite",
            ));
        }
        if status.frame != n.frame {
            return Err(invalid(
                path,
                stopic,
                at("frame"),
                &format!(
                    "status is for frame {} (statuses must pair with node frames)",
                    status.frame
                ),
            ));
        }
        if !TRACK_STATUSES.contains(&status.status.as_str()) {
            return Err(invalid(
                path,
                stopic,
                at("status"),
                &format!(
                    "`{}` is none of {}",
                    status.status,
                    TRACK_STATUSES.join(", ")
                ),
            ));
        }
        frames.push(TrackedFrame {
            frame: n.frame,
            t_camera_s: n.t_camera_s,
            positions_m: n
                .positions_m
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect(),
            status,
        });
    }
    let report = if r.channel(topics::TRACK_REPORT.name()).is_some() {
        Some(r.read_static(&topics::TRACK_REPORT)?)
    } else {
        None
    };
    Ok(TrackRecording {
        path: path.to_path_buf(),
        mesh,
        material,
        frames,
        report,
    })
}
