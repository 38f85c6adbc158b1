//! Round trips of every message type through a softcap file, read back by softcap and by the
//! plain `mcap` crate; digest stability; corrupt/truncated files; atomic writes.

use std::collections::BTreeSet;
use std::path::Path;

use prost::Message as _;
use softcap_mcap::proto::*;
use softcap_mcap::{Error, Provenance, Recording, Topic, Writer, topics, viz, viz_topic};

fn v(x: f64, y: f64, z: f64) -> Option<Vec3> {
    Some(Vec3 { x, y, z })
}

fn provenance(timestamp: &str) -> Provenance {
    let mut p = Provenance::new("test", env!("CARGO_PKG_VERSION"))
        .with_arguments(["softcap-test", "--seed", "3"])
        .with_seed(3)
        .with_settings("tolerance = 1e-6\n");
    p.git_commit = "0123456789abcdef".into();
    p.timestamp = timestamp.into();
    p
}

fn tri_mesh() -> TriMesh {
    TriMesh {
        name: "surface".into(),
        frame_id: "world".into(),
        positions_m: vec![
            0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01,
        ],
        triangles: vec![0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3],
    }
}

fn tet_mesh() -> TetMesh {
    TetMesh {
        name: "volume".into(),
        frame_id: "world".into(),
        positions_m: tri_mesh().positions_m,
        tets: vec![0, 1, 2, 3],
        surface_triangles: tri_mesh().triangles,
    }
}

fn marker_frame(frame: u64) -> MarkerFrame {
    MarkerFrame {
        frame,
        t_camera_s: frame as f64 / 30.0,
        markers: vec![
            Marker {
                id: 0,
                position_m: v(0.001 * frame as f64, 0.02, -0.003),
                visible: true,
                filled: false,
                views: 3,
                reprojection_error_px: 0.41,
            },
            Marker {
                id: 7,
                position_m: v(0.05, -0.01, 0.002),
                visible: false,
                filled: true,
                views: 0,
                reprojection_error_px: 0.0,
            },
        ],
    }
}

fn probe_sample(frame: u64) -> ProbeSample {
    ProbeSample {
        frame,
        t_camera_s: frame as f64 / 30.0,
        tip_m: v(0.01, 0.02, 0.03 - 0.001 * frame as f64),
        axis: v(0.0, 0.0, -1.0),
        force_n: v(0.1, -0.05, -2.5 * frame as f64),
        voltage_v: 1.25 + 0.1 * frame as f64,
    }
}

fn element_material() -> ElementMaterial {
    ElementMaterial {
        example: 2,
        frame: 14,
        lambda_pa: vec![1.2e4, 1.3e4],
        alpha_pa: vec![4.0e3, 4.5e3],
        strain: (0..12).map(|i| 1e-3 * i as f64).collect(),
        residual_m: 2.5e-4,
    }
}

fn basis() -> StrainSpaceBasis {
    StrainSpaceBasis {
        elements: 2,
        kernel: "r".into(),
        tail: "linear".into(),
        center_examples: vec![0, 3],
        centers_strain: (0..24).map(|i| 1e-3 * i as f64).collect(),
        weights: (0..8).map(|i| 100.0 * i as f64).collect(),
        tail_coefficients: (0..28).map(|i| i as f64).collect(),
        centers_per_tet: vec![2, 1],
        center_samples: vec![0, 3, 0, 0],
        lambda_floor_pa: vec![1e4, 2e4],
        nu_min: 0.0,
        nu_max: 0.49,
        lambda_ceiling_pa: vec![3e5, 4e5],
    }
}

fn simulated() -> SimulatedMarkers {
    SimulatedMarkers {
        frame: 5,
        example: 1,
        load_step: 9,
        ids: vec![0, 7],
        positions_m: vec![
            Vec3 {
                x: 0.1,
                y: 0.2,
                z: 0.3,
            },
            Vec3 {
                x: 0.0,
                y: -0.1,
                z: 0.0,
            },
        ],
        measured_m: vec![
            Vec3 {
                x: 0.1,
                y: 0.2,
                z: 0.31,
            },
            Vec3 {
                x: 0.0,
                y: -0.1,
                z: 0.01,
            },
        ],
    }
}

