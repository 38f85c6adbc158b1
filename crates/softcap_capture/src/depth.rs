//! Dynamic sessions (SESSION_FORMAT.md "Dynamic sessions", wang2015 §4): depth cameras watching
//! a freely moving object, turned into one world-frame point cloud per frame.
//!
//! Every valid pixel (u, v) of a 16-bit depth image (count × `depth_scale`, inside
//! [`min_depth`, `max_depth`]) is back-projected through the camera's Brown–Conrady model —
//! `softcap_core::Camera::back_project`: X_c = z (x, y, 1) with (x, y) the undistorted normalized
//! coordinates, X = Rᵀ (X_c − t) — and gets the normal of the surface the depth image shows there,
//! n ∝ (P(u+1, v) − P(u−1, v)) × (P(u, v+1) − P(u, v−1)) (one-sided where a neighbour is missing
//! or lies across a depth jump), oriented towards the camera. A pixel with no usable neighbour in
//! u or in v has no normal and is dropped (isolated readings and silhouette slivers). The clouds
//! of all cameras are fused and optionally voxel-downsampled (centroid and mean normal per voxel,
//! voxels in lexicographic order). Fused PLY clouds (`points/<frame>.ply`) are read instead when
//! the session has no depth images; they carry no normals.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::error::{CaptureError, Result};
use crate::session::{
    CsvTable, RawCamera, RawFiles, Session, SessionKind, Support, parse_toml, raw_camera,
    read_trigger_csv,
};

/// A depth camera: the calibrated camera and its depth encoding (metres).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthCamera {
    /// Pinhole + Brown–Conrady camera (`softcap_core::Camera`).
    pub camera: Camera,
    /// One count of the 16-bit image, m.
    pub depth_scale_m: f64,
    /// Smallest valid depth, m.
    pub min_depth_m: f64,
    /// Largest valid depth, m.
    pub max_depth_m: f64,
}

/// Rigid motion of the attached region relative to frame 0 (`support_motion.csv`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SupportMotion {
    /// Frame index.
    pub frame: usize,
    /// Rotation R.
    pub rotation: UnitQuaternion<f64>,
    /// Translation t, m.
    pub translation_m: Vector3<f64>,
}

/// Where the clouds come from.
#[derive(Debug, Clone, PartialEq)]
pub enum CloudSource {
    /// `depth/<camera>/<frame>.png` with the depth cameras.
    Depth {
        /// Folder of the depth images.
        dir: PathBuf,
        /// Cameras file (for provenance).
        cameras_path: PathBuf,
        /// The cameras.
        cameras: Vec<DepthCamera>,
    },
    /// `points/<frame>.ply`, world frame.
    Points {
        /// Folder of the PLY files.
        dir: PathBuf,
    },
}

/// The dynamic part of a session.
#[derive(Debug, Clone, PartialEq)]
pub struct DynamicInputs {
    /// Depth images or fused clouds.
    pub source: CloudSource,
    /// 0-based nodes of the volume mesh held by the support (`[support] nodes_file`).
    pub support_nodes: Option<Vec<usize>>,
    /// Support motion per frame (`support_motion.csv`), if given.
    pub support_motion: Option<Vec<SupportMotion>>,
    /// Interaction intervals `(t_start_s, t_end_s)` (`interactions.csv`).
    pub interactions: Vec<(f64, f64)>,
    /// Files read (for provenance): trigger, volume mesh, support nodes, support motion,
    /// interactions.
    pub files: Vec<PathBuf>,
}

/// What `Session::load` parsed from session.toml before handing a dynamic session over.
pub(crate) struct DynamicManifest<'a> {
    pub dir: &'a Path,
    pub manifest: &'a Path,
    pub name: String,
    pub metres_per_unit: f64,
    pub gravity: Vector3<f64>,
    pub density_kg_m3: Option<f64>,
    pub support: Option<Option<Support>>,
    pub support_nodes_file: Option<PathBuf>,
}

#[derive(Deserialize)]
struct RawDepthCameras {
    camera: Vec<RawDepthCamera>,
}

