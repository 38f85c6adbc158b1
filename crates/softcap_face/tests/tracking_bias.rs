//! Where the shallow-wrinkle (d, w) bias comes from (docs/face.md): the same rendered wrinkle
//! tracked with and without image noise, with 16² and 32² AO rays per pixel, with the quantile
//! reference I_obs(m) fixed (thesis) or scaled by the fit. Prints a table; ~1 min, so ignored.

use softcap_face::morphology::connected_components;
use softcap_face::{
    AoRenderSettings, TrackSettings, WrinkleScene, render_ambient_occlusion, track_wrinkle,
};

#[test]
#[ignore]
fn shallow_wrinkle_bias_sources() {
    for (w, d) in [(5.0, 2.0), (4.0, 3.0)] {
        let scene = WrinkleScene {
            width_w_px: w,
            depth_d_px: d,
            ..Default::default()
        };
        for (rays, noise) in [(16, 0.002), (16, 0.0), (32, 0.0)] {
            let f = render_ambient_occlusion(
                &scene,
                &AoRenderSettings {
                    rays_per_axis: rays,
                    noise_sigma: noise,
                    ..Default::default()
                },
            );
            let comps = connected_components(&f.paint_mask, scene.width_px, scene.height_px);
            for (q, sc) in [(0.9, false), (0.9, true), (0.97, true)] {
                let t = track_wrinkle(
                    &f.image,
                    &comps[0],
                    &TrackSettings {
                        ambient_quantile: q,
                        fit_reference_scale: sc,
                        ..Default::default()
                    },
                )
                .unwrap();
                let n = t.sections.len() as f64;
                let md = t.sections.iter().map(|s| s.depth_px).sum::<f64>() / n;
                let mw = t.sections.iter().map(|s| s.width_px).sum::<f64>() / n;
                println!(
                    "w {w} d {d} rays {rays} noise {noise} q {q} scale {sc}: d {:+.1} % w {:+.1} %",
                    100.0 * (md - d) / d,
                    100.0 * (mw - w) / w
                );
            }
        }
    }
}