fn report() -> Report {
    Report {
        title: "capture".into(),
        entries: vec![
            KeyValue {
                key: "rms_reprojection_error".into(),
                unit: "px".into(),
                value: Some(key_value::Value::Number(0.37)),
            },
            KeyValue {
                key: "frames".into(),
                unit: String::new(),
                value: Some(key_value::Value::Integer(120)),
            },
            KeyValue {
                key: "method".into(),
                unit: String::new(),
                value: Some(key_value::Value::Text("triangulation".into())),
            },
            KeyValue {
                key: "converged".into(),
                unit: String::new(),
                value: Some(key_value::Value::Flag(true)),
            },
        ],
    }
}

const FRAME_NS: u64 = 33_333_333;

/// Writes one of every message type (and their viz twins) to `path`.
fn write_everything(path: &Path, timestamp: &str) {
    let mut w = Writer::create(path, &provenance(timestamp)).unwrap();
    w.write_static(&topics::SURFACE_MESH, &tri_mesh()).unwrap();
    w.write_static(&topics::VOLUME_MESH, &tet_mesh()).unwrap();
    w.write_foxglove(
        &viz_topic(topics::SURFACE_MESH.name()),
        0,
        &viz::trimesh_scene(&tri_mesh(), 0),
    )
    .unwrap();
    w.write_static(
        &topics::CLOCK_SYNC,
        &ClockSync {
            offset_s: 0.0123,
            drift: 2e-6,
            residual_s: 1e-4,
            method: "force-onset cross-correlation".into(),
            samples: 12,
        },
    )
    .unwrap();
    for cam in ["cam0", "cam1", "cam2"] {
        w.write_static(
            &topics::CAMERA_STATS,
            &CameraStats {
                camera_id: cam.into(),
                frames: 4,
                detections: 8,
                detections_used: 7,
                mean_reprojection_error_px: 0.3,
                rms_reprojection_error_px: 0.35,
                max_reprojection_error_px: 0.9,
            },
        )
        .unwrap();
    }
    w.write_static(&topics::CAPTURE_REPORT, &report()).unwrap();
    w.write_static(&topics::STRAIN_SPACE_BASIS, &basis())
        .unwrap();
    let settings = softcap_mcap::VizSettings::default();
    for frame in 0..4u64 {
        let t = frame * FRAME_NS;
        w.write(&topics::MARKERS, t, &marker_frame(frame)).unwrap();
        w.write_foxglove(
            &viz_topic(topics::MARKERS.name()),
            t,
            &viz::markers_scene(&marker_frame(frame), t, &settings),
        )
        .unwrap();
        w.write(&topics::PROBE, t, &probe_sample(frame)).unwrap();
        w.write_foxglove(
            &viz_topic(topics::PROBE.name()),
            t,
            &viz::probe_scene(&probe_sample(frame), t, &settings),
        )
        .unwrap();
        w.write(
            &Topic::<Scalar>::custom("/series/voltage"),
            t,
            &Scalar {
                name: "voltage".into(),
                value: 1.0 + frame as f64,
                unit: "V".into(),
            },
        )
        .unwrap();
    }
    w.write(&topics::ELEMENT_MATERIAL, 3 * FRAME_NS, &element_material())
        .unwrap();
    w.write(&topics::SIMULATED_MARKERS, 3 * FRAME_NS, &simulated())
        .unwrap();
    w.write_foxglove(
        "/viz/tf",
        0,
        &viz::frame_transform("world", "probe", [0.0, 0.0, 0.1], [0.0, 0.0, 0.0, 1.0], 0),
    )
    .unwrap();
    assert_eq!(w.finish().unwrap(), path);
}