#[derive(Deserialize)]
struct RawDepthCamera {
    #[serde(flatten)]
    camera: RawCamera,
    depth_scale: f64,
    min_depth: f64,
    max_depth: f64,
}

/// Reads `rig/depth_cameras.toml` (the cameras of rig/cameras.toml plus `depth_scale`,
/// `min_depth`, `max_depth` in the session's length unit).
pub fn read_depth_cameras_toml(path: &Path, metres_per_unit: f64) -> Result<Vec<DepthCamera>> {
    let raw: RawDepthCameras = parse_toml(path)?;
    let mut out: Vec<DepthCamera> = Vec::new();
    for c in &raw.camera {
        let camera = raw_camera(&c.camera, path, metres_per_unit)?;
        let bad = |message: &str| CaptureError::Camera {
            path: path.to_path_buf(),
            camera: c.camera.id.clone(),
            message: message.into(),
        };
        if out.iter().any(|o| o.camera.id == camera.id) {
            return Err(bad("duplicate id"));
        }
        if !(c.depth_scale > 0.0 && c.depth_scale.is_finite()) {
            return Err(bad("depth_scale must be positive"));
        }
        if !(c.min_depth >= 0.0 && c.max_depth > c.min_depth && c.max_depth.is_finite()) {
            return Err(bad("need 0 ≤ min_depth < max_depth"));
        }
        out.push(DepthCamera {
            camera,
            depth_scale_m: c.depth_scale * metres_per_unit,
            min_depth_m: c.min_depth * metres_per_unit,
            max_depth_m: c.max_depth * metres_per_unit,
        });
    }
    if out.is_empty() {
        return Err(CaptureError::field(
            path,
            0,
            "camera",
            "no [[camera]] tables",
        ));
    }
    Ok(out)
}

/// Reads `support_motion.csv`: `frame,qw,qx,qy,qz,tx,ty,tz` (unit quaternion, length unit).
pub fn read_support_motion_csv(path: &Path, metres_per_unit: f64) -> Result<Vec<SupportMotion>> {
    let t = CsvTable::read(path)?;
    let cols: Vec<usize> = ["frame", "qw", "qx", "qy", "qz", "tx", "ty", "tz"]
        .iter()
        .map(|c| t.require(c))
        .collect::<Result<_>>()?;
    let mut out: Vec<SupportMotion> = Vec::with_capacity(t.rows.len());
    for row in &t.rows {
        let frame = t.usize_at(row, cols[0], "frame")?;
        let v: Vec<f64> = ["qw", "qx", "qy", "qz", "tx", "ty", "tz"]
            .iter()
            .zip(&cols[1..])
            .map(|(name, &c)| t.f64_at(row, c, name))
            .collect::<Result<_>>()?;
        let q = nalgebra::Quaternion::new(v[0], v[1], v[2], v[3]);
        if (q.norm() - 1.0).abs() > 1e-6 {
            return Err(CaptureError::field(
                path,
                row.0,
                "qw",
                format!("quaternion is not unit (norm {:.9})", q.norm()),
            ));
        }
        if out.last().is_some_and(|p| p.frame >= frame) {
            return Err(CaptureError::field(
                path,
                row.0,
                "frame",
                "frames must increase",
            ));
        }
        out.push(SupportMotion {
            frame,
            rotation: UnitQuaternion::new_normalize(q),
            translation_m: Vector3::new(v[4], v[5], v[6]) * metres_per_unit,
        });
    }
    Ok(out)
}

/// Reads `interactions.csv`: `t_start_s,t_end_s` with start ≤ end.
pub fn read_interactions_csv(path: &Path) -> Result<Vec<(f64, f64)>> {
    let t = CsvTable::read(path)?;
    let (a, b) = (t.require("t_start_s")?, t.require("t_end_s")?);
    let mut out = Vec::with_capacity(t.rows.len());
    for row in &t.rows {
        let (s, e) = (t.f64_at(row, a, "t_start_s")?, t.f64_at(row, b, "t_end_s")?);
        if e < s {
            return Err(CaptureError::field(
                path,
                row.0,
                "t_end_s",
                "ends before it starts",
            ));
        }
        out.push((s, e));
    }
    Ok(out)
}

