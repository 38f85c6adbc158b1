//! Criterion benches of the face stage, the four rows of issue 10 plus the small-face rows:
//!
//! | group / bench | what | aim (issue 10) |
//! |---|---|---|
//! | `ict/*` | shell prefactor, frame by solve, frame by basis on the ICT face (9,409 v) | |
//! | `face_592k/shell_setup_prefactor_basis_592166v` | assemble + factor A_FF + basis B (41 columns) on the 3× subdivided face | ≤ 20 s |
//! | `face_592k/shell_frame_basis_592166v` | correspondence + u = B u_H on the same face | ≤ 100 ms |
//! | `wrinkle/track_and_cross_sections_one_frame` | PCA + valley spline + 9 cross-section (d, w) fits, 140 × 64 px | ≤ 1 s |
//! | `wrinkle/track_video_12_frames_176x120` | `face track`'s per-camera work on 12 frames of the fixture take | ≤ 1 s per frame (issue 32) |
//! | `synthesis/face_11_wrinkles_148402v` | eleven wrinkles on the jaw-open face subdivided 2× | ≤ 10 s |
//!
//! `scripts/bench softcap_face` runs them all (≈ 5–6 min on 2 idle cores, most of it the 592k
//! setup's 11 runs; docs/face.md). `SOFTCAP_FACE_BENCH_FINE=1` adds the 592k prefactor alone, the
//! 592k frame by the factor solve and the synthesis on the 3× subdivided face (several more
//! minutes).

use std::time::Duration;

use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use softcap_face::morphology::connected_components;
use softcap_face::{
    AoRenderSettings, FaceAnimator, SynthesisSettings, TrackSettings, WrinkleScene, factor_shell,
    read_animface_csv, render_ambient_occlusion, subdivide_midpoint, synthesize_wrinkles,
    track_wrinkle,
};
use softcap_mesh::shell::ShellSettings;

#[path = "../tests/common/face_scene.rs"]
mod face_scene;

/// `levels` midpoint subdivisions (original vertices keep their indices, so the handles stay).
fn subdivide(mesh: &softcap_mesh::TriMesh, levels: usize) -> softcap_mesh::TriMesh {
    let (mut tris, mut verts) = (mesh.triangles.clone(), mesh.vertices.clone());
    for _ in 0..levels {
        let (t, mut f) = subdivide_midpoint(&tris, &[&verts]).expect("subdivide");
        tris = t;
        verts = f.pop().expect("field");
    }
    softcap_mesh::TriMesh {
        vertices: verts,
        triangles: tris,
    }
}

/// A group for runs of seconds: one iteration per sample, 10 samples, 1 s warm-up.
fn long_group<'a>(
    c: &'a mut Criterion,
    name: &str,
) -> criterion::BenchmarkGroup<'a, criterion::measurement::WallTime> {
    let mut group = c.benchmark_group(name);
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5));
    group
}