#[test]
fn every_message_type_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("all.mcap");
    write_everything(&path, "2026-11-21T17:00:00.000000000Z");
    let r = Recording::open(&path).unwrap();

    assert_eq!(r.read_static(&topics::SURFACE_MESH).unwrap(), tri_mesh());
    assert_eq!(r.read_static(&topics::VOLUME_MESH).unwrap(), tet_mesh());
    assert_eq!(r.read_static(&topics::CLOCK_SYNC).unwrap().offset_s, 0.0123);
    let stats = r.read(&topics::CAMERA_STATS).unwrap();
    assert_eq!(stats.len(), 3);
    assert!(stats.iter().all(|(t, _)| *t == 0));
    assert_eq!(stats[2].1.camera_id, "cam2");
    assert_eq!(r.read_static(&topics::CAPTURE_REPORT).unwrap(), report());
    assert_eq!(r.read_static(&topics::STRAIN_SPACE_BASIS).unwrap(), basis());
    let markers = r.read(&topics::MARKERS).unwrap();
    assert_eq!(markers.len(), 4);
    for (frame, (t, m)) in markers.iter().enumerate() {
        assert_eq!(*t, frame as u64 * FRAME_NS);
        assert_eq!(*m, marker_frame(frame as u64));
    }
    let probe = r.read(&topics::PROBE).unwrap();
    assert_eq!(probe[3], (3 * FRAME_NS, probe_sample(3)));
    let scalars = r.read(&Topic::<Scalar>::custom("/series/voltage")).unwrap();
    assert_eq!(
        scalars.iter().map(|(_, s)| s.value).collect::<Vec<_>>(),
        [1.0, 2.0, 3.0, 4.0]
    );
    assert_eq!(
        r.read(&topics::ELEMENT_MATERIAL).unwrap(),
        vec![(3 * FRAME_NS, element_material())]
    );
    assert_eq!(
        r.read(&topics::SIMULATED_MARKERS).unwrap(),
        vec![(3 * FRAME_NS, simulated())]
    );

    // Foxglove twins decode as their foxglove types.
    let scene = r.messages_on("/viz/capture/markers").unwrap();
    assert_eq!(scene.len(), 4);
    assert_eq!(scene[0].schema_name, "foxglove.SceneUpdate");
    let update = foxglove::messages::SceneUpdate::decode(scene[1].data.as_slice()).unwrap();
    assert_eq!(update.entities[0].spheres.len(), 2);
    let tf = r.messages_on("/viz/tf").unwrap();
    assert_eq!(tf[0].schema_name, "foxglove.FrameTransform");

    // Provenance round-trips.
    assert_eq!(
        r.provenance().unwrap().unwrap(),
        provenance("2026-11-21T17:00:00.000000000Z")
    );
}

#[test]
fn read_back_by_plain_mcap_crate_with_summary_and_indexes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("plain.mcap");
    write_everything(&path, "2026-11-21T17:00:00.000000000Z");
    let bytes = std::fs::read(&path).unwrap();

    let summary = mcap::Summary::read(&bytes)
        .unwrap()
        .expect("summary section present");
    let stats = summary.stats.as_ref().expect("statistics record");
    // 2 meshes + 1 viz mesh + 1 sync + 3 cams + 1 report + 1 basis + 4*(2+2+1) + 1 + 1 + 1 tf
    assert_eq!(stats.message_count, 2 + 1 + 1 + 3 + 1 + 1 + 20 + 3);
    assert_eq!(stats.message_end_time, 3 * FRAME_NS);
    assert!(!summary.chunk_indexes.is_empty(), "chunk indexes present");
    assert_eq!(summary.metadata_indexes.len(), 1);
    for chunk in &summary.chunk_indexes {
        assert_eq!(chunk.compression, "zstd");
        // Message indexes: every chunk lists its messages per channel.
        let indexes = summary.read_message_indexes(&bytes, chunk).unwrap();
        let indexed: usize = indexes.values().map(|v| v.len()).sum();
        assert!(indexed > 0);
        for (channel, entries) in &indexes {
            for entry in entries {
                let m = summary.seek_message(&bytes, chunk, entry).unwrap();
                assert_eq!(m.channel.id, channel.id);
                assert_eq!(m.log_time, entry.log_time);
            }
        }
    }
    let total_indexed: usize = summary
        .chunk_indexes
        .iter()
        .map(|c| {
            summary
                .read_message_indexes(&bytes, c)
                .unwrap()
                .values()
                .map(Vec::len)
                .sum::<usize>()
        })
        .sum();
    assert_eq!(total_indexed as u64, stats.message_count);

    // Every schema is protobuf with a FileDescriptorSet that defines the named message, so
    // `mcap cat --json` and Foxglove can decode the channels.
    let mut names = BTreeSet::new();
    for schema in summary.schemas.values() {
        assert_eq!(schema.encoding, "protobuf");
        let pool = prost_reflect::DescriptorPool::decode(schema.data.as_ref()).unwrap();
        assert!(
            pool.get_message_by_name(&schema.name).is_some(),
            "{} in its own descriptor set",
            schema.name
        );
        names.insert(schema.name.clone());
    }
    assert!(names.contains("softcap.MarkerFrame"));
    assert!(names.contains("foxglove.SceneUpdate"));

    // And a plain linear read yields every message with its channel.
    let n = mcap::MessageStream::new(&bytes).unwrap().count();
    assert_eq!(n as u64, stats.message_count);
}

