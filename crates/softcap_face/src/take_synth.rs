//! A rendered face take with known wrinkles (`softcap face synth-take`): the test data of
//! `softcap face track`.
//!
//! The face scan is animated by a mocap take ([`FaceAnimator`], thesis §3.2); two pinhole cameras
//! look at the forehead along the face's −z. Two painted wrinkles live on the forehead, given in
//! centimetres relative to the forehead landmark vertex (`ForeHead_M`) of the animated face:
//!
//! - wrinkle 0: a 2.6 cm frown line, d = 0.75 mm, w = 1 mm, that slides along the skin and deepens
//!   and relaxes over the take; in camera 0 a strand of hair (an occluder in front of the skin)
//!   covers part of it during the middle of the take;
//! - wrinkle 1: a 2.2 cm line, d = 0.5 mm, w = 1.25 mm, that appears at 25 % of the take and
//!   disappears at 75 % (its depth ramps over [`TakeSynthSettings::ramp_frames`] frames; the paint
//!   is always there).
//!
//! With [`TakeMotion::Varying`] (`synth-take --motion varying`) the take is made differently:
//! both wrinkles change depth AND width over time at their own rates (wrinkle 0: d × 0.7–1.0 at
//! 1.3 cycles per 60 frames, w × 0.8–1.2 at 0.8 cycles; wrinkle 1: d × 0.75–1.25 at 2 cycles,
//! w × 0.7–1.3 at 1.7 cycles, up to 5 % per frame) and wrinkle 1 appears at 20 % and disappears
//! at 70 % of the take.
//!
//! Each camera's image of a frame is the Monte-Carlo ambient-occlusion render
//! ([`render_ambient_occlusion`]) of a [`CompositeScene`]: the wrinkles as height fields in the
//! image plane, placed at the projection of the animated anchor vertex and scaled by the camera's
//! pixel footprint f/Z at the anchor (the forehead patch is treated as fronto-parallel: the
//! cameras look straight at it). The truth (every camera's scene per frame) is written next to
//! the take as `truth.json`.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use softcap_mesh::TriMesh;
use softcap_mesh::shell::ShellSettings;

use crate::animate::FaceAnimator;
use crate::error::{FaceError, Result};
use crate::landmarks::{Landmark, rigid_fit};
use crate::mocap::MocapTake;
use crate::render::{
    AoRenderSettings, CompositeScene, Occluder, WrinkleScene, render_ambient_occlusion,
};
use crate::synth::PinholeCamera;

/// Settings of [`synth_take`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TakeSynthSettings {
    /// Frames (the first `frames` frames of the mocap take).
    pub frames: usize,
    /// Image columns.
    pub width_px: usize,
    /// Image rows.
    pub height_px: usize,
    /// Camera 0's pixels per centimetre at the forehead (camera 1 is 15 % farther away).
    pub px_per_cm: f64,
    /// Frames over which an appearing or disappearing wrinkle's depth ramps.
    pub ramp_frames: usize,
    /// Renderer settings (rays, noise, seed; each frame and camera derives its own seed).
    pub render: AoRenderSettings,
    /// How the wrinkles' depth and width change over the take.
    pub motion: TakeMotion,
}

/// How the wrinkles of a rendered take change over time (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum TakeMotion {
    /// Constant widths; wrinkle 0 deepens and relaxes, wrinkle 1 appears at 25 % and disappears
    /// at 75 % of the take.
    #[default]
    Steady,
    /// Depth and width of both wrinkles vary at different rates; wrinkle 1 appears at 20 % and
    /// disappears at 70 % of the take.
    Varying,
}

impl Default for TakeSynthSettings {
    fn default() -> Self {
        Self {
            frames: 60,
            width_px: 176,
            height_px: 120,
            px_per_cm: 40.0,
            ramp_frames: 3,
            render: AoRenderSettings {
                rays_per_axis: 12,
                ..Default::default()
            },
            motion: TakeMotion::Steady,
        }
    }
}

