//! `softcap inspect export --what markers` writes the session's marker ids, so the exported CSV
//! lines up row for row with the session's `truth/markers.csv` (`frame,id,x,y,z`).

use std::collections::BTreeMap;
use std::path::Path;

use softcap_capture::{CaptureSettings, Session, capture, write_capture_mcap};
use softcap_synth::{Scenario, synthesize};

/// `(frame, id) → [x, y, z]` of a `frame,id,x,y,z` CSV, coordinates scaled by `scale`.
fn rows(path: &Path, scale: f64) -> BTreeMap<(u64, String), [f64; 3]> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("frame,id,x,y,z"), "{}", path.display());
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let p = |k: usize| scale * f[k].parse::<f64>().unwrap();
            (
                (f[0].parse().unwrap(), f[1].to_string()),
                [p(2), p(3), p(4)],
            )
        })
        .collect()
}

#[test]
fn exported_marker_ids_line_up_with_the_session_truth() {
    let tmp = tempfile::tempdir().unwrap();
    let mut scenario = Scenario::load(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../fixtures/scenarios/suite/clean.toml")
            .as_path(),
    )
    .unwrap();
    scenario.protocol.locations = 1;
    let session_dir = tmp.path().join("session");
    synthesize(&scenario, &session_dir).unwrap();
    let session = Session::load(&session_dir).unwrap();
    let settings = CaptureSettings::default();
    let result = capture(&session, &settings).unwrap();
    let mcap = tmp.path().join("capture.mcap");
    write_capture_mcap(&mcap, &session, &result, &settings, &[]).unwrap();

    let csv = tmp.path().join("markers.csv");
    let recording = softcap_mcap::Recording::open(&mcap).unwrap();
    softcap_cli::export::export(&recording, "markers", &csv).unwrap();

    // The synthetic session's length unit is mm; the export is in metres.
    let truth = rows(&session_dir.join("truth/markers.csv"), 1e-3);
    let exported = rows(&csv, 1.0);
    let mut matched = 0;
    let mut sum_sq = 0.0;
    for (key, t) in &truth {
        let Some(e) = exported.get(key) else { continue };
        matched += 1;
        sum_sq += (0..3).map(|k| (e[k] - t[k]).powi(2)).sum::<f64>();
    }
    // Every object marker of every frame (capture sees or fills them all on the clean suite
    // scenario) is found under its session id, and the rows sit where the truth puts them: the
    // marker RMS bound of the capture suite (tests/capture_reads_synth.rs).
    assert_eq!(matched, truth.len(), "truth rows matched by (frame, id)");
    let rms_m = (sum_sq / matched as f64).sqrt();
    assert!(rms_m < 0.3e-3, "marker RMS {:.4} mm", rms_m * 1e3);
    // The rows absent from the truth are the probe's shaft markers, named as the session names them.
    let truth_ids: std::collections::BTreeSet<&str> = truth.keys().map(|k| k.1.as_str()).collect();
    let extra: std::collections::BTreeSet<&str> = exported
        .keys()
        .map(|k| k.1.as_str())
        .filter(|id| !truth_ids.contains(id))
        .collect();
    assert!(
        extra
            .iter()
            .all(|id| result.marker_ids[result.object_markers..]
                .iter()
                .any(|s| s == id)),
        "ids neither in truth nor shaft markers: {extra:?}"
    );
}