/// Reads a `[support] nodes_file`: one `node` column of 0-based node indices.
pub fn read_support_nodes_csv(path: &Path) -> Result<Vec<usize>> {
    let t = CsvTable::read(path)?;
    let c = t.require("node")?;
    let mut out: Vec<usize> = t
        .rows
        .iter()
        .map(|row| t.usize_at(row, c, "node"))
        .collect::<Result<_>>()?;
    out.sort_unstable();
    out.dedup();
    if out.is_empty() {
        return Err(CaptureError::field(path, 2, "node", "no nodes"));
    }
    Ok(out)
}

/// The dynamic branch of `Session::load`: volume mesh, trigger, density and one of depth / points
/// are required.
pub(crate) fn load_dynamic(m: DynamicManifest<'_>, f: RawFiles) -> Result<Session> {
    let dir = m.dir;
    let required = |p: &Option<String>, field: &str| -> Result<PathBuf> {
        let rel = p.as_ref().ok_or_else(|| {
            CaptureError::field(m.manifest, 0, field, "required for kind dynamic")
        })?;
        existing(dir.join(rel), field)
    };
    let volume = required(&f.volume, "files.volume")?;
    let trigger_path = required(&f.trigger, "files.trigger")?;
    let trigger = read_trigger_csv(&trigger_path)?;
    let density = m.density_kg_m3.ok_or_else(|| {
        CaptureError::field(
            m.manifest,
            0,
            "object.density_kg_m3",
            "required for kind dynamic",
        )
    })?;
    let source = match (&f.depth, &f.points) {
        (Some(depth), _) => {
            let cameras_path = required(&f.depth_cameras, "files.depth_cameras")?;
            CloudSource::Depth {
                dir: existing(dir.join(depth), "files.depth")?,
                cameras: read_depth_cameras_toml(&cameras_path, m.metres_per_unit)?,
                cameras_path,
            }
        }
        (None, Some(points)) => CloudSource::Points {
            dir: existing(dir.join(points), "files.points")?,
        },
        (None, None) => {
            return Err(CaptureError::field(
                m.manifest,
                0,
                "files.depth",
                "one of depth / points is required for kind dynamic",
            ));
        }
    };
    let mut files = vec![trigger_path, volume.clone()];
    let support_nodes = match &m.support_nodes_file {
        Some(p) => {
            let p = existing(p.clone(), "support.nodes_file")?;
            files.push(p.clone());
            Some(read_support_nodes_csv(&p)?)
        }
        None => None,
    };
    let support_motion = match &f.support_motion {
        Some(rel) => {
            let p = existing(dir.join(rel), "files.support_motion")?;
            files.push(p.clone());
            Some(read_support_motion_csv(&p, m.metres_per_unit)?)
        }
        None => None,
    };
    let interactions = match &f.interactions {
        Some(rel) => {
            let p = existing(dir.join(rel), "files.interactions")?;
            files.push(p.clone());
            read_interactions_csv(&p)?
        }
        None => Vec::new(),
    };
    let surface = f
        .surface
        .as_ref()
        .map(|p| dir.join(p))
        .filter(|p| p.exists());
    Ok(Session {
        root: dir.to_path_buf(),
        name: m.name,
        kind: SessionKind::Dynamic,
        metres_per_unit: m.metres_per_unit,
        cameras: Vec::new(),
        cameras_path: None,
        markers: Vec::new(),
        images: None,
        detections: None,
        c3d: None,
        trigger,
        fsr: None,
        fsr_samples: None,
        probe: None,
        robot: None,
        surface,
        volume: Some(volume),
        gravity: m.gravity,
        support: m.support.flatten(),
        density_kg_m3: Some(density),
        dynamic: Some(DynamicInputs {
            source,
            support_nodes,
            support_motion,
            interactions,
            files,
        }),
    })
}

fn existing(p: PathBuf, field: &str) -> Result<PathBuf> {
    if p.exists() {
        Ok(p)
    } else {
        Err(CaptureError::Io {
            path: p,
            source: std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("named by session.toml {field}"),
            ),
        })
    }
}

