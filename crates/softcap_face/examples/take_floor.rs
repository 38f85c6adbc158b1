//! The noise floor of one frame's (d, w) (issue 32; docs/face.md "Measured"): one camera's scene
//! of one frame of a rendered take (`truth.json`), rendered again with `RENDERS` ray and noise
//! seeds (written as 8-bit PNG and read back, as `face track` sees a take), and wrinkle `K`'s
//! pooled profile fitted on its true paint mask in each render:
//!
//! ```sh
//! cargo run --profile test -p softcap_face --example take_floor -- TAKE cam0 15 1 [RENDERS] [RAYS]
//! ```
//!
//! Prints the bias (mean error) and the spread (standard deviation) of d and w over the
//! renders next to the fit's own Cramér–Rao σ (σ̂²(JᵀJ)⁻¹, median over the renders) and the
//! σ of d given w exactly (√(C_dd − C_dw²/C_ww)): what a frame alone can hold, and what it holds
//! once its width is known from the neighbouring frames.

use std::path::PathBuf;

use softcap_face::take::read_png;
use softcap_face::take_synth::TakeTruth;
use softcap_face::{
    AoRenderSettings, AoSurface, TrackSettings, render_ambient_occlusion, track_wrinkle,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        return Err(
            "usage: take_floor TAKE_DIR CAMERA FRAME WRINKLE [RENDERS] [RAYS_PER_AXIS]".into(),
        );
    }
    let take = PathBuf::from(&args[0]);
    let (frame, k): (usize, usize) = (args[2].parse()?, args[3].parse()?);
    let renders: u64 = args.get(4).map_or(Ok(16), |s| s.parse())?;
    let rays: usize = args.get(5).map_or(Ok(12), |s| s.parse())?;
    let truth: TakeTruth =
        serde_json::from_str(&std::fs::read_to_string(take.join("truth.json"))?)?;
    let c = truth
        .cameras
        .iter()
        .position(|id| id == &args[1])
        .ok_or("no such camera")?;
    let scene = truth.scenes[c].get(frame).ok_or("no such frame")?;
    let ws = scene.wrinkles.get(k).ok_or("no such wrinkle")?;
    let (w, h) = (scene.width_px, scene.height_px);
    let patch: Vec<usize> = (0..w * h)
        .filter(|&i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            ws.painted(x, y) && scene.occluder(x, y).is_none()
        })
        .collect();
    let (d0, w0) = (ws.depth_d_px, ws.width_w_px);
    println!(
        "{} frame {frame} wrinkle {k}: true d {d0:.3} px, w {w0:.3} px (d/w {:.3}); {renders} renders, {} rays per pixel",
        args[1],
        d0 / w0,
        rays * rays
    );
    let dir = std::env::temp_dir().join(format!("take_floor_{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let settings = TrackSettings::default();
    let mut rows = Vec::new();
    for r in 0..renders {
        let render = AoRenderSettings {
            rays_per_axis: rays,
            seed: 1000 + r,
            ..Default::default()
        };
        let png = dir.join(format!("{r}.png"));
        render_ambient_occlusion(scene, &render)
            .image
            .write_png(&png)?;
        let image = read_png(&png, w as u32, h as u32)?;
        let t = track_wrinkle(&image, &patch, &settings)?;
        let p = t.profile.ok_or("no pooled profile")?;
        let cond = (p.depth_sigma_px.powi(2)
            - p.depth_width_cov_px2.powi(2) / p.width_sigma_px.powi(2))
        .max(0.0)
        .sqrt();
        println!(
            "  seed {}: d {:+.2} %, w {:+.2} %; σ_d {:.2} %, σ_w {:.2} %, σ_d|w {:.2} %",
            1000 + r,
            100.0 * (p.depth_px / d0 - 1.0),
            100.0 * (p.width_px / w0 - 1.0),
            100.0 * p.depth_sigma_px / d0,
            100.0 * p.width_sigma_px / w0,
            100.0 * cond / d0
        );
        rows.push([
            p.depth_px / d0 - 1.0,
            p.width_px / w0 - 1.0,
            p.depth_sigma_px / d0,
            p.width_sigma_px / w0,
            cond / d0,
        ]);
    }
    std::fs::remove_dir_all(&dir)?;
    let n = rows.len() as f64;
    let mean = |i: usize| rows.iter().map(|r| r[i]).sum::<f64>() / n;
    let sd = |i: usize| {
        let m = mean(i);
        (rows.iter().map(|r| (r[i] - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt()
    };
    let med = |i: usize| {
        let mut v: Vec<f64> = rows.iter().map(|r| r[i]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    println!(
        "d: bias {:+.2} %, spread {:.2} %, CR σ {:.2} %, σ given w {:.2} % | w: bias {:+.2} %, spread {:.2} %, CR σ {:.2} %",
        100.0 * mean(0),
        100.0 * sd(0),
        100.0 * med(2),
        100.0 * med(4),
        100.0 * mean(1),
        100.0 * sd(1),
        100.0 * med(3)
    );
    Ok(())
}
