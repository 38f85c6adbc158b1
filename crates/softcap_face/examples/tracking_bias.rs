//! Where the shallow-wrinkle (d, w) bias came from
//! (docs/notes/2026-11-22-wrinkle-cross-section-fit.md), minutes per part:
//!
//! `cargo run --release -p softcap_face --example tracking_bias [PART]` (all parts without PART)
//!
//! - `model_only`: the eq. 4.4 fit on Monte-Carlo AO pixels with the *true* distance p to the
//!   valley (no tracking, no noise, 16²–64² rays);
//! - `seeds`: the full tracking pipeline on six renders (different MC/noise seeds) per wrinkle;
//! - `residual_profile`, `truth_residuals`: MC render minus the 2.5D model at the true (d, w).
use softcap_face::morphology::connected_components;
use softcap_face::{
    AoRenderSettings, TrackSettings, WrinkleScene, fit_cross_section, render_ambient_occlusion,
    track_wrinkle,
};

fn model_only() {
    let (w, d) = (5.0, 2.0);
    let scene = WrinkleScene {
        width_w_px: w,
        depth_d_px: d,
        ..Default::default()
    };
    for rays in [16usize, 32, 64] {
        let f = render_ambient_occlusion(
            &scene,
            &AoRenderSettings {
                rays_per_axis: rays,
                noise_sigma: 0.0,
                ..Default::default()
            },
        );
        // pooled over the middle, true p, direct occlusion
        let mut ps = Vec::new();
        let mut rs = Vec::new();
        for y in 0..scene.height_px {
            for x in 0..scene.width_px {
                let (p, s) = scene.valley_coordinates(x as f64, y as f64);
                if s > 30.0 && s < scene.length_px() - 30.0 && p.abs() <= 14.0 {
                    ps.push(p);
                    rs.push(f.occlusion[y * scene.width_px + x]);
                }
            }
        }
        for scale in [false, true] {
            let st = TrackSettings {
                fit_reference_scale: scale,
                ..Default::default()
            };
            let (dd, ww, p0, rms, conv) = fit_cross_section(&ps, &rs, &st).unwrap();
            println!(
                "rays {rays} scale {scale} n {}: d {:+.2} % w {:+.2} % p0 {p0:.3} rms {rms:.4} conv {conv}",
                ps.len(),
                100.0 * (dd / d - 1.0),
                100.0 * (ww / w - 1.0)
            );
        }
    }
}

fn seeds() {
    for (w, d) in [(5.0, 2.0), (4.0, 3.0)] {
        let scene = WrinkleScene {
            width_w_px: w,
            depth_d_px: d,
            ..Default::default()
        };
        let mut all = Vec::new();
        for seed in 0..6u64 {
            let f = render_ambient_occlusion(
                &scene,
                &AoRenderSettings {
                    rays_per_axis: 16,
                    seed,
                    ..Default::default()
                },
            );
            let comps = connected_components(&f.paint_mask, scene.width_px, scene.height_px);
            let t = track_wrinkle(&f.image, &comps[0], &TrackSettings::default()).unwrap();
            let n = t.sections.len() as f64;
            let md = t.sections.iter().map(|s| s.depth_px).sum::<f64>() / n;
            let mw = t.sections.iter().map(|s| s.width_px).sum::<f64>() / n;
            let sw: Vec<String> = t
                .sections
                .iter()
                .map(|s| format!("{:.2}/{:.2}", s.depth_px, s.width_px))
                .collect();
            println!(
                "w {w} d {d} seed {seed}: d {:+.1} % w {:+.1} %  {}",
                100.0 * (md / d - 1.0),
                100.0 * (mw / w - 1.0),
                sw.join(" ")
            );
            all.push((md, mw));
        }
        let n = all.len() as f64;
        println!(
            "mean over seeds: d {:+.2} % w {:+.2} %",
            100.0 * (all.iter().map(|a| a.0).sum::<f64>() / n / d - 1.0),
            100.0 * (all.iter().map(|a| a.1).sum::<f64>() / n / w - 1.0)
        );
    }
}

fn residual_profile() {
    use softcap_face::{HorizonSettings, ambient_ratio};
    for r in [400.0, 1e6] {
        let half = 55.0 / r;
        let mut scene = WrinkleScene {
            width_w_px: 5.0,
            depth_d_px: 2.0,
            arc_radius_px: r,
            arc_center_px: [0.0, 32.0 + r],
            arc_angles_rad: [
                -std::f64::consts::FRAC_PI_2 - half,
                -std::f64::consts::FRAC_PI_2 + half,
            ],
            ..Default::default()
        };
        scene.width_px = 1;
        let f = render_ambient_occlusion(
            &scene,
            &AoRenderSettings {
                rays_per_axis: 96,
                noise_sigma: 0.0,
                ..Default::default()
            },
        );
        let hs = HorizonSettings::default();
        let mut line = String::new();
        for y in 0..scene.height_px {
            let (p, _s) = scene.valley_coordinates(0.0, y as f64);
            if p.abs() > 16.0 {
                continue;
            }
            let m = ambient_ratio(5.0, 2.0, p, &hs).ratio;
            line += &format!(
                "p {p:+.1}: mc {:.4} model {m:.4} diff {:+.4}\n",
                f.occlusion[y],
                f.occlusion[y] - m
            );
        }
        println!("R {r}\n{line}");
    }
}

fn truth_residuals() {
    use softcap_face::{HorizonSettings, ambient_ratio};
    let (w, d) = (5.0, 2.0);
    let scene = WrinkleScene {
        width_w_px: w,
        depth_d_px: d,
        ..Default::default()
    };
    let f = render_ambient_occlusion(
        &scene,
        &AoRenderSettings {
            rays_per_axis: 64,
            noise_sigma: 0.0,
            ..Default::default()
        },
    );
    let hs = HorizonSettings::default();
    let mut res = Vec::new();
    for y in 0..scene.height_px {
        for x in 0..scene.width_px {
            let (p, s) = scene.valley_coordinates(x as f64, y as f64);
            if s > 30.0 && s < scene.length_px() - 30.0 && p.abs() <= 14.0 {
                let m = ambient_ratio(w, d, p, &hs).ratio;
                res.push((p, s, f.occlusion[y * scene.width_px + x] - m, m));
            }
        }
    }
    let rms = (res.iter().map(|r| r.2 * r.2).sum::<f64>() / res.len() as f64).sqrt();
    println!("rms at truth {rms:.5}");
    res.sort_by(|a, b| b.2.abs().total_cmp(&a.2.abs()));
    for r in res.iter().take(25) {
        println!(
            "p {:+.3} s {:.1}: diff {:+.4} model {:.4}",
            r.0, r.1, r.2, r.3
        );
    }
}

/// Runs the part named by the first argument, or all of them.
fn main() {
    match std::env::args().nth(1).as_deref() {
        Some("model_only") => model_only(),
        Some("seeds") => seeds(),
        Some("residual_profile") => residual_profile(),
        Some("truth_residuals") => truth_residuals(),
        None => {
            model_only();
            seeds();
            residual_profile();
            truth_residuals();
        }
        Some(other) => {
            eprintln!(
                "unknown part `{other}`; one of: model_only, seeds, residual_profile, truth_residuals"
            );
            std::process::exit(2);
        }
    }
}
