//! `softcap face track` → `softcap face run` on the committed rendered take
//! (`fixtures/face-takes/forehead`: 12 frames, 2 cameras, Monte-Carlo ambient-occlusion renders of two
//! painted forehead wrinkles on the ICT face animated by the AnimFace jaw take; one wrinkle
//! slides and is partly covered by hair in camera 0, the other appears at frame 3 and is gone at
//! frame 9). The truth is the take's `truth.json`.

use std::path::{Path, PathBuf};
use std::process::Command;

use softcap_face::nalgebra::Vector3;
use softcap_face::take_synth::{TakeTruth, score_track};
use softcap_mcap::reader::Recording;
use softcap_mcap::topics;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
}

fn face_args(c: &mut Command) -> &mut Command {
    c.arg("--face")
        .arg(fixtures().join("ict-face/neutral.obj"))
        .arg("--landmarks")
        .arg(fixtures().join("animface-mocap/ict_landmarks.csv"))
}

fn track(take: &Path, out: &Path, report: Option<&Path>) -> std::process::Output {
    track_with_threads(take, out, report, None)
}

fn track_with_threads(
    take: &Path,
    out: &Path,
    report: Option<&Path>,
    threads: Option<usize>,
) -> std::process::Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_softcap-face"));
    if let Some(n) = threads {
        c.env("RAYON_NUM_THREADS", n.to_string());
    }
    c.arg("track").arg(take);
    face_args(&mut c).arg("-o").arg(out);
    if let Some(r) = report {
        c.arg("--report").arg(r);
    }
    c.output().unwrap()
}

#[test]
fn track_then_run_reproduces_the_rendered_wrinkles() {
    let take = fixtures().join("face-takes/forehead");
    let dir = tempfile::tempdir().unwrap();
    let wrinkles = dir.path().join("wrinkles.mcap");
    let report = dir.path().join("report");
    // the same bytes with 1 and 2 threads (the output path is part of the digested provenance)
    let mut digests = Vec::new();
    for threads in [1, 2] {
        let o = track_with_threads(&take, &wrinkles, Some(&report), Some(threads));
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        digests.push(Recording::open(&wrinkles).unwrap().digest().unwrap());
    }
    assert_eq!(digests[0], digests[1], "RAYON_NUM_THREADS 1 and 2 differ");
    for f in ["splines_cam0.png", "depth_width_cam1.png"] {
        assert!(report.join(f).is_file(), "{f}");
    }
    let truth: TakeTruth =
        serde_json::from_str(&std::fs::read_to_string(take.join("truth.json")).unwrap()).unwrap();
    let rec = Recording::open(&wrinkles).unwrap();
    let frames: Vec<_> = rec
        .read(&topics::FACE_TRACK_WRINKLES)
        .unwrap()
        .into_iter()
        .map(|(_, f)| f)
        .collect();
    assert_eq!(frames.len(), 2 * 12);
    // issue 32: valleys within 0.5 px, (d, w) within 5 % where visible, events within 2 frames.
    // (d, w) of a frame: the median over the wrinkle's cross-sections (the pooled profile,
    // smoothed in time with the process noise estimated from the take). Measured: valleys
    // ≤ 0.20 px; d/w ≥ 0.3: d 2.2 %, w 2.8 %; every frame the wrinkle is present (the
    // appearance ramps' d/w 0.27 and 0.13 too): d 4.2 %, w 4.4 % (docs/face.md).
    let s = score_track(&truth, &frames, 0.3);
    eprintln!("{s:#?}");
    assert!(s.valley_max_px < 0.5, "valley {} px", s.valley_max_px);
    assert!(s.depth_max_rel < 0.05, "depth {}", s.depth_max_rel);
    assert!(s.width_max_rel < 0.05, "width {}", s.width_max_rel);
    assert_eq!(s.missed, 0);
    let ramp = score_track(&truth, &frames, f64::MIN_POSITIVE);
    eprintln!("{ramp:#?}");
    assert!(
        ramp.depth_max_rel < 0.05 && ramp.width_max_rel < 0.05,
        "{ramp:?}"
    );
    assert_eq!(ramp.missed, 0);
    assert_eq!(s.false_visible, 0);
    assert!(
        s.detection_lag_frames <= 2,
        "lag {}",
        s.detection_lag_frames
    );

    // face run consumes the MCAP: every visible wrinkle's valley lands on the animated face and
    // reprojects onto its image valley
    let face = dir.path().join("face.mcap");
    let mut c = Command::new(env!("CARGO_BIN_EXE_softcap-face"));
    c.arg("run")
        .arg("--mocap")
        .arg(take.join("mocap.csv"))
        .arg("--wrinkles")
        .arg(&wrinkles);
    let o = face_args(&mut c).arg("-o").arg(&face).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rec = Recording::open(&face).unwrap();
    let meshes = rec.read(&topics::FACE_MESH).unwrap();
    assert_eq!(meshes.len(), 12);
    let cams = Recording::open(&wrinkles)
        .unwrap()
        .read_static(&topics::FACE_TRACK_CAMERAS)
        .unwrap();
    let cam = softcap_face::take_track::read_track_mcap(&wrinkles, 0.01).unwrap();
    let out = rec.read(&topics::FACE_WRINKLES).unwrap();
    assert_eq!(out.len(), 12, "every frame has a visible wrinkle");
    let mut worst: f64 = 0.0;
    let mut sections = 0;
    for (_, fw) in &out {
        for w in &fw.wrinkles {
            for s in &w.sections {
                let v = s.valley_m.as_ref().expect("projected");
                let x = Vector3::new(v.x, v.y, v.z) / 0.01;
                // the camera whose pixel this section came from reprojects it best
                let e = cam
                    .iter()
                    .filter_map(|i| i.camera.as_ref()?.project(&x))
                    .map(|p| (p[0] - s.valley_u_px).hypot(p[1] - s.valley_v_px))
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(e);
                assert!(s.depth_m > 0.0 && s.width_m > 0.0);
                sections += 1;
            }
        }
    }
    eprintln!(
        "{} cameras, {sections} projected sections, reprojection ≤ {worst:.2e} px",
        cams.cameras.len()
    );
    assert!(worst < 1e-6, "reprojection {worst} px");
}

