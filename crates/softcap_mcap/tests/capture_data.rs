//! `CaptureData::read`: round trip of a small capture, probe-location grouping, and bad input
//! errors that name the file, channel and field.

use softcap_mcap::capture::{CaptureData, Phase, ProbeLocationSettings};
use softcap_mcap::{Error, Provenance, Writer, proto, topics};

fn v(x: f64, y: f64, z: f64) -> Option<proto::Vec3> {
    Some(proto::Vec3 { x, y, z })
}

fn session() -> proto::SessionInfo {
    proto::SessionInfo {
        name: "t".into(),
        kind: "probe".into(),
        marker_ids: vec!["a".into(), "b".into(), "shaft0".into()],
        object_markers: 2,
        rest_positions_m: vec![v(0.0, 0.0, 0.02).unwrap(), v(0.01, 0.0, 0.02).unwrap()],
        gravity_m_s2: v(0.0, 0.0, -9.81),
        support: Some(proto::SupportPlane {
            normal: v(0.0, 0.0, 2.0),
            offset_m: 0.0,
            tolerance_m: 1e-4,
        }),
        density_kg_m3: Some(1000.0),
        tip_shape: "sphere".into(),
        tip_radius_m: 0.004,
        shaft_direction: "handle-to-tip".into(),
        trigger_present: true,
        ..Default::default()
    }
}

/// Force profile of two locations: 0 (rest), ramp 1,2,3, hold 3, unload 1, 0, then at another
/// place ramp 2, 4, unload 1, 0.
const FORCES: [f64; 12] = [0.0, 1.0, 2.0, 3.0, 3.0, 1.0, 0.0, 2.0, 4.0, 1.0, 0.0, 0.0];

fn write(path: &std::path::Path, edit: impl Fn(u64, &mut proto::MarkerFrame)) {
    let mut w = Writer::create(path, &Provenance::new("capture", "0")).unwrap();
    w.write_static(&topics::SESSION, &session()).unwrap();
    for (k, &f) in FORCES.iter().enumerate() {
        let frame = k as u64;
        let x = if k < 7 { 0.0 } else { 0.02 };
        let mut m = proto::MarkerFrame {
            frame,
            t_camera_s: 0.1 * k as f64,
            markers: vec![
                proto::Marker {
                    id: 1,
                    position_m: v(0.01, 0.0, 0.02 - 1e-4 * f),
                    visible: true,
                    ..Default::default()
                },
                proto::Marker {
                    id: 0,
                    position_m: v(0.0, 0.0, 0.02),
                    filled: true,
                    ..Default::default()
                },
            ],
        };
        edit(frame, &mut m);
        let t = frame * 100_000_000;
        w.write(&topics::MARKERS, t, &m).unwrap();
        w.write(
            &topics::PROBE,
            t,
            &proto::ProbeSample {
                frame,
                t_camera_s: 0.1 * k as f64,
                tip_m: v(x, 0.0, 0.02 - 1e-4 * f),
                axis: v(0.0, 0.0, -1.0),
                force_n: v(0.0, 0.0, -f),
                voltage_v: f,
            },
        )
        .unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn round_trip_joins_frames_and_groups_locations() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("capture.mcap");
    write(&path, |_, _| {});
    let c = CaptureData::read(&path).unwrap();
    assert_eq!(c.session.marker_ids.len(), 3);
    assert_eq!(c.session.support.unwrap().normal, [0.0, 0.0, 1.0]);
    assert_eq!(c.session.density_kg_m3, Some(1000.0));
    assert_eq!(c.frames.len(), FORCES.len());
    // Markers sorted by id even though written out of order.
    assert_eq!(c.frames[3].markers[0].id, 0);
    assert!(c.frames[3].marker(0).unwrap().filled);
    assert!((c.frames[3].marker(1).unwrap().position_m[2] - (0.02 - 3e-4)).abs() < 1e-15);
    assert_eq!(c.frames[8].probe.unwrap().force_n, Some([0.0, 0.0, -4.0]));
    let locs = c.probe_locations(&ProbeLocationSettings::default());
    assert_eq!(locs.len(), 2);
    assert_eq!(locs[0].frames, vec![1, 2, 3, 4, 5]);
    assert_eq!(
        locs[0].phases,
        vec![
            Phase::Loading,
            Phase::Loading,
            Phase::Loading,
            Phase::Hold,
            Phase::Unloading
        ]
    );
    assert_eq!(locs[0].peak, 2);
    assert_eq!(locs[1].frames, vec![7, 8, 9]);
    assert_eq!(locs[1].peak_force_n, 4.0);
    let phases = c.phases(&locs);
    assert_eq!(phases[0], Phase::Rest);
    assert_eq!(phases[6], Phase::Released);
    assert_eq!(phases[11], Phase::Released);
}

#[test]
fn non_finite_marker_names_frame_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("capture.mcap");
    write(&path, |frame, m| {
        if frame == 4 {
            m.markers[0].position_m = v(f64::NAN, 0.0, 0.0);
        }
    });
    let e = CaptureData::read(&path).unwrap_err();
    let text = e.to_string();
    assert!(matches!(e, Error::Invalid { .. }), "{text}");
    assert!(
        text.contains("capture.mcap") && text.contains("frame 4 markers[0].position_m"),
        "{text}"
    );
}

#[test]
fn marker_id_out_of_range_and_missing_session_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("capture.mcap");
    write(&path, |frame, m| {
        if frame == 2 {
            m.markers[1].id = 9;
        }
    });
    let text = CaptureData::read(&path).unwrap_err().to_string();
    assert!(text.contains("frame 2 markers[1].id"), "{text}");

    let bare = dir.path().join("bare.mcap");
    let mut w = Writer::create(&bare, &Provenance::new("capture", "0")).unwrap();
    w.write(&topics::MARKERS, 0, &proto::MarkerFrame::default())
        .unwrap();
    w.finish().unwrap();
    let e = CaptureData::read(&bare).unwrap_err();
    assert!(
        matches!(&e, Error::MissingChannel { topic, .. } if topic == "/capture/session"),
        "{e}"
    );
}
