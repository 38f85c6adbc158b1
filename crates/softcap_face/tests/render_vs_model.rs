//! The Monte-Carlo 3D ambient-occlusion renderer and the 2.5D visible-wedge model (thesis
//! eq. 4.3–4.4) are independent; on the straight middle part of a long wrinkle they must agree.

use softcap_face::{
    AoRenderSettings, HorizonSettings, WrinkleScene, ambient_ratio, render_ambient_occlusion,
};

#[test]
fn monte_carlo_occlusion_matches_wedge_integral_mid_wrinkle() {
    // Only the middle column is compared: shift the default wrinkle so its middle is column 0
    // of a 1-pixel-wide image.
    let mut scene = WrinkleScene::default();
    scene.arc_center_px[0] = 0.0;
    scene.width_px = 1;
    let frame = render_ambient_occlusion(&scene, &AoRenderSettings::default());
    let hs = HorizonSettings::default();
    let mut worst: f64 = 0.0;
    let mut n = 0;
    let mut sum_sq = 0.0;
    let x = 0;
    for y in 0..scene.height_px {
        let (p, s) = scene.valley_coordinates(x as f64, y as f64);
        assert!((s - scene.length_px() / 2.0).abs() < 1.0);
        if p.abs() > 12.0 {
            continue;
        }
        let model = ambient_ratio(scene.width_w_px, scene.depth_d_px, p, &hs).ratio;
        let mc = frame.occlusion[y * scene.width_px + x];
        worst = worst.max((mc - model).abs());
        sum_sq += (mc - model).powi(2);
        n += 1;
    }
    let rms = (sum_sq / n as f64).sqrt();
    eprintln!("MC vs 2.5D model over {n} pixels: rms {rms:.4}, max {worst:.4}");
    // 576 stratified rays per pixel: MC standard error ≲ 0.01.
    assert!(rms < 0.01, "rms {rms}");
    assert!(worst < 0.03, "max {worst}");
}