#[test]
fn digest_is_stable_across_writes_with_different_timestamps() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.mcap");
    let b = dir.path().join("b.mcap");
    write_everything(&a, "2026-11-21T17:00:00.000000000Z");
    write_everything(&b, "2031-01-01T00:00:00.5Z");
    let (ra, rb) = (Recording::open(&a).unwrap(), Recording::open(&b).unwrap());
    assert_ne!(
        ra.provenance().unwrap().unwrap().timestamp,
        rb.provenance().unwrap().unwrap().timestamp
    );
    let da = ra.digest().unwrap();
    assert_eq!(da.len(), 64);
    assert_eq!(da, rb.digest().unwrap());

    // A different message changes it; so does a different seed.
    let c = dir.path().join("c.mcap");
    let mut w = Writer::create(&c, &provenance("x")).unwrap();
    w.write(&topics::PROBE, 0, &probe_sample(1)).unwrap();
    w.finish().unwrap();
    let d = dir.path().join("d.mcap");
    let mut w = Writer::create(&d, &provenance("x")).unwrap();
    w.write(&topics::PROBE, 0, &probe_sample(2)).unwrap();
    w.finish().unwrap();
    let e = dir.path().join("e.mcap");
    let mut w = Writer::create(&e, &provenance("x").with_seed(4)).unwrap();
    w.write(&topics::PROBE, 0, &probe_sample(1)).unwrap();
    w.finish().unwrap();
    let digest = |p: &Path| Recording::open(p).unwrap().digest().unwrap();
    assert_ne!(digest(&c), digest(&d));
    assert_ne!(digest(&c), digest(&e));
}

#[test]
fn truncated_file_is_reported_with_its_path() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.mcap");
    write_everything(&path, "t");
    let bytes = std::fs::read(&path).unwrap();
    for cut in [bytes.len() - 1, bytes.len() / 2, 40, 9] {
        let p = dir.path().join(format!("cut{cut}.mcap"));
        std::fs::write(&p, &bytes[..cut]).unwrap();
        let err = Recording::open(&p).unwrap_err();
        assert!(matches!(err, Error::Truncated { .. }), "cut {cut}: {err}");
        let msg = err.to_string();
        assert!(
            msg.contains(&p.display().to_string()) && msg.contains("truncated"),
            "{msg}"
        );
    }
}

#[test]
fn corrupt_files_are_reported_with_their_path() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.mcap");
    write_everything(&path, "t");
    let bytes = std::fs::read(&path).unwrap();

    // Not an MCAP file at all.
    let p = dir.path().join("text.mcap");
    std::fs::write(&p, "frame,id,x,y,z\n").unwrap();
    let err = Recording::open(&p).unwrap_err();
    assert!(matches!(err, Error::Corrupt { .. }), "{err}");
    assert!(err.to_string().contains("magic"), "{err}");

    // Empty.
    let p = dir.path().join("empty.mcap");
    std::fs::write(&p, b"").unwrap();
    assert!(
        Recording::open(&p)
            .unwrap_err()
            .to_string()
            .contains("empty")
    );

    // A flipped byte inside the first chunk's compressed data: chunk CRC or zstd fails.
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let chunk = &summary.chunk_indexes[0];
    let mut bad = bytes.clone();
    let at = (chunk.chunk_start_offset + chunk.chunk_length - 8) as usize;
    bad[at] ^= 0x5a;
    let p = dir.path().join("flipped.mcap");
    std::fs::write(&p, &bad).unwrap();
    let err = Recording::open(&p).unwrap_err();
    assert!(matches!(err, Error::Corrupt { .. }), "{err}");
    assert!(err.to_string().contains(&p.display().to_string()), "{err}");

    // A garbage summary section.
    let mut bad = bytes.clone();
    let n = bad.len();
    for b in &mut bad[n - 200..n - 40] {
        *b = 0xff;
    }
    let p = dir.path().join("summary.mcap");
    std::fs::write(&p, &bad).unwrap();
    let err = Recording::open(&p).unwrap_err();
    assert!(
        matches!(err, Error::Corrupt { .. } | Error::Truncated { .. }),
        "{err}"
    );
}

