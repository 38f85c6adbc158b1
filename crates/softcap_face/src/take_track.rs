//! `softcap face track`: a face take → tracked wrinkles on the animated face (`wrinkles.mcap`).
//!
//! Per camera: decode every frame, track the labelled wrinkles through them ([`track_video`],
//! thesis §4.3), and cast each visible wrinkle's cross-sections through the camera onto the face
//! animated by the take's mocap (thesis §3.3.1, [`project_wrinkle`]); the camera is expressed in
//! face coordinates by the rigid map of the neutral markers onto their landmark vertices
//! ([`face_from_mocap`](crate::take_synth::face_from_mocap)). The MCAP holds `/face/track/cameras` (static) and
//! `/face/track/wrinkles` (one message per camera and frame; pixel coordinates of the
//! distortion-free image, equal to the image's own for a camera without distortion);
//! `softcap face run --wrinkles` synthesizes from it.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use softcap_mcap::{Provenance, Writer, proto, topics};

use crate::animate::FaceAnimator;
use crate::error::{FaceError, Result};
use crate::image::RgbImage;
use crate::output::{FrameWrinkles, WrinkleInput};
use crate::synth::{PinholeCamera, ProjectedWrinkle, WrinkleCurve, WrinkleSample, project_wrinkle};
use crate::take::{Take, face_camera, ideal_pixel, read_png};
use crate::video::{FrameWrinkle, VideoTrackSettings, WrinkleStatus, smooth_profiles, track_video};

/// One camera's track of a take.
#[derive(Clone, Debug)]
pub struct CameraTrack {
    /// Camera id.
    pub id: String,
    /// The camera in face coordinates (scan units).
    pub camera: PinholeCamera,
    /// The camera as calibrated (mocap frame, with distortion).
    pub raw: softcap_core::Camera,
    /// `frames[t]`: every labelled wrinkle at frame t.
    pub frames: Vec<Vec<FrameWrinkle>>,
    /// `projected[t][k]`: wrinkle k of frame t on the animated face (visible wrinkles only).
    pub projected: Vec<Vec<Option<ProjectedWrinkle>>>,
}

/// The image-space wrinkle of a tracked wrinkle, in distortion-free pixels of `cam`.
fn ideal_curve(fw: &FrameWrinkle, cam: &softcap_core::Camera) -> Option<WrinkleCurve> {
    let t = fw.tracked.as_ref()?;
    Some(WrinkleCurve {
        samples: t
            .sections
            .iter()
            .filter(|s| s.converged)
            .map(|s| WrinkleSample {
                valley_px: ideal_pixel(cam, s.valley_px),
                depth_px: s.depth_px,
                width_px: s.width_px,
            })
            .collect(),
    })
}

/// Track every camera of `take` (module docs). `progress` is called once per camera frame.
pub fn track_take(
    take: &Take,
    animator: &FaceAnimator,
    face_from_mocap: &Isometry3<f64>,
    settings: &VideoTrackSettings,
    progress: &(dyn Fn() + Sync),
) -> Result<Vec<CameraTrack>> {
    let n = take.n_frames();
    // decode everything first: a bad image is reported before any work
    let mut decoded: Vec<(Vec<bool>, Vec<RgbImage>)> = Vec::new();
    for cam in &take.cameras {
        let (w, h) = (cam.camera.width, cam.camera.height);
        let label = read_png(&cam.label, w, h)?;
        let mask: Vec<bool> = label
            .data
            .iter()
            .map(|p| p.iter().sum::<f64>() > 1.5)
            .collect();
        if !mask.iter().any(|&m| m) {
            return Err(FaceError::Take {
                path: cam.label.clone(),
                reason: "no paint pixels (white) in the label".into(),
            });
        }
        let frames = cam
            .frames
            .iter()
            .map(|p| read_png(p, w, h))
            .collect::<Result<Vec<_>>>()?;
        decoded.push((mask, frames));
    }
    let verts: Vec<Vec<Vector3<f64>>> = (0..n)
        .map(|t| animator.frame(&take.mocap.positions_cm[t]))
        .collect::<Result<_>>()?;
    // every camera's wrinkles, then their (d, w) smoothed in time with one process noise per
    // wrinkle estimated from all cameras
    let per_camera = VideoTrackSettings {
        smooth_in_time: false,
        ..*settings
    };
    let mut tracked: Vec<Vec<Vec<FrameWrinkle>>> = take
        .cameras
        .iter()
        .zip(&decoded)
        .map(|(_, (mask, frames))| track_video(mask, frames, &per_camera, progress))
        .collect::<Result<_>>()?;
    if settings.smooth_in_time {
        smooth_profiles(
            &mut tracked.iter_mut().collect::<Vec<_>>(),
            settings.drift_per_frame,
        );
    }
    let mut out = Vec::new();
    for (cam, tracked) in take.cameras.iter().zip(tracked) {
        let pin = face_camera(&cam.camera, face_from_mocap);
        let projected = tracked
            .iter()
            .zip(&verts)
            .map(|(row, v)| {
                row.iter()
                    .map(|fw| {
                        if fw.status != WrinkleStatus::Visible {
                            return None;
                        }
                        let curve = ideal_curve(fw, &cam.camera)?;
                        Some(project_wrinkle(v, &animator.mesh.triangles, &pin, &curve))
                    })
                    .collect()
            })
            .collect();
        out.push(CameraTrack {
            id: cam.camera.id.clone(),
            camera: pin,
            raw: cam.camera.clone(),
            frames: tracked,
            projected,
        });
    }
    Ok(out)
}