/// Settings of the dynamic capture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthCaptureSettings {
    /// Voxel size of the downsampling, m (0 = keep every point).
    pub voxel_size_m: f64,
    /// Neighbouring readings further apart in depth than this × depth are across a depth jump
    /// (not used for the normal).
    pub depth_jump_rel: f64,
}

impl Default for DepthCaptureSettings {
    fn default() -> Self {
        Self {
            voxel_size_m: 0.0,
            depth_jump_rel: 0.02,
        }
    }
}

/// One frame's fused cloud.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CloudFrame {
    /// Frame index.
    pub frame: usize,
    /// Exposure time, camera clock, s.
    pub t_camera_s: f64,
    /// Points, m, world frame.
    pub points_m: Vec<Vector3<f32>>,
    /// Unit normals towards the camera (empty for PLY input).
    pub normals: Vec<Vector3<f32>>,
    /// Camera index per point (empty for PLY input).
    pub camera: Vec<u32>,
    /// Support motion of the frame, if the session has one.
    pub support_motion: Option<SupportMotion>,
}

/// The whole dynamic capture.
#[derive(Debug, Clone, PartialEq)]
pub struct DynamicCapture {
    /// Session name.
    pub session: String,
    /// One cloud per trigger frame.
    pub frames: Vec<CloudFrame>,
    /// Depth cameras (empty for PLY input).
    pub cameras: Vec<DepthCamera>,
    /// Points per camera over all frames (before downsampling).
    pub points_per_camera: Vec<usize>,
}

/// Depth images (or PLY clouds) → one fused world-frame cloud per trigger frame. Every input is
/// checked before anything is returned: a missing frame, an 8-bit or colour PNG, or an image
/// whose size disagrees with its camera is an error naming the file.
pub fn capture_dynamic(
    session: &Session,
    settings: &DepthCaptureSettings,
) -> Result<DynamicCapture> {
    let manifest = session.root.join("session.toml");
    let inputs = session
        .dynamic
        .as_ref()
        .ok_or_else(|| CaptureError::field(&manifest, 0, "kind", "not a dynamic session"))?;
    if !(settings.voxel_size_m >= 0.0 && settings.voxel_size_m.is_finite()) {
        return Err(CaptureError::field(
            &manifest,
            0,
            "voxel_size_m",
            "must be ≥ 0 and finite",
        ));
    }
    let motion_of = |frame: usize| -> Result<Option<SupportMotion>> {
        let Some(list) = &inputs.support_motion else {
            return Ok(None);
        };
        list.iter()
            .find(|m| m.frame == frame)
            .copied()
            .map(Some)
            .ok_or_else(|| {
                CaptureError::field(
                    &session.root.join("support_motion.csv"),
                    0,
                    "frame",
                    format!("no row for frame {frame} of trigger.csv"),
                )
            })
    };
    let mut out = DynamicCapture {
        session: session.name.clone(),
        frames: Vec::with_capacity(session.trigger.len()),
        cameras: Vec::new(),
        points_per_camera: Vec::new(),
    };
    match &inputs.source {
        CloudSource::Depth { dir, cameras, .. } => {
            out.cameras = cameras.clone();
            out.points_per_camera = vec![0; cameras.len()];
            let pixels: Vec<Vec<nalgebra::Vector2<f64>>> =
                cameras.iter().map(normalized_pixels).collect();
            for &(frame, t) in &session.trigger {
                let mut cloud = CloudFrame {
                    frame,
                    t_camera_s: t,
                    support_motion: motion_of(frame)?,
                    ..Default::default()
                };
                for (c, cam) in cameras.iter().enumerate() {
                    let path = dir.join(&cam.camera.id).join(format!("{frame:06}.png"));
                    let counts = read_depth_png(&path, &cam.camera)?;
                    let before = cloud.points_m.len();
                    back_project(cam, &pixels[c], &counts, settings, c as u32, &mut cloud);
                    out.points_per_camera[c] += cloud.points_m.len() - before;
                }
                out.frames
                    .push(voxel_downsample(cloud, settings.voxel_size_m));
            }
        }
        CloudSource::Points { dir } => {
            for &(frame, t) in &session.trigger {
                let path = dir.join(format!("{frame:06}.ply"));
                let ply = softcap_mesh::read_ply(&path).map_err(|e| CaptureError::Format {
                    path: path.clone(),
                    message: e.to_string(),
                })?;
                let cloud = CloudFrame {
                    frame,
                    t_camera_s: t,
                    points_m: ply
                        .vertices
                        .iter()
                        .map(|p| (p * session.metres_per_unit).cast::<f32>())
                        .collect(),
                    support_motion: motion_of(frame)?,
                    ..Default::default()
                };
                if cloud
                    .points_m
                    .iter()
                    .any(|p| !p.iter().all(|v| v.is_finite()))
                {
                    return Err(CaptureError::Format {
                        path,
                        message: "non-finite point coordinate".into(),
                    });
                }
                out.frames
                    .push(voxel_downsample(cloud, settings.voxel_size_m));
            }
        }
    }
    Ok(out)
}