#[test]
fn writer_dropped_without_finish_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.mcap");
    let tmps = || -> Vec<std::path::PathBuf> {
        std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| softcap_app::is_tmp_of(&path, p))
            .collect()
    };
    {
        let mut w = Writer::create(&path, &provenance("t")).unwrap();
        w.write(&topics::PROBE, 0, &probe_sample(0)).unwrap();
        assert_eq!(tmps().len(), 1, "writes go to one tmp file");
        assert!(!path.exists(), "final name appears only on finish");
    }
    assert!(tmps().is_empty());
    assert!(!path.exists());
    // An existing finished file is not touched by a failed rewrite.
    write_everything(&path, "t");
    let before = std::fs::read(&path).unwrap();
    {
        let mut w = Writer::create(&path, &provenance("t")).unwrap();
        w.write(&topics::PROBE, 0, &probe_sample(0)).unwrap();
    }
    assert_eq!(std::fs::read(&path).unwrap(), before);
    assert!(tmps().is_empty());
}

#[test]
fn wrong_type_and_missing_channel_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.mcap");
    write_everything(&path, "t");
    let r = Recording::open(&path).unwrap();
    let err = r
        .read(&Topic::<ProbeSample>::custom("/capture/markers"))
        .unwrap_err();
    assert!(matches!(err, Error::WrongSchema { .. }), "{err}");
    let err = r.read(&topics::TISSUE_REPORT).unwrap_err();
    assert!(matches!(err, Error::MissingChannel { .. }), "{err}");
    let err = r.read_static(&topics::MARKERS).unwrap_err();
    assert!(matches!(err, Error::NotStatic { count: 4, .. }), "{err}");

    // Writing two types on one topic is refused.
    let mut w = Writer::create(dir.path().join("x.mcap"), &provenance("t")).unwrap();
    w.write(&topics::PROBE, 0, &probe_sample(0)).unwrap();
    let err = w
        .write(
            &Topic::<Scalar>::custom("/capture/probe"),
            0,
            &Scalar::default(),
        )
        .unwrap_err();
    assert!(matches!(err, Error::WrongSchema { .. }), "{err}");
}

#[test]
fn provenance_hashes_input_files_and_folders() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("session/rig")).unwrap();
    std::fs::write(dir.path().join("session/session.toml"), "name = 'x'\n").unwrap();
    std::fs::write(dir.path().join("session/rig/fsr.toml"), "supply_v = 5.0\n").unwrap();
    std::fs::write(dir.path().join("abc"), "abc").unwrap();
    let p = Provenance::new("capture", "0.1.0")
        .with_input(dir.path().join("abc"))
        .unwrap()
        .with_input(dir.path().join("session"))
        .unwrap();
    assert_eq!(p.inputs.len(), 3);
    assert_eq!(
        p.inputs[0].sha256,
        "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    );
    assert!(p.inputs[1].path.ends_with("rig/fsr.toml"));
    assert!(p.inputs[2].path.ends_with("session.toml"));
    assert!(!p.arguments.is_empty());
    assert!(!p.git_commit.is_empty());
    let back = Provenance::from_metadata(Path::new("f.mcap"), &p.to_metadata()).unwrap();
    assert_eq!(back, p);

    let err = Provenance::with_input(p, dir.path().join("missing")).unwrap_err();
    assert!(err.to_string().contains("missing"), "{err}");
}

