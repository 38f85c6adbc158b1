//! A face take on disk (`docs/face.md`, "Face takes"): the input of `softcap face track`.
//!
//! ```text
//! TAKE/cameras.toml              [[camera]] tables (SESSION_FORMAT.md rig/cameras.toml), mocap frame,
//!                                translations in cm (the mocap's unit)
//! TAKE/mocap.csv                 AnimFace CSV of the take's markers (or TAKE/capture.mcap, /capture/markers)
//! TAKE/frames/<camera>/<frame>.png   one image per frame, <frame> = 000000, 000001, … (8- or 16-bit, sRGB)
//! TAKE/labels/<camera>.png       the paint mask of frame 0 (white = wrinkle paint): the SVM's training label
//! ```
//!
//! Take frame k is the k-th frame of the mocap take. Every error names the file and what is
//! wrong; nothing is decoded twice.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde::Deserialize;
use softcap_core::{Camera, CameraTable};

use crate::error::{FaceError, Result};
use crate::image::RgbImage;
use crate::mocap::{MocapTake, read_animface_csv};
use crate::synth::PinholeCamera;

/// One camera of a take.
#[derive(Clone, Debug)]
pub struct TakeCamera {
    /// The calibration (mocap frame, metres).
    pub camera: Camera,
    /// Frame images, in frame order.
    pub frames: Vec<PathBuf>,
    /// Training label of frame 0.
    pub label: PathBuf,
}

/// A face take: cameras with their frames and the mocap of the same take.
#[derive(Clone, Debug)]
pub struct Take {
    /// The take directory.
    pub dir: PathBuf,
    /// Cameras in cameras.toml order.
    pub cameras: Vec<TakeCamera>,
    /// The mocap take (its first `frames` frames are the take's).
    pub mocap: MocapTake,
    /// The mocap file.
    pub mocap_path: PathBuf,
}

impl Take {
    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.cameras.first().map_or(0, |c| c.frames.len())
    }
}

fn take_err(path: &Path, reason: impl Into<String>) -> FaceError {
    FaceError::Take {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

#[derive(Deserialize)]
struct RawCameras {
    camera: Vec<CameraTable>,
}

/// Read `cameras.toml` (SESSION_FORMAT.md; translations in cm).
pub fn read_take_cameras(path: &Path) -> Result<Vec<Camera>> {
    let text = std::fs::read_to_string(path).map_err(|e| FaceError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    let raw: RawCameras = toml::from_str(&text).map_err(|e| take_err(path, e.to_string()))?;
    let mut out: Vec<Camera> = Vec::new();
    for c in raw.camera {
        if out.iter().any(|o| o.id == c.id) {
            return Err(take_err(path, format!("camera `{}` appears twice", c.id)));
        }
        let cam = c
            .to_camera(0.01)
            .map_err(|e| take_err(path, format!("camera `{}`: {e}", c.id)))?;
        out.push(cam);
    }
    if out.is_empty() {
        return Err(take_err(path, "no [[camera]] tables"));
    }
    Ok(out)
}

/// The frame images of one camera directory: `000000.png`, `000001.png`, … with no gap.
fn frame_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| FaceError::Io {
        path: dir.to_path_buf(),
        source: e,
    })?;
    let mut numbered = Vec::new();
    for e in entries {
        let e = e.map_err(|e| FaceError::Io {
            path: dir.to_path_buf(),
            source: e,
        })?;
        let p = e.path();
        if p.extension().and_then(|x| x.to_str()) != Some("png") {
            continue;
        }
        let stem = p.file_stem().and_then(|s| s.to_str()).unwrap_or_default();
        let Ok(k) = stem.parse::<usize>() else {
            return Err(take_err(
                &p,
                "frame images are named <frame>.png, e.g. 000000.png",
            ));
        };
        numbered.push((k, p));
    }
    numbered.sort();
    for (i, (k, _)) in numbered.iter().enumerate() {
        if *k != i {
            return Err(take_err(
                &dir.join(format!("{i:06}.png")),
                format!(
                    "missing frame {i} (frames must be numbered 0, 1, 2, … without gaps; next is {k})"
                ),
            ));
        }
    }
    if numbered.is_empty() {
        return Err(take_err(dir, "no frame images (<frame>.png)"));
    }
    Ok(numbered.into_iter().map(|(_, p)| p).collect())
}

/// Read and check a take directory's layout (module docs): every frames/ directory has a
/// calibrated camera, every calibrated camera has frames and a label, all cameras have the same
/// frames without gaps, and the mocap covers them.
pub fn read_take(dir: &Path) -> Result<Take> {
    let cameras_path = dir.join("cameras.toml");
    if !cameras_path.is_file() {
        return Err(take_err(
            &cameras_path,
            "missing (the take's camera calibration)",
        ));
    }
    let cams = read_take_cameras(&cameras_path)?;
    let frames_dir = dir.join("frames");
    let listing = std::fs::read_dir(&frames_dir).map_err(|e| FaceError::Io {
        path: frames_dir.clone(),
        source: e,
    })?;
    let mut subdirs: Vec<String> = Vec::new();
    for e in listing {
        let e = e.map_err(|e| FaceError::Io {
            path: frames_dir.clone(),
            source: e,
        })?;
        if e.path().is_dir() {
            subdirs.push(e.file_name().to_string_lossy().into_owned());
        }
    }
    subdirs.sort();
    if let Some(s) = subdirs.iter().find(|s| !cams.iter().any(|c| &c.id == *s)) {
        return Err(take_err(
            &frames_dir.join(s),
            format!(
                "camera `{s}` has no calibration in {}",
                cameras_path.display()
            ),
        ));
    }
    let mut cameras = Vec::new();
    for cam in cams {
        let d = frames_dir.join(&cam.id);
        if !d.is_dir() {
            return Err(take_err(
                &d,
                format!("missing: no frames of camera `{}`", cam.id),
            ));
        }
        let frames = frame_files(&d)?;
        let label = dir.join("labels").join(format!("{}.png", cam.id));
        if !label.is_file() {
            return Err(take_err(
                &label,
                "missing (the paint mask of frame 0 the classifier is trained on)",
            ));
        }
        cameras.push(TakeCamera {
            camera: cam,
            frames,
            label,
        });
    }
    let n = cameras[0].frames.len();
    for c in &cameras[1..] {
        if c.frames.len() != n {
            let (short, long) = if c.frames.len() < n {
                (c, &cameras[0])
            } else {
                (&cameras[0], c)
            };
            let k = short.frames.len();
            return Err(take_err(
                &frames_dir
                    .join(&short.camera.id)
                    .join(format!("{k:06}.png")),
                format!(
                    "missing frame {k} (camera `{}` has {} frames)",
                    long.camera.id,
                    long.frames.len()
                ),
            ));
        }
    }
    let mocap_path = dir.join("mocap.csv");
    if !mocap_path.is_file() {
        return Err(take_err(
            &mocap_path,
            "missing (the take's mocap markers, AnimFace CSV)",
        ));
    }
    let mocap = read_animface_csv(&mocap_path)?;
    if mocap.frames.len() < n {
        return Err(take_err(
            &mocap_path,
            format!("{} mocap frames for {n} image frames", mocap.frames.len()),
        ));
    }
    Ok(Take {
        dir: dir.to_path_buf(),
        cameras,
        mocap,
        mocap_path,
    })
}

/// sRGB-encoded value in [0, 1] → linear.
fn srgb_to_linear(s: f32) -> f64 {
    let s = f64::from(s);
    if s <= 0.040_45 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }
}

