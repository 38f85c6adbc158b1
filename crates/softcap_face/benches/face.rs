//! Criterion benches of the face stage: linear-shell prefactor and per-frame solve on the ICT
//! face (41 marker handles), and the (d, w) cross-section fit of one rendered wrinkle frame.

use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use softcap_face::morphology::connected_components;
use softcap_face::{
    AoRenderSettings, FaceAnimator, TrackSettings, WrinkleScene, factor_shell, parse_landmarks_csv,
    read_animface_csv, render_ambient_occlusion, track_wrinkle,
};
use softcap_mesh::shell::ShellSettings;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
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
}

criterion_group!(benches, bench);
criterion_main!(benches);