/// The known truth of a synthesized take: per camera, the rendered scene of every frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TakeTruth {
    /// Camera ids, in cameras.toml order.
    pub cameras: Vec<String>,
    /// `scenes[c][t]`: camera c's scene at frame t (wrinkle geometry in pixels).
    pub scenes: Vec<Vec<CompositeScene>>,
}

/// Marker whose landmark vertex anchors the wrinkles.
pub const ANCHOR_MARKER: &str = "ForeHead_M";

/// Wrinkle geometry on the forehead, centimetres relative to the anchor (x right, y up).
struct ForeheadWrinkle {
    /// Height of the valley's top point above the anchor.
    top_cm: f64,
    radius_cm: f64,
    length_cm: f64,
    depth_cm: f64,
    width_cm: f64,
}

const WRINKLES: [ForeheadWrinkle; 2] = [
    ForeheadWrinkle {
        top_cm: 0.6,
        radius_cm: 10.0,
        length_cm: 2.6,
        depth_cm: 0.075,
        width_cm: 0.1,
    },
    ForeheadWrinkle {
        top_cm: -0.55,
        radius_cm: 12.0,
        length_cm: 2.2,
        depth_cm: 0.05,
        width_cm: 0.125,
    },
];

/// Depth multiplier of wrinkle `k` at frame `t` of `n` for [`TakeMotion::Steady`]: wrinkle 0
/// deepens and relaxes (0.8–1.0), wrinkle 1 ramps in at n/4 and out at 3n/4 over `ramp` frames.
pub fn depth_factor(k: usize, t: usize, n: usize, ramp: usize) -> f64 {
    profile_factors(TakeMotion::Steady, k, t, n, ramp)[0]
}

/// (depth, width) multipliers of wrinkle `k` at frame `t` of `n` (module docs); an appearing or
/// disappearing wrinkle's depth ramps over `ramp` frames.
pub fn profile_factors(motion: TakeMotion, k: usize, t: usize, n: usize, ramp: usize) -> [f64; 2] {
    let cycles = |c: f64| std::f64::consts::TAU * c * t as f64 / n.max(1) as f64;
    // the varying take's rates are per 60 frames, so a shorter take is the start of the long one
    let per_60 = |c: f64| std::f64::consts::TAU * c * t as f64 / 60.0;
    let ramp_in_out = |on: usize, off: usize| {
        let r = ramp.max(1) as f64;
        let up = ((t as f64 - on as f64 + 1.0) / r).clamp(0.0, 1.0);
        let down = ((off as f64 - t as f64) / r).clamp(0.0, 1.0);
        up.min(down)
    };
    match (motion, k) {
        (TakeMotion::Steady, 0) => [0.9 - 0.1 * cycles(1.0).cos(), 1.0],
        (TakeMotion::Steady, _) => [ramp_in_out(n / 4, (3 * n) / 4), 1.0],
        (TakeMotion::Varying, 0) => [
            0.85 + 0.15 * per_60(1.3).sin(),
            1.0 + 0.2 * (per_60(0.8) + 1.0).sin(),
        ],
        (TakeMotion::Varying, _) => [
            ramp_in_out(n / 5, (7 * n) / 10) * (1.0 + 0.25 * per_60(2.0).sin()),
            1.0 + 0.3 * per_60(1.7).cos(),
        ],
    }
}

/// Slide of wrinkle `k` along the skin at frame `t` of `n` (cm, x right / y up).
fn slide_cm(k: usize, t: usize, n: usize) -> [f64; 2] {
    let phase = std::f64::consts::TAU * t as f64 / n.max(1) as f64;
    if k == 0 {
        [0.2 * phase.sin(), 0.06 * (2.0 * phase).sin()]
    } else {
        [-0.1 * phase.sin(), 0.0]
    }
}