fn bench(c: &mut Criterion) {
    let fine_extra = std::env::var_os("SOFTCAP_FACE_BENCH_FINE").is_some();
    let take = read_animface_csv(&face_scene::fixtures().join("animface-mocap/jaw_subset.csv"))
        .expect("fixture");
    let t = take.frames.iter().position(|&f| f == 390).expect("frame");
    // the ICT face with its handles in the take's marker order
    let (ict, _) = face_scene::ict_animator();
    let (mesh, handles) = (ict.mesh.clone(), ict.handles.clone());

    let mut group = c.benchmark_group("ict");
    group.bench_function("shell_prefactor_9409v", |b| {
        b.iter(|| factor_shell(&mesh, &handles, &ShellSettings::default()).expect("factor"))
    });
    group.bench_function("shell_frame_9409v", |b| {
        b.iter(|| ict.frame(&take.positions_cm[t]).expect("frame"))
    });
    let mut fast = FaceAnimator::new(
        mesh.clone(),
        handles.clone(),
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .expect("animator");
    fast.precompute_basis().expect("basis");
    group.bench_function("shell_frame_basis_9409v", |b| {
        b.iter(|| fast.frame(&take.positions_cm[t]).expect("frame"))
    });
    group.finish();

    // cross-section fit of one rendered wrinkle frame (thesis §4.3.2; d = 3, w = 4 px)
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
    group.sample_size(20);
    group.bench_function("track_and_cross_sections_one_frame", |b| {
        b.iter(|| track_wrinkle(&frame.image, &patch, &TrackSettings::default()).expect("track"))
    });
    // `face track`'s per-camera work on the committed take (12 frames of cam0, 176 × 120 px, two
    // wrinkles): SVM training, classification, morphology, association, splines and fits
    let face_take = softcap_face::take::read_take(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../fixtures/face-takes/forehead"),
    )
    .expect("fixture take");
    let cam = &face_take.cameras[0];
    let (w, h) = (cam.camera.width, cam.camera.height);
    let label: Vec<bool> = softcap_face::take::read_png(&cam.label, w, h)
        .expect("label")
        .data
        .iter()
        .map(|p| p[0] > 0.5)
        .collect();
    let frames: Vec<_> = cam
        .frames
        .iter()
        .map(|p| softcap_face::take::read_png(p, w, h).expect("frame"))
        .collect();
    group.sample_size(10);
    group.bench_function("track_video_12_frames_176x120", |b| {
        b.iter(|| {
            softcap_face::video::track_video(&label, &frames, &Default::default(), &|| {})
                .expect("track video")
        })
    });
    group.finish();

    // wrinkle synthesis on a full face: eleven wrinkles (forehead, glabella, nasolabial folds,
    // crow's feet; tests/common/face_scene.rs) on the jaw-open ICT frame subdivided twice
    let (rest2, deformed2) = face_scene::face_scene_meshes(2);
    let camera = face_scene::face_camera(&deformed2);
    let wrinkles = face_scene::face_wrinkles(&camera, &deformed2);
    let mut group = long_group(c, "synthesis");
    group.bench_function(format!("face_11_wrinkles_{}v", rest2.vertices.len()), |b| {
        b.iter(|| {
            synthesize_wrinkles(
                &rest2,
                &deformed2,
                &camera,
                &wrinkles,
                &SynthesisSettings::default(),
            )
            .expect("synthesis")
        })
    });
    group.finish();

    // ≈600k-vertex face: three midpoint subdivisions of the ICT face, same marker handles
    // (the thesis's scans have ≈700k vertices, bickel2007: 120 s setup, 3 s per frame)
    let fine = subdivide(&mesh, 3);
    let n = fine.vertices.len();
    let mut group = long_group(c, "face_592k");
    group.bench_function(format!("shell_setup_prefactor_basis_{n}v"), |b| {
        b.iter(|| {
            let mut a = FaceAnimator::new(
                fine.clone(),
                handles.clone(),
                &take.positions_cm[0],
                &ShellSettings::default(),
            )
            .expect("animator");
            a.precompute_basis().expect("basis");
            a
        })
    });
    let mut fine_animator = FaceAnimator::new(
        fine.clone(),
        handles.clone(),
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .expect("animator");
    if fine_extra {
        group.bench_function(format!("shell_prefactor_{n}v"), |b| {
            b.iter(|| factor_shell(&fine, &handles, &ShellSettings::default()).expect("factor"))
        });
        group.bench_function(format!("shell_frame_solve_{n}v"), |b| {
            b.iter(|| fine_animator.frame(&take.positions_cm[t]).expect("frame"))
        });
    }
    fine_animator.precompute_basis().expect("basis");
    group.bench_function(format!("shell_frame_basis_{n}v"), |b| {
        b.iter(|| fine_animator.frame(&take.positions_cm[t]).expect("frame"))
    });
    drop(fine_animator);
    if fine_extra {
        let (rest3, deformed3) = face_scene::face_scene_meshes(3);
        let camera3 = face_scene::face_camera(&deformed3);
        let wrinkles3 = face_scene::face_wrinkles(&camera3, &deformed3);
        group.bench_function(
            format!("synthesis_face_11_wrinkles_{}v", rest3.vertices.len()),
            |b| {
                b.iter(|| {
                    synthesize_wrinkles(
                        &rest3,
                        &deformed3,
                        &camera3,
                        &wrinkles3,
                        &SynthesisSettings::default(),
                    )
                    .expect("synthesis")
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