/// The second, differently-made take (`fixtures/face-take-varying`: both wrinkles change depth
/// and width over time at their own rates, another seed and sample count; wrinkle 1 appears at
/// frame 2 and is gone at frame 8): the time prior's process noise is estimated from the take,
/// not set for the first generator. Measured: valleys ≤ 0.20 px; (d, w) in every frame a
/// wrinkle is present ≤ 4.6 % / 3.7 % (docs/face.md).
#[test]
fn a_take_whose_wrinkles_change_width_is_tracked_within_5_percent() {
    let take = fixtures().join("face-take-varying");
    let dir = tempfile::tempdir().unwrap();
    let wrinkles = dir.path().join("wrinkles.mcap");
    let o = track(&take, &wrinkles, None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let truth: TakeTruth =
        serde_json::from_str(&std::fs::read_to_string(take.join("truth.json")).unwrap()).unwrap();
    let frames: Vec<_> = Recording::open(&wrinkles)
        .unwrap()
        .read(&topics::FACE_TRACK_WRINKLES)
        .unwrap()
        .into_iter()
        .map(|(_, f)| f)
        .collect();
    let s = score_track(&truth, &frames, f64::MIN_POSITIVE);
    eprintln!("{s:#?}");
    assert!(s.valley_max_px < 0.5, "valley {} px", s.valley_max_px);
    assert!(
        s.depth_max_rel < 0.05 && s.width_max_rel < 0.05,
        "d {}, w {}",
        s.depth_max_rel,
        s.width_max_rel
    );
    assert_eq!((s.missed, s.false_visible), (0, 0));
    assert!(
        s.detection_lag_frames <= 2,
        "lag {}",
        s.detection_lag_frames
    );
}

/// Copy the fixture take (without truth) into `dst`.
fn copy_take(dst: &Path) {
    let src = fixtures().join("face-takes/forehead");
    for sub in ["", "frames", "frames/cam0", "frames/cam1", "labels"] {
        std::fs::create_dir_all(dst.join(sub)).unwrap();
        for e in std::fs::read_dir(src.join(sub)).unwrap() {
            let p = e.unwrap().path();
            if p.is_file() && p.file_name().unwrap() != "truth.json" {
                std::fs::copy(&p, dst.join(sub).join(p.file_name().unwrap())).unwrap();
            }
        }
    }
}

#[test]
fn bad_takes_exit_2_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("wrinkles.mcap");
    let check = |take: &Path, needle: &str| {
        let o = track(take, &out, None);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains(needle), "`{needle}` not in: {err}");
        assert!(!out.exists());
    };
    // a missing frame
    let t1 = dir.path().join("gap");
    copy_take(&t1);
    std::fs::remove_file(t1.join("frames/cam1/000005.png")).unwrap();
    check(&t1, "frames/cam1/000005.png: missing frame 5");
    // a camera without calibration
    let t2 = dir.path().join("uncalibrated");
    copy_take(&t2);
    std::fs::create_dir_all(t2.join("frames/cam2")).unwrap();
    check(&t2, "frames/cam2: camera `cam2` has no calibration");
    // a frame of the wrong size
    let t3 = dir.path().join("size");
    copy_take(&t3);
    let text = std::fs::read_to_string(t3.join("cameras.toml")).unwrap();
    std::fs::write(
        t3.join("cameras.toml"),
        text.replacen("width = 176", "width = 170", 1),
    )
    .unwrap();
    check(&t3, "labels/cam0.png: 176×120 px, the camera is 170×120 px");
    // no mocap
    let t4 = dir.path().join("nomocap");
    copy_take(&t4);
    std::fs::remove_file(t4.join("mocap.csv")).unwrap();
    check(&t4, "mocap.csv: missing");
}

