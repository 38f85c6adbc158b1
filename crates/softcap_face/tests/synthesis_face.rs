//! Thesis §3.3.1 on a full face: eleven image-space wrinkles (forehead, glabella, nasolabial
//! folds, crow's feet; `common/face_scene.rs`) are cast through a frontal camera onto the
//! jaw-open ICT face (frame 390, once midpoint-subdivided: 37k vertices) and synthesized. Every
//! sample must hit the face, the regions must segment into the expected groups, each region's
//! Gauss–Newton must converge and lower eq. 3.6, and the valley vertices carry S(w, d, p).
//! The figures docs/face/synth_face*.png come from `examples/synth_face_figure.rs`.

mod common;

use common::face_scene::{face_camera, face_scene_meshes, face_wrinkles};
use softcap_face::{SynthesisSettings, synthesize_wrinkles};

#[test]
fn full_face_wrinkles_project_segment_and_converge() {
    let (rest, deformed) = face_scene_meshes(1);
    let cam = face_camera(&deformed);
    let wrinkles = face_wrinkles(&cam, &deformed);
    let t0 = std::time::Instant::now();
    let out = synthesize_wrinkles(
        &rest,
        &deformed,
        &cam,
        &wrinkles,
        &SynthesisSettings::default(),
    )
    .unwrap();
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "{} vertices, {} wrinkles, {} regions in {secs:.2} s",
        rest.vertices.len(),
        wrinkles.len(),
        out.regions.len()
    );
    for (k, w) in wrinkles.iter().enumerate() {
        assert_eq!(
            out.projected[k].points.len(),
            w.samples.len(),
            "wrinkle {k}: every sample hits the face"
        );
    }
    for r in &out.regions {
        println!(
            "  region: {} free + {} valley vertices, E {:.3e} → {:.3e}, {} GN iterations, converged {}",
            r.free_vertices,
            r.valley_vertices,
            r.initial_energy,
            r.final_energy,
            r.iterations,
            r.converged
        );
        assert!(r.converged);
        assert!(r.valley_vertices > 0);
        assert!(r.final_energy < r.initial_energy);
    }
    // influence regions (4w around each valley) merge where they touch: the forehead lines
    // (1 cm apart, 4w = 0.72 cm) are one region, the two lines of each crow's foot another;
    // measured 5 regions
    assert!(
        (4..=9).contains(&out.regions.len()),
        "{} regions",
        out.regions.len()
    );
    // valley vertices moved by S along the smoothed normal: depth range matches the input
    // (d in cm = d in pixels × the footprint z/f at the hit point)
    let deepest = out.valley_offset.iter().copied().fold(0.0, f64::min);
    let d_max = out
        .projected
        .iter()
        .flat_map(|p| p.depth.iter().copied())
        .fold(0.0, f64::max);
    println!("deepest valley offset {deepest:.4} cm (deepest projected d {d_max:.4} cm)");
    assert!(deepest < -0.5 * d_max && deepest >= -d_max - 1e-12);
}