/// The messages added by the diagnose and face stages (nested messages included) round-trip
/// through a softcap file exactly.
#[test]
fn diagnose_and_face_messages_round_trip() {
    let number = |key: &str, v: f64, unit: &str| KeyValue {
        key: key.into(),
        unit: unit.into(),
        value: Some(key_value::Value::Number(v)),
    };
    let diagnosis = Diagnosis {
        verdict: "clock-offset".into(),
        ranked: vec![
            HypothesisScore {
                hypothesis: "clock-offset".into(),
                score: -412.5,
                heldout_rmse_before_m: 6.47e-5,
                heldout_rmse_after_m: 8.6e-6,
                params: vec![number("delta_s", 0.1, "s")],
                evidence_json: r#"{"time_shift_s":0.1}"#.into(),
            },
            HypothesisScore {
                hypothesis: "none".into(),
                score: 0.0,
                heldout_rmse_before_m: 6.47e-5,
                heldout_rmse_after_m: 6.47e-5,
                params: vec![],
                evidence_json: "{}".into(),
            },
        ],
        located: vec![LocatedResidual {
            region: "probed".into(),
            phase: "loading".into(),
            component: "probe-axis".into(),
            rmse_m: 7.1e-5,
        }],
        unexplained: Some(Unexplained {
            heldout_rmse_m: 7.0e-5,
            best_explained_rmse_m: 6.2e-5,
            noise_floor_m: 7.8e-6,
            cell: "free/released".into(),
            cell_rmse_m: 9.1e-5,
            location: Some(0),
            markers: vec![number("m0", 3.93e-4, "m")],
        }),
        outliers: vec![OutlierRun {
            marker: "m0".into(),
            marker_index: 0,
            first_frame: 24,
            last_frame: 63,
            first_time_s: 1.2,
            last_time_s: 3.15,
            step_m: 4.5e-4,
            observations: 40,
        }],
    };
    let extended = ExtendedModel {
        hypothesis: "clock-offset".into(),
        term: "t_force = t_camera - delta".into(),
        params: vec![number("delta_s", 0.1, "s")],
        base_material_sha256: "ab".repeat(32),
    };
    let wrinkles = FaceWrinkles {
        frame: 390,
        wrinkles: vec![Wrinkle {
            sections: vec![WrinkleSection {
                valley_u_px: 812.25,
                valley_v_px: 401.5,
                depth_px: 1.75,
                width_px: 6.5,
                depth_m: 8.0e-4,
                width_m: 2.1e-3,
                valley_m: v(0.01, 0.02, 0.1),
            }],
        }],
    };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stages.mcap");
    let mut w = Writer::create(&path, &provenance("2026-11-21T22:30:00Z")).unwrap();
    w.write_static(&topics::DIAGNOSIS, &diagnosis).unwrap();
    w.write_static(&topics::EXTENDED_MODEL, &extended).unwrap();
    w.write(&topics::FACE_WRINKLES, 13 * FRAME_NS, &wrinkles)
        .unwrap();
    w.finish().unwrap();

    let r = Recording::open(&path).unwrap();
    assert_eq!(r.read_static(&topics::DIAGNOSIS).unwrap(), diagnosis);
    assert_eq!(r.read_static(&topics::EXTENDED_MODEL).unwrap(), extended);
    assert_eq!(
        r.read(&topics::FACE_WRINKLES).unwrap(),
        vec![(13 * FRAME_NS, wrinkles)]
    );
}

/// Bounded resources (docs/reliability.md): a chunk declaring more uncompressed bytes than
/// `MAX_CHUNK_BYTES` — a decompression bomb, here 1 TiB claimed by a few hundred bytes — is
/// refused before anything is allocated, as bad input (exit code 2) naming the file.
#[test]
fn a_decompression_bomb_is_refused_as_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bomb.mcap");
    write_everything(&path, "t");
    let mut bytes = std::fs::read(&path).unwrap();
    let mut pos = 8;
    loop {
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        if bytes[pos] == 0x06 {
            bytes[pos + 9 + 16..pos + 9 + 24].copy_from_slice(&(1u64 << 40).to_le_bytes());
            break;
        }
        pos += 9 + len;
    }
    let e = Recording::from_bytes(&path, bytes).unwrap_err();
    assert!(e.to_string().contains("decompression bomb"), "{e}");
    assert!(e.to_string().contains("bomb.mcap"), "{e}");
    const { assert!(softcap_mcap::MAX_CHUNK_BYTES < 1 << 40) };
    assert_eq!(softcap_app::Error::from(e).exit_code(), 2);
}

/// The MCAP inputs that made a reader panic under the fuzzer (`fuzz/regressions/mcap_*`) are
/// corrupt-file errors: e.g. an attachment record in the summary section that ends inside its CRC.
#[test]
fn fuzz_regression_inputs_are_corrupt_file_errors() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/regressions");
    for target in ["mcap_recording", "mcap_typed"] {
        for entry in std::fs::read_dir(root.join(target)).unwrap() {
            let path = entry.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            let e = Recording::from_bytes(&path, bytes).unwrap_err();
            let clean = matches!(e, Error::Corrupt { .. } | Error::Truncated { .. });
            assert!(clean, "{}: {e}", path.display());
        }
    }
}
