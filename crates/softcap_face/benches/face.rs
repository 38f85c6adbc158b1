//! Criterion benches of the face stage: linear-shell prefactor and per-frame solve on the ICT
//! face (41 marker handles) and on its 3× midpoint-subdivided version (≈600k vertices), the (d, w)
//! cross-section fit of one rendered wrinkle frame, and the wrinkle synthesis (§3.3.1) of one
//! forehead wrinkle on the jaw-open ICT frame.

use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use softcap_face::morphology::connected_components;
use softcap_face::nalgebra::{Isometry3, Vector3};
use softcap_face::{
    AoRenderSettings, FaceAnimator, TrackSettings, WrinkleScene, factor_shell, parse_landmarks_csv,
    read_animface_csv, render_ambient_occlusion, track_wrinkle,
};
use softcap_face::{
    PinholeCamera, SynthesisSettings, WrinkleCurve, WrinkleSample, synthesize_wrinkles,
};
use softcap_mesh::shell::ShellSettings;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
}

/// One midpoint subdivision (each triangle → 4); original vertices keep their indices.
fn subdivide(mesh: &softcap_mesh::TriMesh) -> softcap_mesh::TriMesh {
    let mut vertices = mesh.vertices.clone();
    let mut mid = std::collections::HashMap::new();
    let mut triangles = Vec::with_capacity(4 * mesh.triangles.len());
    for t in &mesh.triangles {
        let mut m = [0usize; 3];
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            m[k] = *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                vertices.push((mesh.vertices[a] + mesh.vertices[b]) * 0.5);
                vertices.len() - 1
            });
        }
        triangles.push([t[0], m[0], m[2]]);
        triangles.push([t[1], m[1], m[0]]);
        triangles.push([t[2], m[2], m[1]]);
        triangles.push(m);
    }
    softcap_mesh::TriMesh {
        vertices,
        triangles,
    }
}

fn bench(c: &mut Criterion) {
    let take =
        read_animface_csv(&fixtures().join("animface-mocap/jaw_subset.csv")).expect("fixture");
    let mesh = softcap_mesh::read_obj(fixtures().join("ict-face/neutral.obj"))
        .expect("fixture")
        .to_tri_mesh();
    let path = fixtures().join("animface-mocap/ict_landmarks.csv");
    let table = parse_landmarks_csv(&std::fs::read_to_string(&path).expect("fixture"), &path)
        .expect("table");
    let handles: Vec<usize> = table.iter().map(|r| r.vertex).collect();
    c.bench_function("shell_prefactor_ict_9409v", |b| {
        b.iter(|| factor_shell(&mesh, &handles, &ShellSettings::default()).expect("factor"))
    });
    let animator = FaceAnimator::new(
        mesh.clone(),
        handles.clone(),
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .expect("animator");
    let t = take.frames.iter().position(|&f| f == 390).expect("frame");
    c.bench_function("shell_frame_ict_9409v", |b| {
        b.iter(|| animator.frame(&take.positions_cm[t]).expect("frame"))
    });
    // wrinkle synthesis: one horizontal forehead wrinkle seen by a frontal camera 50 cm away
    let deformed = animator.frame(&take.positions_cm[t]).expect("frame");
    let (lo, hi) = deformed.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(a, b), v| (a.inf(v), b.sup(v)),
    );
    let forehead_y = lo.y + 0.8 * (hi.y - lo.y);
    let front = deformed
        .iter()
        .filter(|v| (v.y - forehead_y).abs() < 0.5)
        .max_by(|a, b| a.z.total_cmp(&b.z))
        .copied()
        .expect("forehead vertex");
    let camera = PinholeCamera {
        world_from_camera: Isometry3::new(
            Vector3::new(front.x, front.y, front.z + 50.0),
            Vector3::new(std::f64::consts::PI, 0.0, 0.0),
        ),
        focal_px: 1000.0,
        principal_px: [500.0, 500.0],
    };
    let curve = WrinkleCurve {
        samples: (0..17)
            .map(|k| WrinkleSample {
                valley_px: [420.0 + 10.0 * k as f64, 500.0],
                depth_px: 3.0,
                width_px: 6.0,
            })
            .collect(),
    };
    let mut group = c.benchmark_group("synthesis");
    group.sample_size(10);
    group.bench_function("forehead_wrinkle_ict_frame", |b| {
        b.iter(|| {
            synthesize_wrinkles(
                &animator.mesh,
                &deformed,
                &camera,
                std::slice::from_ref(&curve),
                &SynthesisSettings::default(),
            )
            .expect("synthesis")
        })
    });
    group.finish();

    let scene = WrinkleScene::default();
    let frame = render_ambient_occlusion(
        &scene,
        &AoRenderSettings {
            rays_per_axis: 16,
            ..Default::default()
        },
    );
    let patch = connected_components(&frame.paint_mask, scene.width_px, scene.height_px).remove(0);
    let mut group = c.benchmark_group("wrinkle");
    group.sample_size(10);
    group.bench_function("track_and_cross_sections_one_frame", |b| {
        b.iter(|| track_wrinkle(&frame.image, &patch, &TrackSettings::default()).expect("track"))
    });
    group.finish();

    // ≈600k-vertex face: three midpoint subdivisions of the ICT face, same marker handles
    // (several minutes with criterion's minimum of 10 samples: run with SOFTCAP_FACE_BENCH_FINE=1)
    if std::env::var_os("SOFTCAP_FACE_BENCH_FINE").is_none() {
        return;
    }
    let fine = subdivide(&subdivide(&subdivide(&mesh)));
    let mut group = c.benchmark_group("subdivided");
    group.sample_size(10);
    group.bench_function(format!("shell_prefactor_{}v", fine.vertices.len()), |b| {
        b.iter(|| factor_shell(&fine, &handles, &ShellSettings::default()).expect("factor"))
    });
    let fine_animator = FaceAnimator::new(
        fine.clone(),
        handles.clone(),
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .expect("animator");
    group.bench_function(format!("shell_frame_{}v", fine.vertices.len()), |b| {
        b.iter(|| fine_animator.frame(&take.positions_cm[t]).expect("frame"))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