/// The two cameras in face coordinates: camera 0 40 cm in front of the anchor, camera 1 46 cm in
/// front and 3 cm to the side, both looking along −z (OpenCV axes: x right, y down), principal
/// points placing the neutral anchor at the image centre.
fn face_cameras(
    anchor: &Vector3<f64>,
    settings: &TakeSynthSettings,
) -> [(String, PinholeCamera); 2] {
    let rot =
        UnitQuaternion::from_matrix(&Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0));
    let focal = settings.px_per_cm * 40.0;
    let centre = [
        (settings.width_px as f64 - 1.0) / 2.0,
        (settings.height_px as f64 - 1.0) / 2.0,
    ];
    let make = |offset: Vector3<f64>| {
        let pose = Isometry3::from_parts(Translation3::from(anchor + offset), rot);
        let mut cam = PinholeCamera {
            world_from_camera: pose,
            focal_px: focal,
            principal_px: [0.0, 0.0],
        };
        let p = cam.project(anchor).unwrap_or([0.0, 0.0]);
        cam.principal_px = [centre[0] - p[0], centre[1] - p[1]];
        cam
    };
    [
        ("cam0".to_string(), make(Vector3::new(0.0, 0.0, 40.0))),
        ("cam1".to_string(), make(Vector3::new(3.0, 0.5, 46.0))),
    ]
}

/// The rigid map mocap → face of the neutral frame (Kabsch of the markers onto their landmark
/// vertices): `softcap face track` expresses the take's cameras in face coordinates with it.
pub fn face_from_mocap(
    take: &MocapTake,
    landmarks: &[Landmark],
    face: &TriMesh,
) -> Result<Isometry3<f64>> {
    let mut a = Vec::new();
    let mut b = Vec::new();
    for (i, name) in take.names.iter().enumerate() {
        let Some(row) = landmarks.iter().find(|r| &r.marker == name) else {
            return Err(FaceError::InvalidInput {
                what: "landmarks",
                reason: format!("no landmark for marker `{name}`"),
            });
        };
        let Some(v) = face.vertices.get(row.vertex) else {
            return Err(FaceError::InvalidInput {
                what: "landmarks",
                reason: format!("vertex {} of `{name}` is not in the face", row.vertex),
            });
        };
        a.push(take.positions_cm[0][i]);
        b.push(*v);
    }
    if a.len() < 3 {
        return Err(FaceError::InvalidInput {
            what: "landmarks",
            reason: format!(
                "{} markers; need ≥ 3 for the rigid face ← mocap map",
                a.len()
            ),
        });
    }
    let (r, t) = rigid_fit(&a, &b);
    let rot = UnitQuaternion::from_matrix(&r);
    Ok(Isometry3::from_parts(Translation3::from(t), rot))
}

/// One camera's scene of one frame: the wrinkles placed at the projection of the anchor.
fn frame_scene(
    cam: &PinholeCamera,
    cam_index: usize,
    anchor: &Vector3<f64>,
    t: usize,
    settings: &TakeSynthSettings,
) -> CompositeScene {
    let base = WrinkleScene::default();
    let a = cam.project(anchor).unwrap_or([0.0, 0.0]);
    let s = 1.0 / cam.world_per_px(anchor); // px per cm at the anchor
    let n = settings.frames;
    let wrinkles = WRINKLES
        .iter()
        .enumerate()
        .map(|(k, w)| {
            let [sx, sy] = slide_cm(k, t, n);
            // valley top at (sx, top + sy) cm; image rows grow downwards
            let top = [a[0] + s * sx, a[1] - s * (w.top_cm + sy)];
            let half = 0.5 * w.length_cm / w.radius_cm;
            let [fd, fw] = profile_factors(settings.motion, k, t, n, settings.ramp_frames);
            WrinkleScene {
                width_px: settings.width_px,
                height_px: settings.height_px,
                arc_center_px: [top[0], top[1] + s * w.radius_cm],
                arc_radius_px: s * w.radius_cm,
                arc_angles_rad: [
                    -std::f64::consts::FRAC_PI_2 - half,
                    -std::f64::consts::FRAC_PI_2 + half,
                ],
                taper_px: 0.3 * s,
                width_w_px: s * w.width_cm * fw,
                depth_d_px: s * w.depth_cm * fd,
                paint_half_width_px: 0.35 * s,
                ..base.clone()
            }
        })
        .collect();
    // camera 0: a 0.3 cm strand of hair over wrinkle 0's right half in the middle of the take
    let mut occluders = Vec::new();
    let (from, to) = ((35 * n) / 100, (60 * n) / 100);
    if cam_index == 0 && (from..to).contains(&t) {
        let x = a[0] + s * (0.45 + 0.02 * (t - from) as f64);
        occluders.push(Occluder {
            x_px: [x, x + 0.3 * s],
            y_px: [-1.0, a[1] - 0.05 * s],
            rgb: [0.12, 0.08, 0.05],
        });
    }
    CompositeScene {
        width_px: settings.width_px,
        height_px: settings.height_px,
        wrinkles,
        occluders,
        paint_rgb: base.paint_rgb,
        skin_rgb: base.skin_rgb,
        ambient: base.ambient,
    }
}

