//! CPU-time figures for docs/face.md on the ≈600k-vertex face (ICT face, 3 midpoint
//! subdivisions): shell prefactor, basis precomputation, per-frame time by factor solve and by
//! basis, and the full-face synthesis on the 2×-subdivided face. Criterion (benches/face.rs)
//! measures wall time, which on a shared machine is a multiple of this; these figures are user +
//! system CPU of this process (all threads) from /proc/self/stat. Minutes:
//!
//! `cargo run --release -p softcap_face --example timing_fine [fine_face_timings | cross_section_fit_timing]`

#[path = "../tests/common/mod.rs"]
#[allow(dead_code)]
mod common;

use common::face_scene::{face_camera, face_scene_meshes, face_wrinkles, fixtures, ict_animator};
use softcap_face::{FaceAnimator, SynthesisSettings, subdivide_midpoint, synthesize_wrinkles};
use softcap_mesh::shell::ShellSettings;

/// (wall s, CPU s) of `f`.
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64, f64) {
    let cpu = || softcap_app::process::cpu_seconds().unwrap_or(0.0);
    let (c0, t0) = (cpu(), std::time::Instant::now());
    let out = f();
    (out, t0.elapsed().as_secs_f64(), cpu() - c0)
}

fn fine_face_timings() {
    let (anim, _) = ict_animator();
    let take =
        softcap_face::read_animface_csv(&fixtures().join("animface-mocap/jaw_subset.csv")).unwrap();
    let (mut tris, mut v) = (anim.mesh.triangles.clone(), anim.mesh.vertices.clone());
    for _ in 0..3 {
        let (t, mut f) = subdivide_midpoint(&tris, &[&v]).unwrap();
        tris = t;
        v = f.pop().unwrap();
    }
    let mesh = softcap_mesh::TriMesh {
        vertices: v,
        triangles: tris,
    };
    let n = mesh.vertices.len();
    let (fa, wall, cpu) = timed(|| {
        FaceAnimator::new(
            mesh,
            anim.handles.clone(),
            &take.positions_cm[0],
            &ShellSettings::default(),
        )
        .unwrap()
    });
    println!("{n} v: prefactor (assemble + sparse Cholesky) wall {wall:.2} s, CPU {cpu:.2} s");
    let mut fa = fa;
    let t = take.frames.iter().position(|&f| f == 390).unwrap();
    let (exact, wall, cpu) = timed(|| fa.frame(&take.positions_cm[t]).unwrap());
    println!("frame by factor solve: wall {wall:.3} s, CPU {cpu:.3} s");
    let ((), wall, cpu) = timed(|| fa.precompute_basis().unwrap());
    println!("basis B (41 columns, one 41-column block solve): wall {wall:.2} s, CPU {cpu:.2} s");
    let (fast, wall, cpu) = timed(|| {
        let mut last = Vec::new();
        for _ in 0..10 {
            last = fa.frame(&take.positions_cm[t]).unwrap();
        }
        last
    });
    let err = exact
        .iter()
        .zip(&fast)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    println!(
        "frame by basis: wall {:.4} s, CPU {:.4} s per frame; max difference to the solve {err:.2e} cm",
        wall / 10.0,
        cpu / 10.0
    );
    assert!(err < 1e-5);

    let (rest2, deformed2) = face_scene_meshes(2);
    let cam = face_camera(&deformed2);
    let wrinkles = face_wrinkles(&cam, &deformed2);
    let (out, wall, cpu) = timed(|| {
        synthesize_wrinkles(
            &rest2,
            &deformed2,
            &cam,
            &wrinkles,
            &SynthesisSettings::default(),
        )
        .unwrap()
    });
    println!(
        "synthesis, 11 wrinkles on {} v: wall {wall:.2} s, CPU {cpu:.2} s, {} regions {:?}",
        rest2.vertices.len(),
        out.regions.len(),
        out.regions
            .iter()
            .map(|r| (
                r.free_vertices,
                r.valley_vertices,
                r.iterations,
                r.converged
            ))
            .collect::<Vec<_>>()
    );
}

fn cross_section_fit_timing() {
    use softcap_face::morphology::connected_components;
    use softcap_face::{
        AoRenderSettings, TrackSettings, WrinkleScene, render_ambient_occlusion, track_wrinkle,
    };
    for (w, d) in [(4.0, 3.0), (5.0, 2.0)] {
        let scene = WrinkleScene {
            width_w_px: w,
            depth_d_px: d,
            ..Default::default()
        };
        let frame = render_ambient_occlusion(
            &scene,
            &AoRenderSettings {
                rays_per_axis: 16,
                ..Default::default()
            },
        );
        let patch =
            connected_components(&frame.paint_mask, scene.width_px, scene.height_px).remove(0);
        let (t, wall, cpu) =
            timed(|| track_wrinkle(&frame.image, &patch, &TrackSettings::default()).unwrap());
        println!(
            "track + {} cross-section fits (d, w) = ({d}, {w}) px: wall {wall:.3} s, CPU {cpu:.3} s",
            t.sections.len()
        );
    }
}

/// Runs the part named by the first argument, or all of them.
fn main() {
    match std::env::args().nth(1).as_deref() {
        Some("fine_face_timings") => fine_face_timings(),
        Some("cross_section_fit_timing") => cross_section_fit_timing(),
        None => {
            fine_face_timings();
            cross_section_fit_timing();
        }
        Some(other) => {
            eprintln!(
                "unknown part `{other}`; one of: fine_face_timings, cross_section_fit_timing"
            );
            std::process::exit(2);
        }
    }
}