/// Decode a PNG (8- or 16-bit, gray or RGB, sRGB) to a linear RGB image of the expected size.
pub fn read_png(path: &Path, width: u32, height: u32) -> Result<RgbImage> {
    let img = image::open(path).map_err(|e| take_err(path, e.to_string()))?;
    if img.width() != width || img.height() != height {
        return Err(take_err(
            path,
            format!(
                "{}×{} px, the camera is {width}×{height} px",
                img.width(),
                img.height()
            ),
        ));
    }
    let rgb = img.to_rgb32f();
    let mut out = RgbImage::new(width as usize, height as usize);
    for (px, p) in out.data.iter_mut().zip(rgb.pixels()) {
        *px = [
            srgb_to_linear(p.0[0]),
            srgb_to_linear(p.0[1]),
            srgb_to_linear(p.0[2]),
        ];
    }
    Ok(out)
}

/// The camera in face coordinates for wrinkle projection (thesis §3.3.1): `face_from_mocap` the
/// rigid map of the neutral markers onto their landmark vertices; the mocap and face are in cm.
/// The distortion is removed from pixels with [`ideal_pixel`] before projecting.
pub fn face_camera(cam: &Camera, face_from_mocap: &Isometry3<f64>) -> PinholeCamera {
    // camera ← mocap (cm): x_c = R x + 100 t
    let r = UnitQuaternion::from_matrix(&cam.rotation);
    let cam_from_mocap = Isometry3::from_parts(Translation3::from(cam.translation_m * 100.0), r);
    let [fx, fy, cx, cy] = cam.intrinsics;
    PinholeCamera {
        world_from_camera: face_from_mocap * cam_from_mocap.inverse(),
        focal_px: 0.5 * (fx + fy),
        principal_px: [cx, cy],
    }
}

/// Pixel (u, v) of `cam` as seen by the distortion-free pinhole of [`face_camera`] (focal
/// (fx + fy)/2): the identity for a camera without distortion and with fx = fy.
pub fn ideal_pixel(cam: &Camera, px: [f64; 2]) -> [f64; 2] {
    let [fx, fy, cx, cy] = cam.intrinsics;
    if cam.distortion.iter().all(|&k| k == 0.0) && fx == fy {
        return px;
    }
    let n = cam.undistort(px[0], px[1]);
    let f = 0.5 * (fx + fy);
    [f * n.x + cx, f * n.y + cy]
}
