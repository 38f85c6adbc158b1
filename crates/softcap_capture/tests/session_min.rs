//! Accuracy of the capture stage on the session-min fixture against its truth/ (which only tests read).

use crate::common;

use softcap_capture::{CaptureSettings, MarkerSource, Session, capture};

fn check(source: MarkerSource) -> common::Accuracy {
    let session = Session::load(&common::fixture("session-min")).unwrap();
    let settings = CaptureSettings {
        source,
        ..Default::default()
    };
    let r = capture(&session, &settings).unwrap();
    let a = common::accuracy("session-min", &r);
    println!("session-min from {source:?}: {a:#?}");
    println!("sync: {:?}", r.sync);
    println!("cameras: {:#?}", r.cameras);
    a
}

fn assert_done_when(a: &common::Accuracy) {
    assert!(
        a.marker_rms_mm <= 0.3,
        "marker RMS {:.3} mm",
        a.marker_rms_mm
    );
    assert!(
        a.force_rms_n <= 0.02 * a.force_max_n,
        "force RMS {:.4} N vs max {:.3} N",
        a.force_rms_n,
        a.force_max_n
    );
    assert!(a.tip_rms_mm <= 0.5, "tip RMS {:.3} mm", a.tip_rms_mm);
    assert!(
        a.clock_offset_error_ms <= 2.0,
        "clock offset error {:.3} ms",
        a.clock_offset_error_ms
    );
    assert_eq!(a.missing, 0, "every marker is visible or filled");
}

#[test]
fn session_min_from_detections_meets_accuracy() {
    assert_done_when(&check(MarkerSource::Detections));
}

#[test]
fn session_min_from_images_meets_accuracy() {
    assert_done_when(&check(MarkerSource::Images));
}

/// Without a trigger line the clocks come from the data: probe depth against FSR force, offset by
/// maximum correlation, then offset + drift by least squares. session-min with `trigger_v` removed
/// from fsr.csv must give the offset within 3 ms of truth/clock.toml.
#[test]
fn session_min_without_trigger_line_syncs_from_the_data() {
    let (_tmp, dir) = common::session_copy("session-min");
    let fsr = dir.join("fsr.csv");
    let text = std::fs::read_to_string(&fsr).unwrap();
    let stripped: String = text
        .lines()
        .map(|l| l.rsplit_once(',').unwrap().0.to_string() + "\n")
        .collect();
    assert!(stripped.starts_with("t_daq_s,voltage_v\n"));
    std::fs::write(&fsr, stripped).unwrap();
    let session = Session::load(&dir).unwrap();
    assert!(session.fsr_samples.as_ref().unwrap().trigger_v.is_none());
    let settings = CaptureSettings {
        source: MarkerSource::Detections,
        ..Default::default()
    };
    let r = capture(&session, &settings).unwrap();
    let s = r.sync.unwrap();
    let a = common::accuracy("session-min", &r);
    println!("data sync: {s:?}");
    println!("accuracy: {a:#?}");
    assert_eq!(s.method, softcap_capture::SyncMethod::Data);
    assert!(
        a.clock_offset_error_ms <= 3.0,
        "clock offset error {:.3} ms",
        a.clock_offset_error_ms
    );
    assert!(s.residual.is_finite() && s.residual_force_n.is_finite());
    assert!(s.correlation > 0.9, "correlation {}", s.correlation);
}
