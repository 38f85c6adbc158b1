//! Accuracy of `softcap face track` on a rendered take (issue 32; docs/face.md "Measured"):
//!
//! ```sh
//! softcap face synth-take … --frames 60 -o TAKE
//! softcap face track TAKE --face … --landmarks … -o TAKE.wrinkles.mcap
//! cargo run --profile test -p softcap_face --example take_accuracy -- TAKE TAKE.wrinkles.mcap
//! ```
//!
//! Prints the [`score_track`] of the track against the take's `truth.json`, for (d, w) scored at
//! true d/w ≥ 0.3 and ≥ 0.2 (the second includes the ramp frames of the appearing wrinkle).

use std::path::PathBuf;

use softcap_face::take_synth::{TakeTruth, score_track};
use softcap_mcap::reader::Recording;
use softcap_mcap::topics;

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
    for min_ratio in [0.3, 0.2] {
        let s = score_track(&truth, &frames, min_ratio);
        println!(
            "d/w ≥ {min_ratio}: {} scored (camera × frame × wrinkle), {} missed; valleys max {:.3} px, RMS {:.3} px; \
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
    Ok(())
}