#[test]
fn remove_cleans_the_region_of_the_scan_and_of_every_frame() {
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_softcap-face");
    let face = dir.path().join("face.mcap");
    let mut c = Command::new(exe);
    c.arg("run")
        .arg("--mocap")
        .arg(fixtures().join("animface-mocap/jaw_subset.csv"))
        .args(["--frames", "0,390"]);
    let o = face_args(&mut c).arg("-o").arg(&face).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let clean = dir.path().join("clean.mcap");
    let obj = dir.path().join("clean.obj");
    let mut c = Command::new(exe);
    c.arg("remove")
        .args(["--around", "ForeHead_M", "--radius", "1.5", "--frames"])
        .arg(&face)
        .arg("--obj")
        .arg(&obj);
    let o = face_args(&mut c).arg("-o").arg(&clean).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scan = softcap_mesh::read_obj(fixtures().join("ict-face/neutral.obj"))
        .unwrap()
        .to_tri_mesh();
    let cleaned = softcap_mesh::read_obj(&obj).unwrap().to_tri_mesh();
    let landmarks = softcap_face::parse_landmarks_csv(
        &std::fs::read_to_string(fixtures().join("animface-mocap/ict_landmarks.csv")).unwrap(),
        Path::new("ict_landmarks.csv"),
    )
    .unwrap();
    let centre = scan.vertices[landmarks
        .iter()
        .find(|l| l.marker == "ForeHead_M")
        .unwrap()
        .vertex];
    let (mut moved_in, mut moved_out) = (0.0f64, 0.0f64);
    for (a, b) in scan.vertices.iter().zip(&cleaned.vertices) {
        let m = (a - b).norm();
        if (a - centre).norm() <= 1.5 {
            moved_in = moved_in.max(m);
        } else {
            moved_out = moved_out.max(m);
        }
    }
    eprintln!("scan: region moved ≤ {moved_in:.2e} cm, outside ≤ {moved_out:.2e} cm");
    assert!(
        moved_out < 1e-5,
        "outside the region the scan is kept ({moved_out} cm)"
    );
    assert!(
        moved_in > 0.0 && moved_in < 0.2,
        "region smoothed by {moved_in} cm"
    );
    let rec = Recording::open(&clean).unwrap();
    assert_eq!(rec.read(&topics::FACE_MESH).unwrap().len(), 2);
    // bad region file: exit 2 naming file, line and field
    let region = dir.path().join("region.csv");
    std::fs::write(&region, "vertex\n12\n999999\n").unwrap();
    let mut c = Command::new(exe);
    c.arg("remove").arg("--region").arg(&region);
    let o = face_args(&mut c)
        .arg("-o")
        .arg(dir.path().join("x.mcap"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("region.csv:3: field `vertex`"), "{err}");
    assert!(!dir.path().join("x.mcap").exists());
}