fn mcap_err(e: softcap_mcap::Error) -> FaceError {
    FaceError::Output(e.to_string())
}

fn vec3(v: &Vector3<f64>, k: f64) -> proto::Vec3 {
    proto::Vec3 {
        x: v.x * k,
        y: v.y * k,
        z: v.z * k,
    }
}

/// The `softcap.TrackedWrinkle` of one wrinkle in one frame.
fn tracked_message(
    raw: &softcap_core::Camera,
    fw: &FrameWrinkle,
    projected: Option<&ProjectedWrinkle>,
    k: f64,
) -> proto::TrackedWrinkle {
    let mut msg = proto::TrackedWrinkle {
        id: fw.id as u32,
        status: fw.status.name().into(),
        patch_px: fw.patch_px as u32,
        ..Default::default()
    };
    let Some(t) = &fw.tracked else {
        return msg;
    };
    if let Some(p) = &t.profile {
        msg.depth_px = p.depth_px;
        msg.width_px = p.width_px;
        // (NaN when JᵀJ was singular: written as 0, "unknown")
        let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
        msg.depth_sigma_px = finite(p.depth_sigma_px);
        msg.width_sigma_px = finite(p.width_sigma_px);
    }
    let steps = ((t.spline.x1 - t.spline.x0) / 2.0).ceil().max(1.0) as usize;
    for i in 0..=steps {
        let x = t.spline.x0 + (t.spline.x1 - t.spline.x0) * i as f64 / steps as f64;
        let v = t.spline.eval(x);
        let v = ideal_pixel(raw, [v.x, v.y]);
        msg.spline_u_px.push(v[0]);
        msg.spline_v_px.push(v[1]);
    }
    // the projection holds the converged sections, all of them when every ray hit the face
    let converged: Vec<_> = t.sections.iter().filter(|s| s.converged).collect();
    let proj = projected.filter(|p| p.points.len() == converged.len());
    let mut j = 0;
    for s in &t.sections {
        let q = if s.converged {
            j += 1;
            proj.map(|p| (p, j - 1))
        } else {
            None
        };
        let v = ideal_pixel(raw, s.valley_px);
        msg.sections.push(proto::WrinkleSection {
            valley_u_px: v[0],
            valley_v_px: v[1],
            depth_px: s.depth_px,
            width_px: s.width_px,
            depth_m: q.map_or(0.0, |(p, i)| p.depth[i] * k),
            width_m: q.map_or(0.0, |(p, i)| p.width[i] * k),
            valley_m: q.map(|(p, i)| vec3(&p.points[i], k)),
        });
        msg.converged.push(s.converged);
    }
    msg
}

/// The `softcap.FaceCamera` of a track.
fn camera_message(c: &CameraTrack, k: f64) -> proto::FaceCamera {
    let r = c
        .camera
        .world_from_camera
        .rotation
        .to_rotation_matrix()
        .into_inner();
    proto::FaceCamera {
        id: c.id.clone(),
        focal_px: c.camera.focal_px,
        cx_px: c.camera.principal_px[0],
        cy_px: c.camera.principal_px[1],
        position_m: Some(vec3(&c.camera.world_from_camera.translation.vector, k)),
        rotation: (0..9).map(|i| r[(i / 3, i % 3)]).collect(),
        width_px: c.raw.width,
        height_px: c.raw.height,
        metres_per_unit: k,
    }
}