/// `rig/cameras.toml` text of face-frame cameras expressed in the mocap frame (translations in
/// cm, the mocap's unit): X_cam = R (X_mocap) + t with camera ← face ∘ face ← mocap.
fn cameras_toml(
    cams: &[(String, PinholeCamera)],
    face_from_mocap: &Isometry3<f64>,
    w: usize,
    h: usize,
) -> String {
    let mut text = String::from(
        "# softcap face synth-take: cameras in the mocap frame, translations in cm\n\n",
    );
    for (id, cam) in cams {
        let cam_from_mocap = cam.world_from_camera.inverse() * face_from_mocap;
        let r = cam_from_mocap.rotation.to_rotation_matrix().into_inner();
        let t = cam_from_mocap.translation.vector;
        let _ = writeln!(text, "[[camera]]\nid = \"{id}\"\nwidth = {w}\nheight = {h}");
        let _ = writeln!(
            text,
            "fx = {f:.6}\nfy = {f:.6}\ncx = {:.6}\ncy = {:.6}",
            cam.principal_px[0],
            cam.principal_px[1],
            f = cam.focal_px
        );
        let row_major: Vec<String> = (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| format!("{:.15}", r[(i, j)]))
            .collect();
        let _ = writeln!(text, "rotation = [{}]", row_major.join(", "));
        let _ = writeln!(text, "translation = [{:.9}, {:.9}, {:.9}]\n", t.x, t.y, t.z);
    }
    text
}

/// The first `n` frames of `take` as AnimFace CSV.
fn animface_csv(take: &MocapTake, n: usize) -> String {
    let mut s = String::from("frame,time_s,marker,x_cm,y_cm,z_cm\n");
    for t in 0..n {
        for (name, p) in take.names.iter().zip(&take.positions_cm[t]) {
            let _ = writeln!(
                s,
                "{},{:.6},{name},{:.6},{:.6},{:.6}",
                take.frames[t], take.times_s[t], p.x, p.y, p.z
            );
        }
    }
    s
}

