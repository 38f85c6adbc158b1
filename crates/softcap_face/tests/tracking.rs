//! Thesis §4.3.1–4.3.2 end to end on rendered wrinkle "video": Monte-Carlo AO frames of a
//! wrinkle with known (d, w) and valley → RBF-SVM paint classification (trained on frame 0's
//! mask) → morphology → PCA + weighted B-spline valley → per-cross-section (d, w).

use softcap_face::morphology::{close, connected_components, open};
use softcap_face::{
    AoRenderSettings, SvmSettings, TrackSettings, WrinkleScene, classify_frames,
    render_ambient_occlusion, track_wrinkle,
};

#[test]
fn recovers_depth_width_and_valley_from_rendered_frames() {
    let settings = AoRenderSettings {
        rays_per_axis: 16,
        ..Default::default()
    };
    let truth = [(4.0, 3.0), (5.0, 2.0)];
    let scenes: Vec<WrinkleScene> = truth
        .iter()
        .map(|&(w, d)| WrinkleScene {
            width_w_px: w,
            depth_d_px: d,
            ..Default::default()
        })
        .collect();
    let frames: Vec<_> = scenes
        .iter()
        .map(|s| render_ambient_occlusion(s, &settings))
        .collect();
    let images: Vec<_> = frames.iter().map(|f| &f.image).collect();
    let masks = classify_frames(
        &frames[0].image,
        &frames[0].paint_mask,
        &images,
        &SvmSettings::default(),
    )
    .unwrap();
    for (k, scene) in scenes.iter().enumerate() {
        let (wpx, hpx) = (scene.width_px, scene.height_px);
        let agree = masks[k]
            .iter()
            .zip(&frames[k].paint_mask)
            .filter(|(a, b)| a == b)
            .count() as f64
            / masks[k].len() as f64;
        let clean = close(&open(&masks[k], wpx, hpx, 1), wpx, hpx, 1);
        let comps = connected_components(&clean, wpx, hpx);
        let tracked =
            track_wrinkle(&frames[k].image, &comps[0], &TrackSettings::default()).unwrap();
        assert!(tracked.sections.len() >= 4);
        let mut worst_valley: f64 = 0.0;
        let mut x = tracked.spline.x0 + 12.0;
        while x <= tracked.spline.x1 - 12.0 {
            let v = tracked.spline.eval(x);
            let q = scene.closest_valley_point(v.x, v.y);
            worst_valley = worst_valley.max(((v.x - q[0]).powi(2) + (v.y - q[1]).powi(2)).sqrt());
            x += 1.0;
        }
        let (w, d) = truth[k];
        let mut worst_d: f64 = 0.0;
        let mut worst_w: f64 = 0.0;
        let mut worst_section_valley: f64 = 0.0;
        for s in &tracked.sections {
            let q = scene.closest_valley_point(s.valley_px[0], s.valley_px[1]);
            worst_section_valley = worst_section_valley
                .max(((s.valley_px[0] - q[0]).powi(2) + (s.valley_px[1] - q[1]).powi(2)).sqrt());
            worst_d = worst_d.max((s.depth_px / d - 1.0).abs());
            worst_w = worst_w.max((s.width_px / w - 1.0).abs());
        }
        eprintln!(
            "frame {k}: true (d, w) = ({d}, {w}) px; SVM agreement {:.2} %; {} sections, d err max {:.2} %, w err max {:.2} %; valley err max {:.3} px (spline), {:.3} px (cross-section valleys)",
            100.0 * agree,
            tracked.sections.len(),
            100.0 * worst_d,
            100.0 * worst_w,
            worst_valley,
            worst_section_valley
        );
        for s in &tracked.sections {
            eprintln!(
                "   x {:6.1}: d {:.3} w {:.3} rms {:.4} conv {}",
                s.x, s.depth_px, s.width_px, s.rms, s.converged
            );
        }
        assert!(agree > 0.97, "classification agreement {agree}");
        assert!(worst_valley < 0.5, "valley {worst_valley} px");
        assert!(
            worst_section_valley < 0.5,
            "section valley {worst_section_valley} px"
        );
        // The wrinkle's (d, w) is the mean over its cross-sections.
        let mean_d = tracked.sections.iter().map(|s| s.depth_px).sum::<f64>()
            / tracked.sections.len() as f64;
        let mean_w = tracked.sections.iter().map(|s| s.width_px).sum::<f64>()
            / tracked.sections.len() as f64;
        eprintln!(
            "   mean d {mean_d:.3} ({:+.2} %), mean w {mean_w:.3} ({:+.2} %)",
            100.0 * (mean_d / d - 1.0),
            100.0 * (mean_w / w - 1.0)
        );
        // Thesis target: 5 % on both wrinkles (measured: d/w = 0.75 +0.3 % / +0.2 %, d/w = 0.4
        // +0.7 % / −0.1 %; docs/face.md).
        let (tol_d, tol_w) = (0.05, 0.05);
        assert!((mean_d / d - 1.0).abs() < tol_d, "mean depth {mean_d}");
        assert!((mean_w / w - 1.0).abs() < tol_w, "mean width {mean_w}");
        // every single cross-section within 5 % as well (measured ≤ 2.2 % in d, ≤ 3.3 % in w)
        assert!(worst_d < 0.05, "depth error {worst_d}");
        assert!(worst_w < 0.05, "width error {worst_w}");
    }
}
