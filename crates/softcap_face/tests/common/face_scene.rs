//! A full-face wrinkle scene shared by `tests/synthesis_face.rs` and the synthesis bench: the
//! AnimFace jaw take's frame 390 on the ICT face (optionally midpoint-subdivided), a frontal
//! pinhole camera 60 cm in front of the face, and eleven image-space wrinkles in the places
//! wrinkles form on a face — three forehead lines, two glabellar (frown) lines, two nasolabial
//! folds and two crow's-feet lines at each eye — each as pixel samples with (d, w) in pixels.

#![allow(dead_code)]

use std::path::PathBuf;

use softcap_face::nalgebra::{Isometry3, Vector3};
use softcap_face::{
    FaceAnimator, PinholeCamera, WrinkleCurve, WrinkleSample, parse_landmarks_csv,
    read_animface_csv, subdivide_midpoint,
};
use softcap_mesh::TriMesh;
use softcap_mesh::shell::ShellSettings;

pub fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
}

/// The ICT face, its marker handles and the AnimFace jaw take's frame index 390.
pub fn ict_animator() -> (FaceAnimator, Vec<Vector3<f64>>) {
    let take =
        read_animface_csv(&fixtures().join("animface-mocap/jaw_subset.csv")).expect("fixture");
    let mesh = softcap_mesh::read_obj(fixtures().join("ict-face/neutral.obj"))
        .expect("fixture")
        .to_tri_mesh();
    let path = fixtures().join("animface-mocap/ict_landmarks.csv");
    let table = parse_landmarks_csv(&std::fs::read_to_string(&path).expect("fixture"), &path)
        .expect("table");
    let handles: Vec<usize> = take
        .names
        .iter()
        .map(|n| {
            table
                .iter()
                .find(|r| &r.marker == n)
                .expect("landmark")
                .vertex
        })
        .collect();
    let animator = FaceAnimator::new(
        mesh,
        handles,
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .expect("animator");
    let t = take.frames.iter().position(|&f| f == 390).expect("frame");
    let deformed = animator.frame(&take.positions_cm[t]).expect("frame");
    (animator, deformed)
}

/// Rest and deformed face after `levels` midpoint subdivisions.
pub fn face_scene_meshes(levels: usize) -> (TriMesh, Vec<Vector3<f64>>) {
    let (animator, deformed) = ict_animator();
    let mut tris = animator.mesh.triangles.clone();
    let mut rest = animator.mesh.vertices.clone();
    let mut def = deformed;
    for _ in 0..levels {
        let (t, mut f) = subdivide_midpoint(&tris, &[&rest, &def]).expect("subdivide");
        tris = t;
        def = f.pop().expect("field");
        rest = f.pop().expect("field");
    }
    (
        TriMesh {
            vertices: rest,
            triangles: tris,
        },
        def,
    )
}

/// Frontal camera (looking along −z) 60 cm in front of the face, 2000 px focal length
/// (0.03 cm per pixel at the face).
pub fn face_camera(deformed: &[Vector3<f64>]) -> PinholeCamera {
    let z_front = deformed
        .iter()
        .map(|v| v.z)
        .fold(f64::NEG_INFINITY, f64::max);
    PinholeCamera {
        world_from_camera: Isometry3::new(
            Vector3::new(0.0, 0.0, z_front + 60.0),
            Vector3::new(std::f64::consts::PI, 0.0, 0.0),
        ),
        focal_px: 2000.0,
        principal_px: [1000.0, 1000.0],
    }
}

/// A wrinkle through world points (x, y) in cm on the face (the samples are the pixels of
/// (x, y, z_front)), depth and width in cm converted to pixels at 60 cm.
fn wrinkle(cam: &PinholeCamera, z: f64, pts: &[(f64, f64)], d_cm: f64, w_cm: f64) -> WrinkleCurve {
    let px_per_cm = cam.focal_px / 60.0;
    let mut samples = Vec::new();
    for seg in pts.windows(2) {
        let ((x0, y0), (x1, y1)) = (seg[0], seg[1]);
        let len = ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt();
        let n = (len / 0.25).ceil().max(1.0) as usize;
        for k in 0..n {
            let s = k as f64 / n as f64;
            // depth tapers towards both ends of the whole wrinkle
            samples.push((x0 + s * (x1 - x0), y0 + s * (y1 - y0)));
        }
    }
    let last = pts[pts.len() - 1];
    samples.push(last);
    let m = samples.len();
    WrinkleCurve {
        samples: samples
            .iter()
            .enumerate()
            .map(|(k, &(x, y))| {
                let t = k as f64 / (m - 1) as f64;
                let taper = (std::f64::consts::PI * t).sin().max(0.0).sqrt();
                let px = cam.project(&Vector3::new(x, y, z)).expect("in front");
                WrinkleSample {
                    valley_px: px,
                    depth_px: d_cm * px_per_cm * taper.max(0.3),
                    width_px: w_cm * px_per_cm,
                }
            })
            .collect(),
    }
}

/// The eleven wrinkles (cm on the ICT face, frame 390).
pub fn face_wrinkles(cam: &PinholeCamera, deformed: &[Vector3<f64>]) -> Vec<WrinkleCurve> {
    let z = deformed
        .iter()
        .map(|v| v.z)
        .fold(f64::NEG_INFINITY, f64::max);
    let mut w = Vec::new();
    // forehead: three horizontal lines, slightly arched
    for (y, half) in [(6.6, 3.2), (7.6, 3.6), (8.6, 3.0)] {
        w.push(wrinkle(
            cam,
            z,
            &[(-half, y - 0.3), (0.0, y), (half, y - 0.3)],
            0.06,
            0.18,
        ));
    }
    for s in [-1.0, 1.0] {
        // glabellar (frown) line between the brows
        w.push(wrinkle(
            cam,
            z,
            &[(s * 0.7, 4.4), (s * 0.5, 5.8)],
            0.05,
            0.12,
        ));
        // nasolabial fold from the nose wing to beside the mouth corner
        w.push(wrinkle(
            cam,
            z,
            &[(s * 2.0, 0.6), (s * 2.6, -1.0), (s * 2.9, -2.8)],
            0.1,
            0.25,
        ));
        // crow's feet at the outer eye corner
        w.push(wrinkle(
            cam,
            z,
            &[(s * 5.0, 3.9), (s * 6.1, 4.6)],
            0.04,
            0.12,
        ));
        w.push(wrinkle(
            cam,
            z,
            &[(s * 5.0, 3.2), (s * 6.1, 2.6)],
            0.04,
            0.12,
        ));
    }
    w
}
