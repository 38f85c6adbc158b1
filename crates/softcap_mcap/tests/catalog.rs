//! The catalog agrees with the embedded schema and with `docs/formats.md`.

use softcap_mcap::{CATALOG, descriptor_pool, message_names, topics};

#[test]
fn every_catalog_schema_is_in_the_descriptor_set() {
    let pool = descriptor_pool();
    for name in message_names() {
        assert!(pool.get_message_by_name(&name).is_some(), "{name}");
    }
    for row in CATALOG {
        assert!(
            pool.get_message_by_name(row.schema).is_some(),
            "{} → {}",
            row.topic,
            row.schema
        );
    }
}

#[test]
fn topic_constants_are_in_the_catalog() {
    let constants = [
        (topics::SURFACE_MESH.name().to_string(), "softcap.TriMesh"),
        (topics::VOLUME_MESH.name().to_string(), "softcap.TetMesh"),
        (topics::MARKERS.name().to_string(), "softcap.MarkerFrame"),
        (topics::PROBE.name().to_string(), "softcap.ProbeSample"),
        (topics::CLOCK_SYNC.name().to_string(), "softcap.ClockSync"),
        (
            topics::CAMERA_STATS.name().to_string(),
            "softcap.CameraStats",
        ),
        (topics::CAPTURE_REPORT.name().to_string(), "softcap.Report"),
        (topics::SESSION.name().to_string(), "softcap.SessionInfo"),
        (
            topics::ELEMENT_MATERIAL.name().to_string(),
            "softcap.ElementMaterial",
        ),
        (
            topics::STRAIN_SPACE_BASIS.name().to_string(),
            "softcap.StrainSpaceBasis",
        ),
        (
            topics::SIMULATED_MARKERS.name().to_string(),
            "softcap.SimulatedMarkers",
        ),
        (topics::TISSUE_REPORT.name().to_string(), "softcap.Report"),
        (
            topics::SIMULATED_PROBE.name().to_string(),
            "softcap.ProbeSample",
        ),
        (topics::DEFORMED_MESH.name().to_string(), "softcap.TetMesh"),
        (topics::DIAGNOSIS.name().to_string(), "softcap.Diagnosis"),
        (
            topics::EXTENDED_MODEL.name().to_string(),
            "softcap.ExtendedModel",
        ),
        (
            topics::BASELINE_MARKERS.name().to_string(),
            "softcap.SimulatedMarkers",
        ),
        (
            topics::EXTENDED_MARKERS.name().to_string(),
            "softcap.SimulatedMarkers",
        ),
        (topics::DIAGNOSE_REPORT.name().to_string(), "softcap.Report"),
        (topics::FACE_MESH.name().to_string(), "softcap.TriMesh"),
        (
            topics::FACE_WRINKLES.name().to_string(),
            "softcap.FaceWrinkles",
        ),
        (
            topics::FACE_TRACK_CAMERAS.name().to_string(),
            "softcap.FaceCameras",
        ),
        (
            topics::FACE_TRACK_WRINKLES.name().to_string(),
            "softcap.WrinkleTrackFrame",
        ),
        (topics::DESIGN_REPORT.name().to_string(), "softcap.Report"),
        (
            topics::RESHAPE_TEMPLATE.name().to_string(),
            "softcap.TetMesh",
        ),
        (
            topics::PLASTIC_STRAINS.name().to_string(),
            "softcap.PlasticStrains",
        ),
        (
            topics::RESHAPE_CONSTRAINTS.name().to_string(),
            "softcap.ReshapeConstraints",
        ),
        (
            topics::RESHAPE_QUALITY.name().to_string(),
            "softcap.ReshapeQuality",
        ),
        (topics::RESHAPE_REPORT.name().to_string(), "softcap.Report"),
        (
            topics::DYNAMIC_SESSION.name().to_string(),
            "softcap.DynamicSession",
        ),
        (topics::POINTS.name().to_string(), "softcap.PointCloudFrame"),
        (topics::TRACK_NODES.name().to_string(), "softcap.NodeFrame"),
        (
            topics::TRACK_STATUS.name().to_string(),
            "softcap.TrackStatus",
        ),
        (topics::TRACK_REPORT.name().to_string(), "softcap.Report"),
        (
            topics::DYNAMIC_MATERIAL.name().to_string(),
            "softcap.DynamicMaterial",
        ),
        (
            topics::DYNAMIC_FIT_REPORT.name().to_string(),
            "softcap.Report",
        ),
        (
            topics::DYNAMIC_SIM_NODES.name().to_string(),
            "softcap.NodeFrame",
        ),
    ];
    assert_eq!(constants.len(), CATALOG.len());
    for (topic, schema) in constants {
        let row = CATALOG.iter().find(|r| r.topic == topic).expect(&topic);
        assert_eq!(row.schema, schema);
    }
}

#[test]
fn formats_doc_lists_every_channel_and_message() {
    let doc_path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/formats.md");
    let doc = std::fs::read_to_string(doc_path).expect("docs/formats.md exists");
    for row in CATALOG {
        assert!(
            doc.contains(&format!("`{}`", row.topic)),
            "formats.md lacks {}",
            row.topic
        );
    }
    for name in message_names() {
        assert!(
            doc.contains(&format!("`{name}`")),
            "formats.md lacks {name}"
        );
    }
}