/// Undistorted normalized coordinates of every pixel (row-major), computed once per camera.
fn normalized_pixels(cam: &DepthCamera) -> Vec<nalgebra::Vector2<f64>> {
    let c = &cam.camera;
    (0..c.height)
        .flat_map(|v| (0..c.width).map(move |u| (u, v)))
        .map(|(u, v)| c.undistort(u as f64, v as f64))
        .collect()
}

/// Largest depth image softcap decodes, pixels (4096 × 4096; a Kinect-class sensor is 640 × 576).
pub const MAX_DEPTH_PIXELS: u64 = 4096 * 4096;

/// Decodes a depth image: 16-bit grayscale of the camera's size, else an error naming the file.
pub fn read_depth_png(path: &Path, camera: &Camera) -> Result<Vec<u16>> {
    let bad = |message: String| CaptureError::Image {
        path: path.to_path_buf(),
        message,
    };
    if !path.exists() {
        return Err(CaptureError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "depth image of a trigger.csv frame is missing",
            ),
        });
    }
    // The header is read first: size and pixel type are checked against the camera and the
    // documented limit before the pixels are allocated and inflated.
    let file = std::fs::File::open(path).map_err(|source| CaptureError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let decoder = image::codecs::png::PngDecoder::new(std::io::BufReader::new(file))
        .map_err(|e| bad(format!("cannot decode: {e}")))?;
    let (width, height) = image::ImageDecoder::dimensions(&decoder);
    let color = image::ImageDecoder::color_type(&decoder);
    if u64::from(width) * u64::from(height) > MAX_DEPTH_PIXELS {
        return Err(bad(format!(
            "image is {width}×{height} px, more than the {MAX_DEPTH_PIXELS} pixels softcap reads"
        )));
    }
    if width != camera.width || height != camera.height {
        return Err(bad(format!(
            "image is {width}×{height} px but camera `{}` is {}×{}",
            camera.id, camera.width, camera.height
        )));
    }
    if color != image::ColorType::L16 {
        return Err(bad(format!(
            "expected a 16-bit grayscale depth PNG, got {color:?}"
        )));
    }
    let img = image::DynamicImage::from_decoder(decoder)
        .map_err(|e| bad(format!("cannot decode: {e}")))?;
    let image::DynamicImage::ImageLuma16(buf) = img else {
        return Err(bad(format!(
            "expected a 16-bit grayscale depth PNG, got {:?}",
            img.color()
        )));
    };
    Ok(buf.into_raw())
}

