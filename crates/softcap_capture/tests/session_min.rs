//! Accuracy of the capture stage on the session-min fixture against its truth/ (which only tests read).

mod common;

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