/// Render a face take into `out` (`docs/face.md`, "Face takes"): `cameras.toml`, `mocap.csv`,
/// `frames/<camera>/<frame>.png`, `labels/<camera>.png` (the paint mask of frame 0, the user's
/// training label of thesis §4.3.1) and `truth.json`. `on_frame` is called after each frame.
pub fn synth_take(
    face: &TriMesh,
    take: &MocapTake,
    landmarks: &[Landmark],
    out: &Path,
    settings: &TakeSynthSettings,
    on_frame: &dyn Fn(),
) -> Result<TakeTruth> {
    let n = settings.frames;
    if n < 4 || n > take.frames.len() {
        return Err(FaceError::InvalidSetting {
            field: "frames",
            reason: format!(
                "{n} frames; need 4 ≤ frames ≤ {} (the mocap take)",
                take.frames.len()
            ),
        });
    }
    let Some(anchor_row) = landmarks.iter().find(|r| r.marker == ANCHOR_MARKER) else {
        return Err(FaceError::InvalidInput {
            what: "landmarks",
            reason: format!("no `{ANCHOR_MARKER}` row (the wrinkles' anchor)"),
        });
    };
    let handles: Vec<usize> = take
        .names
        .iter()
        .map(|m| {
            landmarks
                .iter()
                .find(|r| &r.marker == m)
                .map(|r| r.vertex)
                .ok_or_else(|| FaceError::InvalidInput {
                    what: "landmarks",
                    reason: format!("no landmark for marker `{m}`"),
                })
        })
        .collect::<Result<_>>()?;
    let f_from_m = face_from_mocap(take, landmarks, face)?;
    let animator = FaceAnimator::new(
        face.clone(),
        handles,
        &take.positions_cm[0],
        &ShellSettings::default(),
    )?;
    let anchor0 = face.vertices[anchor_row.vertex];
    let cams = face_cameras(&anchor0, settings);
    let io = |p: &Path, e: std::io::Error| FaceError::Io {
        path: p.to_path_buf(),
        source: e,
    };
    for (id, _) in &cams {
        let d = out.join("frames").join(id);
        std::fs::create_dir_all(&d).map_err(|e| io(&d, e))?;
    }
    let labels = out.join("labels");
    std::fs::create_dir_all(&labels).map_err(|e| io(&labels, e))?;
    let write =
        |p: &Path, text: &str| softcap_app::write_atomic(p, text.as_bytes()).map_err(|e| io(p, e));
    write(
        &out.join("cameras.toml"),
        &cameras_toml(&cams, &f_from_m, settings.width_px, settings.height_px),
    )?;
    write(&out.join("mocap.csv"), &animface_csv(take, n))?;
    let mut truth = TakeTruth {
        cameras: cams.iter().map(|(id, _)| id.clone()).collect(),
        scenes: vec![Vec::with_capacity(n); cams.len()],
    };
    for t in 0..n {
        let verts = animator.frame(&take.positions_cm[t])?;
        let anchor = verts[anchor_row.vertex];
        for (c, (id, cam)) in cams.iter().enumerate() {
            let scene = frame_scene(cam, c, &anchor, t, settings);
            let render = AoRenderSettings {
                seed: settings.render.seed
                    ^ (((t as u64) << 8) | c as u64).wrapping_mul(0x2545_F491_4F6C_DD1D),
                ..settings.render
            };
            let frame = render_ambient_occlusion(&scene, &render);
            frame
                .image
                .write_png(&out.join("frames").join(id).join(format!("{t:06}.png")))?;
            if t == 0 {
                let mut label = crate::image::RgbImage::new(scene.width_px, scene.height_px);
                for (px, &m) in label.data.iter_mut().zip(&frame.paint_mask) {
                    *px = if m { [1.0; 3] } else { [0.0; 3] };
                }
                label.write_png(&labels.join(format!("{id}.png")))?;
            }
            truth.scenes[c].push(scene);
        }
        on_frame();
    }
    let json =
        serde_json::to_string_pretty(&truth).map_err(|e| FaceError::Output(e.to_string()))?;
    write(&out.join("truth.json"), &json)?;
    Ok(truth)
}

/// Accuracy of a tracked take against its truth ([`score_track`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrackScore {
    /// Largest distance of a visible wrinkle's cross-section valley from the true valley (px).
    pub valley_max_px: f64,
    /// RMS of those distances (px).
    pub valley_rms_px: f64,
    /// Largest |median d / true d − 1| over (camera, frame, wrinkle) with truth d/w ≥ the
    /// `min_ratio` of [`score_track`].
    pub depth_max_rel: f64,
    /// The same for w.
    pub width_max_rel: f64,
    /// Largest |d / true d − 1| of a single cross-section in those frames.
    pub depth_section_max_rel: f64,
    /// The same for w.
    pub width_section_max_rel: f64,
    /// Frames scored for (d, w) (camera × frame × wrinkle).
    pub scored: usize,
    /// Of those, frames in which the tracker did not report the wrinkle visible.
    pub missed: usize,
    /// Largest |frame the tracker first (last) reports a wrinkle visible − first (last) frame its
    /// true depth is > 0| over cameras, wrinkles and appearance (disappearance) events.
    pub detection_lag_frames: usize,
    /// Frames the tracker reports visible where the true depth is 0.
    pub false_visible: usize,
}