/// Back-projects the valid pixels of one depth image into `cloud` (points with a normal only).
fn back_project(
    cam: &DepthCamera,
    normalized: &[nalgebra::Vector2<f64>],
    counts: &[u16],
    settings: &DepthCaptureSettings,
    camera_index: u32,
    cloud: &mut CloudFrame,
) {
    let (w, h) = (cam.camera.width as usize, cam.camera.height as usize);
    let z: Vec<f64> = counts
        .iter()
        .map(|&c| {
            let z = f64::from(c) * cam.depth_scale_m;
            if c > 0 && z >= cam.min_depth_m && z <= cam.max_depth_m {
                z
            } else {
                0.0
            }
        })
        .collect();
    // camera-frame point of pixel i
    let p = |i: usize| {
        let n = normalized[i];
        Vector3::new(n.x, n.y, 1.0) * z[i]
    };
    let near =
        |i: usize, j: usize| z[j] > 0.0 && (z[j] - z[i]).abs() <= settings.depth_jump_rel * z[i];
    let centre = cam.camera.centre_world().coords;
    for v in 0..h {
        for u in 0..w {
            let i = v * w + u;
            if z[i] <= 0.0 {
                continue;
            }
            let du = difference(
                i,
                (u > 0).then(|| i - 1),
                (u + 1 < w).then(|| i + 1),
                &near,
                &p,
            );
            let dv = difference(
                i,
                (v > 0).then(|| i - w),
                (v + 1 < h).then(|| i + w),
                &near,
                &p,
            );
            let (Some(du), Some(dv)) = (du, dv) else {
                continue;
            };
            let nc = du.cross(&dv);
            let len = nc.norm();
            if len <= 0.0 || len.is_nan() {
                continue;
            }
            let x = cam.camera.to_world(&p(i)).coords;
            let mut n = cam.camera.rotation.transpose() * (nc / len);
            if n.dot(&(centre - x)) < 0.0 {
                n = -n;
            }
            cloud.points_m.push(x.cast::<f32>());
            cloud.normals.push(n.cast::<f32>());
            cloud.camera.push(camera_index);
        }
    }
}

/// Central difference P(next) − P(prev) along one image axis, one-sided where a neighbour is
/// missing or across a depth jump; `None` if neither neighbour is usable.
fn difference(
    i: usize,
    prev: Option<usize>,
    next: Option<usize>,
    near: &impl Fn(usize, usize) -> bool,
    p: &impl Fn(usize) -> Vector3<f64>,
) -> Option<Vector3<f64>> {
    let prev = prev.filter(|&j| near(i, j));
    let next = next.filter(|&j| near(i, j));
    match (prev, next) {
        (Some(a), Some(b)) => Some(p(b) - p(a)),
        (None, Some(b)) => Some(p(b) - p(i)),
        (Some(a), None) => Some(p(i) - p(a)),
        (None, None) => None,
    }
}

/// Centroid (and renormalized mean normal) per voxel of size `voxel_m`, voxels in lexicographic
/// order of their integer coordinates; the camera index of a voxel is its first point's.
pub fn voxel_downsample(cloud: CloudFrame, voxel_m: f64) -> CloudFrame {
    if voxel_m <= 0.0 || cloud.points_m.is_empty() {
        return cloud;
    }
    let with_normals = cloud.normals.len() == cloud.points_m.len();
    let with_camera = cloud.camera.len() == cloud.points_m.len();
    let mut cells: BTreeMap<[i64; 3], (Vector3<f64>, Vector3<f64>, usize, u32)> = BTreeMap::new();
    for (k, p) in cloud.points_m.iter().enumerate() {
        let key = [0, 1, 2].map(|a| (f64::from(p[a]) / voxel_m).floor() as i64);
        let e = cells.entry(key).or_insert((
            Vector3::zeros(),
            Vector3::zeros(),
            0,
            if with_camera { cloud.camera[k] } else { 0 },
        ));
        e.0 += p.cast::<f64>();
        if with_normals {
            e.1 += cloud.normals[k].cast::<f64>();
        }
        e.2 += 1;
    }
    let mut out = CloudFrame {
        frame: cloud.frame,
        t_camera_s: cloud.t_camera_s,
        support_motion: cloud.support_motion,
        ..Default::default()
    };
    for (sum, nsum, count, cam) in cells.into_values() {
        out.points_m.push((sum / count as f64).cast::<f32>());
        if with_normals {
            let n = nsum.try_normalize(1e-12).unwrap_or_else(Vector3::z);
            out.normals.push(n.cast::<f32>());
        }
        if with_camera {
            out.camera.push(cam);
        }
    }
    out
}
