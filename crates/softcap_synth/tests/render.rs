//! Rendered marker discs: their intensity-weighted centroids sit on the projected truth.

use softcap_synth::nalgebra::Vector2;
use softcap_synth::render::{CameraRays, background, paint, render_frame};
use softcap_synth::rig::{cameras, visible};
use softcap_synth::{Scenario, simulate, truth::stream};

/// Covered fraction of a pixel: the colour change from the marker-free image projected on the
/// paint-minus-background direction, α = (I − B)·(P − B) / ‖P − B‖².
fn alpha(i: [u8; 3], b: [u8; 3], p: [u8; 3]) -> f64 {
    let d: Vec<f64> = (0..3).map(|k| p[k] as f64 - b[k] as f64).collect();
    let e: Vec<f64> = (0..3).map(|k| i[k] as f64 - b[k] as f64).collect();
    let n2: f64 = d.iter().map(|x| x * x).sum();
    (d.iter().zip(&e).map(|(a, b)| a * b).sum::<f64>() / n2).clamp(0.0, 1.0)
}

#[test]
fn rendered_marker_centroids_are_within_005_px_of_the_projected_truth() {
    let mut s = Scenario::default();
    s.object.fit_cells = [4, 4, 2];
    s.object.truth_cells = [6, 6, 3];
    s.protocol.locations = 1;
    s.protocol.ramp_frames = 2;
    s.protocol.hold_frames = 0;
    s.protocol.release_frames = 1;
    s.protocol.move_frames = 0;
    let truth = simulate(&s, &mut stream(s.seed, 1)).unwrap();
    let cams = cameras(&s, &truth.block.size_m).unwrap();
    let paint_rgb = paint(&s.object.marker_color);
    let (mut n, mut sum, mut max) = (0usize, 0.0, 0.0f64);
    let mut signed = Vector2::zeros();
    // Frame 0 (probe lifted) and frame 2 (full depth: tilted, indented discs around the probe).
    for frame in [0usize, 2] {
        let f = &truth.frames[frame];
        for (k, cam) in cams.iter().enumerate() {
            let rays = CameraRays::new(cam);
            let base = background(
                &rays,
                &truth.block.size_m,
                s.output.texture_contrast,
                k as u64,
            );
            let r = s.object.marker_radius_mm * 1e-3;
            let with = render_frame(
                &base,
                &rays,
                &truth,
                f,
                "blue",
                r,
                s.output.supersample,
                true,
            );
            let without = render_frame(
                &base,
                &rays,
                &truth,
                f,
                "blue",
                r,
                s.output.supersample,
                false,
            );
            for p in visible(&truth, "blue", cam, f) {
                if p.id.starts_with("shaft") {
                    continue;
                }
                let (u0, v0) = (p.uv.x.round() as i64, p.uv.y.round() as i64);
                // A circular window of the projected disc radius + 2 px keeps neighbours out.
                let depth = (cam.to_camera(&p.position_m.into())).z;
                let rad_px = cam.focal_px() * r / depth + 2.0;
                let win = rad_px.ceil() as i64;
                let (mut sw, mut su, mut sv, mut near_probe) = (0.0, 0.0, 0.0, false);
                for v in v0 - win..=v0 + win {
                    for u in u0 - win..=u0 + win {
                        if u < 0 || v < 0 || u >= cam.width as i64 || v >= cam.height as i64 {
                            near_probe = true;
                            continue;
                        }
                        if ((u as f64 - p.uv.x).powi(2) + (v as f64 - p.uv.y).powi(2)).sqrt()
                            > rad_px
                        {
                            continue;
                        }
                        let (uu, vv) = (u as u32, v as u32);
                        let b = without.get_pixel(uu, vv).0;
                        if b != base.get_pixel(uu, vv).0 {
                            near_probe = true;
                        }
                        let w = alpha(with.get_pixel(uu, vv).0, b, paint_rgb);
                        sw += w;
                        su += w * u as f64;
                        sv += w * v as f64;
                    }
                }
                if near_probe || sw < 1.0 {
                    continue;
                }
                let c = Vector2::new(su / sw, sv / sw);
                let e = (c - p.uv).norm();
                signed += c - p.uv;
                n += 1;
                sum += e;
                max = max.max(e);
            }
        }
    }
    println!(
        "{n} rendered markers: centroid error mean {:.4} px, max {:.4} px, mean signed {:?}",
        sum / n as f64,
        max,
        signed / n as f64
    );
    assert!(n >= 60, "only {n} markers compared");
    assert!(max < 0.05, "max centroid error {max:.4} px");
}