/// Score `face track`'s output (`/face/track/wrinkles`) against the truth of [`synth_take`]:
/// wrinkle id k of a camera is truth wrinkle k (label patches and truth wrinkles are both
/// ordered top to bottom). (d, w) are scored where the true d/w ≥ `min_ratio` (an appearing
/// wrinkle's first ramp frames are barely a dent: d/w 0.13 and 0.27 in the rendered takes);
/// valleys wherever the tracker reports the wrinkle visible; detection counts every frame with a
/// true depth > 0 as present.
pub fn score_track(
    truth: &TakeTruth,
    frames: &[softcap_mcap::proto::WrinkleTrackFrame],
    min_ratio: f64,
) -> TrackScore {
    let mut s = TrackScore::default();
    let (mut sq, mut count) = (0.0, 0usize);
    for (c, id) in truth.cameras.iter().enumerate() {
        let n = truth.scenes[c].len();
        let n_wr = truth.scenes[c].first().map_or(0, |x| x.wrinkles.len());
        let mut seen = vec![vec![false; n]; n_wr];
        let mut present = vec![vec![false; n]; n_wr];
        for f in frames.iter().filter(|f| &f.camera == id) {
            let t = f.frame as usize;
            let Some(scene) = truth.scenes[c].get(t) else {
                continue;
            };
            for (k, ws) in scene.wrinkles.iter().enumerate() {
                present[k][t] = ws.depth_d_px > 0.0;
                let tracked = f.wrinkles.iter().find(|w| w.id as usize == k);
                let visible = tracked.is_some_and(|w| w.status == "visible");
                seen[k][t] = visible;
                if visible && !present[k][t] {
                    s.false_visible += 1;
                }
                let scored = ws.depth_d_px / ws.width_w_px >= min_ratio;
                if scored {
                    s.scored += 1;
                }
                let Some(w) = tracked.filter(|_| visible) else {
                    if scored {
                        s.missed += 1;
                    }
                    continue;
                };
                let mut ds = Vec::new();
                let mut wsz = Vec::new();
                for (sec, _) in w.sections.iter().zip(&w.converged).filter(|(_, ok)| **ok) {
                    let q = ws.closest_valley_point(sec.valley_u_px, sec.valley_v_px);
                    let e = (sec.valley_u_px - q[0]).hypot(sec.valley_v_px - q[1]);
                    s.valley_max_px = s.valley_max_px.max(e);
                    sq += e * e;
                    count += 1;
                    ds.push(sec.depth_px);
                    wsz.push(sec.width_px);
                    if scored {
                        s.depth_section_max_rel = s
                            .depth_section_max_rel
                            .max((sec.depth_px / ws.depth_d_px - 1.0).abs());
                        s.width_section_max_rel = s
                            .width_section_max_rel
                            .max((sec.width_px / ws.width_w_px - 1.0).abs());
                    }
                }
                if scored && !ds.is_empty() {
                    ds.sort_by(f64::total_cmp);
                    wsz.sort_by(f64::total_cmp);
                    let (d, w) = (ds[ds.len() / 2], wsz[wsz.len() / 2]);
                    s.depth_max_rel = s.depth_max_rel.max((d / ws.depth_d_px - 1.0).abs());
                    s.width_max_rel = s.width_max_rel.max((w / ws.width_w_px - 1.0).abs());
                }
            }
        }
        for k in 0..n_wr {
            let first = |v: &[bool]| v.iter().position(|&x| x);
            let last = |v: &[bool]| v.iter().rposition(|&x| x);
            for (a, b) in [
                (first(&seen[k]), first(&present[k])),
                (last(&seen[k]), last(&present[k])),
            ] {
                let lag = match (a, b) {
                    (Some(a), Some(b)) => a.abs_diff(b),
                    (None, None) => 0,
                    _ => n,
                };
                s.detection_lag_frames = s.detection_lag_frames.max(lag);
            }
        }
    }
    s.valley_rms_px = if count > 0 {
        (sq / count as f64).sqrt()
    } else {
        0.0
    };
    s
}
