//! Criterion benches of the face stage: linear-shell prefactor and per-frame solve on the ICT
//! face (41 marker handles) and on its 3× midpoint-subdivided version (≈600k vertices), the (d, w)
//! cross-section fit of one rendered wrinkle frame, and the wrinkle synthesis (§3.3.1) of eleven
//! wrinkles on the jaw-open ICT frame (2× subdivided; 3× in the `subdivided` group, which runs
//! only with SOFTCAP_FACE_BENCH_FINE=1).

use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use softcap_face::morphology::connected_components;
use softcap_face::{
    AoRenderSettings, FaceAnimator, TrackSettings, WrinkleScene, factor_shell, parse_landmarks_csv,
    read_animface_csv, render_ambient_occlusion, subdivide_midpoint, track_wrinkle,
};
use softcap_face::{SynthesisSettings, synthesize_wrinkles};

#[path = "../tests/common/face_scene.rs"]
mod face_scene;
use softcap_mesh::shell::ShellSettings;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
}

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
    let mut fast = FaceAnimator::new(
        mesh.clone(),
        handles.clone(),
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .expect("animator");
    fast.precompute_basis().expect("basis");
    c.bench_function("shell_frame_basis_ict_9409v", |b| {
        b.iter(|| fast.frame(&take.positions_cm[t]).expect("frame"))
    });
    // wrinkle synthesis on a full face: eleven wrinkles (forehead, glabella, nasolabial folds,
    // crow's feet; tests/common/face_scene.rs) on the jaw-open ICT frame subdivided twice
    // (148k vertices; the thesis's scans have ≈700k, see the subdivided group below)
    let (rest2, deformed2) = face_scene::face_scene_meshes(2);
    let camera = face_scene::face_camera(&deformed2);
    let wrinkles = face_scene::face_wrinkles(&camera, &deformed2);
    let check = synthesize_wrinkles(
        &rest2,
        &deformed2,
        &camera,
        &wrinkles,
        &SynthesisSettings::default(),
    )
    .expect("synthesis");
    eprintln!(
        "synthesis scene: {} vertices, {} wrinkles ({} samples, all on the face: {}), {} regions: {:?}",
        rest2.vertices.len(),
        wrinkles.len(),
        wrinkles.iter().map(|w| w.samples.len()).sum::<usize>(),
        check
            .projected
            .iter()
            .zip(&wrinkles)
            .all(|(p, w)| p.points.len() == w.samples.len()),
        check.regions.len(),
        check
            .regions
            .iter()
            .map(|r| (
                r.free_vertices,
                r.valley_vertices,
                r.iterations,
                r.converged
            ))
            .collect::<Vec<_>>()
    );
    let mut group = c.benchmark_group("synthesis");
    group.sample_size(10);
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
    let fine = subdivide(&mesh, 3);
    let mut group = c.benchmark_group("subdivided");
    group.sample_size(10);
    group.bench_function(format!("shell_prefactor_{}v", fine.vertices.len()), |b| {
        b.iter(|| factor_shell(&fine, &handles, &ShellSettings::default()).expect("factor"))
    });
    let mut fine_animator = FaceAnimator::new(
        fine.clone(),
        handles.clone(),
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .expect("animator");
    group.bench_function(format!("shell_frame_{}v", fine.vertices.len()), |b| {
        b.iter(|| fine_animator.frame(&take.positions_cm[t]).expect("frame"))
    });
    fine_animator.precompute_basis().expect("basis");
    group.bench_function(format!("shell_frame_basis_{}v", fine.vertices.len()), |b| {
        b.iter(|| fine_animator.frame(&take.positions_cm[t]).expect("frame"))
    });
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
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