/// Write `wrinkles.mcap` (module docs) atomically. Frame t is at the mocap time of take frame t
/// (relative to the take's first frame).
pub fn write_track_mcap(
    path: &Path,
    provenance: &Provenance,
    take: &Take,
    tracks: &[CameraTrack],
    metres_per_unit: f64,
) -> Result<PathBuf> {
    let k = metres_per_unit;
    let mut w = Writer::create(path, provenance).map_err(mcap_err)?;
    let cams = proto::FaceCameras {
        cameras: tracks.iter().map(|c| camera_message(c, k)).collect(),
    };
    w.write_static(&topics::FACE_TRACK_CAMERAS, &cams)
        .map_err(mcap_err)?;
    let t0 = take.mocap.times_s.first().copied().unwrap_or(0.0);
    for t in 0..take.n_frames() {
        let t_ns = ((take.mocap.times_s[t] - t0).max(0.0) * 1e9).round() as u64;
        for c in tracks {
            let msg = proto::WrinkleTrackFrame {
                camera: c.id.clone(),
                frame: t as u64,
                mocap_frame: take.mocap.frames[t],
                wrinkles: c.frames[t]
                    .iter()
                    .zip(&c.projected[t])
                    .map(|(fw, p)| tracked_message(&c.raw, fw, p.as_ref(), k))
                    .collect(),
            };
            w.write(&topics::FACE_TRACK_WRINKLES, t_ns, &msg)
                .map_err(mcap_err)?;
        }
    }
    w.finish().map_err(mcap_err)
}

/// The wrinkle input of `softcap face run` from a `wrinkles.mcap`: per camera, its face-frame
/// camera and the visible wrinkles of every frame (converged sections, image space), keyed by
/// mocap frame number. `metres_per_unit` must be the one the track was written with.
pub fn read_track_mcap(path: &Path, metres_per_unit: f64) -> Result<Vec<WrinkleInput>> {
    let bad = |reason: String| FaceError::Take {
        path: path.to_path_buf(),
        reason,
    };
    let r = softcap_mcap::reader::Recording::open(path).map_err(|e| bad(e.to_string()))?;
    let cams = r
        .read_static(&topics::FACE_TRACK_CAMERAS)
        .map_err(|e| bad(e.to_string()))?;
    let frames = r
        .read(&topics::FACE_TRACK_WRINKLES)
        .map_err(|e| bad(e.to_string()))?;
    let mut out = Vec::new();
    for c in &cams.cameras {
        if (c.metres_per_unit - metres_per_unit).abs() > 1e-12 * metres_per_unit.abs() {
            return Err(bad(format!(
                "camera `{}` was tracked with {} m per scan unit, run uses --metres-per-unit {metres_per_unit}",
                c.id, c.metres_per_unit
            )));
        }
        if c.rotation.len() != 9 {
            return Err(bad(format!(
                "camera `{}`: rotation has {} entries",
                c.id,
                c.rotation.len()
            )));
        }
        let rot = Matrix3::from_row_slice(&c.rotation);
        let pos = c.position_m.unwrap_or_default();
        let k = 1.0 / metres_per_unit;
        let camera = PinholeCamera {
            world_from_camera: Isometry3::from_parts(
                Translation3::new(pos.x * k, pos.y * k, pos.z * k),
                UnitQuaternion::from_matrix(&rot),
            ),
            focal_px: c.focal_px,
            principal_px: [c.cx_px, c.cy_px],
        };
        let mut input = WrinkleInput {
            camera: Some(camera),
            frames: Vec::new(),
        };
        for (_, f) in frames.iter().filter(|(_, f)| f.camera == c.id) {
            let wrinkles = f
                .wrinkles
                .iter()
                .filter(|w| w.status == WrinkleStatus::Visible.name())
                .map(|w| WrinkleCurve {
                    samples: w
                        .sections
                        .iter()
                        .zip(&w.converged)
                        .filter(|(_, ok)| **ok)
                        .map(|(s, _)| WrinkleSample {
                            valley_px: [s.valley_u_px, s.valley_v_px],
                            depth_px: s.depth_px,
                            width_px: s.width_px,
                        })
                        .collect(),
                })
                .collect();
            input.frames.push(FrameWrinkles {
                frame: f.mocap_frame,
                wrinkles,
            });
        }
        input
            .validate()
            .map_err(|e| bad(format!("camera `{}`: {e}", c.id)))?;
        out.push(input);
    }
    Ok(out)
}
