//! The figures of docs/face.md's full-face synthesis (thesis §3.3.1): the jaw-open ICT face
//! before and after the eleven image-space wrinkles of `tests/common/face_scene.rs` are
//! synthesized, rendered over the upper face.
//!
//! `cargo run --release -p softcap_face --example synth_face_figure [OUT_DIR]` (default
//! `docs/face`): writes `synth_face_before.png` and `synth_face.png`.

#[path = "../tests/common/mod.rs"]
#[allow(dead_code)]
mod common;

use common::face_scene::{face_camera, face_scene_meshes, face_wrinkles};
use softcap_face::nalgebra::Vector3;
use softcap_face::{OrthoView, SynthesisSettings, render_mesh, synthesize_wrinkles};

fn main() -> softcap_face::Result<()> {
    let dir = std::env::args_os().nth(1).map_or_else(
        || std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/face"),
        std::path::PathBuf::from,
    );
    let (rest, deformed) = face_scene_meshes(1);
    let cam = face_camera(&deformed);
    let wrinkles = face_wrinkles(&cam, &deformed);
    let out = synthesize_wrinkles(
        &rest,
        &deformed,
        &cam,
        &wrinkles,
        &SynthesisSettings::default(),
    )?;
    // upper face, where the wrinkles are
    let crop: Vec<Vector3<f64>> = deformed
        .iter()
        .filter(|v| v.y > -4.0 && v.y < 10.0 && v.x.abs() < 7.5)
        .copied()
        .collect();
    let (view, h) = OrthoView::fit(&crop, 900);
    for (name, verts) in [
        ("synth_face_before", &deformed),
        ("synth_face", &out.vertices),
    ] {
        let img = render_mesh(
            verts,
            &rest.triangles,
            &view,
            900,
            h,
            Vector3::new(0.2, 0.5, 1.0),
            [0.85, 0.68, 0.6],
        );
        img.write_png(&dir.join(format!("{name}.png")))?;
        println!("wrote {}", dir.join(format!("{name}.png")).display());
    }
    Ok(())
}
