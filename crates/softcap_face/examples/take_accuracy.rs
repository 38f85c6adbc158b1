//! Accuracy of `softcap face track` on a rendered take (issue 32; docs/face.md "Measured"):
//!
//! ```sh
//! softcap face synth-take … --frames 60 -o TAKE
//! softcap face track TAKE --face … --landmarks … -o TAKE.wrinkles.mcap
//! cargo run --profile test -p softcap_face --example take_accuracy -- TAKE TAKE.wrinkles.mcap
//! ```
//!
//! Prints the [`score_track`] of the track against the take's `truth.json` for (d, w) scored at
//! true d/w ≥ 0.3, ≥ 0.2 and in every frame the wrinkle is present (true d > 0), then, per true
//! d/w, the error of the per-frame (d, w) (the median over the wrinkle's cross-sections: the
//! pooled profile when pooling is on) next to the pooled fit's own standard deviation σ
//! (σ̂²(JᵀJ)⁻¹, `softcap_face::pooled`): an error within ~2σ is at the noise floor of the frame.

use std::collections::BTreeMap;
use std::path::PathBuf;

use softcap_face::take_synth::{TakeTruth, score_track};
use softcap_mcap::reader::Recording;
use softcap_mcap::topics;

/// Per class of true d/w (index into [`EDGES`]): |d err|, |w err|, σ_d/d, σ_w/w per frame.
type Classes = BTreeMap<usize, Vec<[f64; 4]>>;

/// Lower edges of the true-d/w classes (the appearing wrinkle's ramp: 0.13, 0.27, then 0.4;
/// the other wrinkle 0.6–0.75).
const EDGES: [f64; 4] = [0.0, 0.2, 0.3, 0.5];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [take, mcap] = args.as_slice() else {
        return Err("usage: take_accuracy TAKE_DIR WRINKLES.mcap".into());
    };
    let truth: TakeTruth =
        serde_json::from_str(&std::fs::read_to_string(take.join("truth.json"))?)?;
    let frames: Vec<_> = Recording::open(mcap)?
        .read(&topics::FACE_TRACK_WRINKLES)?
        .into_iter()
        .map(|(_, f)| f)
        .collect();
    for (label, min_ratio) in [
        ("d/w ≥ 0.3", 0.3),
        ("d/w ≥ 0.2", 0.2),
        ("every present frame", f64::MIN_POSITIVE),
    ] {
        let s = score_track(&truth, &frames, min_ratio);
        println!(
            "{label}: {} scored (camera × frame × wrinkle), {} missed; valleys max {:.3} px, RMS {:.3} px; \
             per-frame median d max {:.2} %, w max {:.2} %; single sections d max {:.1} %, w max {:.1} %; \
             detection lag {} frames; {} false visible",
            s.scored,
            s.missed,
            s.valley_max_px,
            s.valley_rms_px,
            100.0 * s.depth_max_rel,
            100.0 * s.width_max_rel,
            100.0 * s.depth_section_max_rel,
            100.0 * s.width_section_max_rel,
            s.detection_lag_frames,
            s.false_visible
        );
    }
    let mut classes = Classes::new();
    for (c, id) in truth.cameras.iter().enumerate() {
        for f in frames.iter().filter(|f| &f.camera == id) {
            let Some(scene) = truth.scenes[c].get(f.frame as usize) else {
                continue;
            };
            for w in f.wrinkles.iter().filter(|w| w.status == "visible") {
                let Some(ws) = scene.wrinkles.get(w.id as usize) else {
                    continue;
                };
                if ws.depth_d_px <= 0.0 {
                    continue;
                }
                let median = |mut v: Vec<f64>| {
                    v.sort_by(f64::total_cmp);
                    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
                };
                let ok = || w.sections.iter().zip(&w.converged).filter(|(_, k)| **k);
                let d = median(ok().map(|(s, _)| s.depth_px).collect());
                let wd = median(ok().map(|(s, _)| s.width_px).collect());
                let ratio = ws.depth_d_px / ws.width_w_px;
                if ratio < 0.3 {
                    println!(
                        "{id} frame {} wrinkle {}: true d {:.3} px, w {:.3} px (d/w {ratio:.2}); \
                         d {:+.2} %, w {:+.2} %; σ_d {:.2} %, σ_w {:.2} %",
                        f.frame,
                        w.id,
                        ws.depth_d_px,
                        ws.width_w_px,
                        100.0 * (d / ws.depth_d_px - 1.0),
                        100.0 * (wd / ws.width_w_px - 1.0),
                        100.0 * w.depth_sigma_px / ws.depth_d_px,
                        100.0 * w.width_sigma_px / ws.width_w_px
                    );
                }
                classes
                    .entry(EDGES.iter().rposition(|&e| ratio >= e).unwrap_or(0))
                    .or_default()
                    .push([
                        (d / ws.depth_d_px - 1.0).abs(),
                        (wd / ws.width_w_px - 1.0).abs(),
                        w.depth_sigma_px / ws.depth_d_px,
                        w.width_sigma_px / ws.width_w_px,
                    ]);
            }
        }
    }
    println!("true d/w | frames | d err max, RMS | w err max, RMS | pooled σ_d/d, σ_w/w (median)");
    for (k, rows) in &classes {
        let max = |i: usize| rows.iter().map(|r| r[i]).fold(0.0, f64::max);
        let rms =
            |i: usize| (rows.iter().map(|r| r[i] * r[i]).sum::<f64>() / rows.len() as f64).sqrt();
        let med = |i: usize| {
            let mut v: Vec<f64> = rows.iter().map(|r| r[i]).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        println!(
            "{} | {} | {:.2} %, {:.2} % | {:.2} %, {:.2} % | {:.2} %, {:.2} %",
            EDGES
                .get(k + 1)
                .map_or(format!("≥ {}", EDGES[*k]), |hi| format!(
                    "{}–{hi}",
                    EDGES[*k]
                )),
            rows.len(),
            100.0 * max(0),
            100.0 * rms(0),
            100.0 * max(1),
            100.0 * rms(1),
            100.0 * med(2),
            100.0 * med(3)
        );
    }
    Ok(())
}
