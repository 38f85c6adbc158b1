//! `softcap capture calibrate`: bundle adjustment recovers a synthetic rig perturbed by known
//! errors to within its noise, keeps a known-distance scale, rejects the outliers; on the real
//! aniposelib rig it lowers the median per-point error ≥ 3× and matches aniposelib's own bundle
//! adjustment; bad input is exit code 2 naming it, with nothing written.

use crate::common;

use std::path::Path;
use std::process::Command;

use nalgebra::{Matrix3, Point3, Rotation3, Unit, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use softcap_capture::calibrate::{
    CalibrateSettings, CalibrationInput, CalibrationStatus, calibrate,
};
use softcap_capture::{Camera, PixelObservation, TriangulationSettings, triangulate};

/// Eight cameras on a ring 1.2 m from the origin, looking at it, 1280×1024, f ≈ 1000 px,
/// barrel distortion.
fn true_rig() -> Vec<Camera> {
    (0..8)
        .map(|i| {
            let a = i as f64 * std::f64::consts::TAU / 8.0;
            let centre = Vector3::new(1.2 * a.cos(), 1.2 * a.sin(), 0.3 + 0.1 * (i % 2) as f64);
            let z = (-centre).normalize();
            let x = z.cross(&Vector3::z()).normalize();
            let y = z.cross(&x);
            let r = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
            Camera::new(
                format!("cam{i}"),
                1280,
                1024,
                [
                    1000.0 + 5.0 * i as f64,
                    1001.0 + 5.0 * i as f64,
                    640.0,
                    512.0,
                ],
                [-0.12, 0.03, 0.0, 0.0, 0.0],
                r,
                -(r * centre),
            )
            .unwrap()
        })
        .collect()
}

struct Synthetic {
    truth: Vec<Camera>,
    input: CalibrationInput,
    /// Per point, whether each of its observations is an outlier.
    outlier: Vec<Vec<bool>>,
}

/// 500 points in a 0.6 m box, each seen by a random 70 % of the cameras (≥ 2), 0.5 px Gaussian
/// noise, 5 % of the observations moved 10–60 px; the rig perturbed (all cameras but cam0) by
/// 0.5° rotations about random axes, 5 mm centre shifts, and (all cameras) ±2 % focal.
fn synthetic(seed: u64) -> Synthetic {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let truth = true_rig();
    let noise = Normal::new(0.0, 0.5).unwrap();
    let mut points = Vec::new();
    let mut outlier = Vec::new();
    while points.len() < 500 {
        let x = Point3::new(
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
        );
        let mut obs = Vec::new();
        let mut out = Vec::new();
        for (c, cam) in truth.iter().enumerate() {
            let Some(uv) = cam.project(&x) else { continue };
            if rng.random::<f64>() > 0.7 {
                continue;
            }
            let mut uv = uv + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng));
            let is_outlier = rng.random::<f64>() < 0.05;
            if is_outlier {
                let a = rng.random_range(0.0..std::f64::consts::TAU);
                uv += rng.random_range(10.0..60.0) * Vector2::new(a.cos(), a.sin());
            }
            obs.push(PixelObservation { camera: c, uv });
            out.push(is_outlier);
        }
        if obs.len() >= 2 {
            points.push(obs);
            outlier.push(out);
        }
    }
    let perturbed: Vec<Camera> = truth
        .iter()
        .enumerate()
        .map(|(i, cam)| {
            let mut c = cam.clone();
            let f = 1.0 + if rng.random::<bool>() { 0.02 } else { -0.02 };
            c.intrinsics[0] *= f;
            c.intrinsics[1] *= f;
            if i > 0 {
                let axis = Unit::new_normalize(Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                ));
                let dir = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .normalize();
                let centre: Vector3<f64> = cam.centre_world().coords + 0.005 * dir;
                c.rotation = Rotation3::from_axis_angle(&axis, 0.5f64.to_radians()).into_inner()
                    * c.rotation;
                c.translation_m = -(c.rotation * centre);
            }
            c
        })
        .collect();
    Synthetic {
        truth,
        input: CalibrationInput {
            source: "synthetic".into(),
            cameras_path: "synthetic-rig.toml".into(),
            cameras: perturbed,
            points,
            length_unit: "m".into(),
        },
        outlier,
    }
}

/// Per-component RMS of the residuals of the clean observations, each point triangulated from
/// its clean views, corrected for the 3 point coordinates fitted per point.
fn clean_rms(rig: &[Camera], s: &Synthetic) -> f64 {
    let (mut sum, mut dof) = (0.0, 0.0);
    for (obs, out) in s.input.points.iter().zip(&s.outlier) {
        let clean: Vec<PixelObservation> = obs
            .iter()
            .zip(out)
            .filter(|(_, o)| !**o)
            .map(|(p, _)| *p)
            .collect();
        if clean.len() < 2 {
            continue;
        }
        let x = triangulate(rig, &clean, &TriangulationSettings::default())
            .unwrap()
            .position_m;
        for o in &clean {
            sum += (rig[o.camera].project(&x).unwrap() - o.uv).norm_squared();
        }
        dof += 2.0 * clean.len() as f64 - 3.0;
    }
    (sum / dof).sqrt()
}

#[test]
fn synthetic_rig_is_recovered_to_within_the_noise() {
    let s = synthetic(7);
    let truth = &s.truth;
    // The known distance: true |C(cam0) − C(cam4)| (cam4 is the farthest from cam0).
    let known = (truth[4].centre_world() - truth[0].centre_world()).norm();
    let mut settings = CalibrateSettings {
        scale_camera: Some("cam4".into()),
        scale_distance_m: Some(known),
        ..Default::default()
    };
    if let Ok(r) = std::env::var("REFINE") {
        settings.bundle.refine = softcap_capture::bundle::Refine::parse(&r).unwrap();
    }
    let cal = calibrate(&s.input, &settings, &mut |line| eprintln!("{line}")).unwrap();
    assert_eq!(
        cal.status,
        CalibrationStatus::Converged,
        "{}",
        cal.status_description()
    );

    let before = clean_rms(&s.input.cameras, &s);
    let after = clean_rms(&cal.refined, &s);
    let ideal = clean_rms(truth, &s);
    println!(
        "clean-observation RMS per component: perturbed {before:.3} px, refined {after:.3} px, true rig {ideal:.3} px (noise 0.5)"
    );
    assert!(before > 3.0, "the perturbation is visible: {before}");
    assert!(
        (after - 0.5).abs() < 0.05,
        "refined RMS {after} ≉ 0.5 px noise"
    );

    // The same adjustment started from the true rig: the optimum the noise allows. The perturbed
    // start must reach it; what is left against the truth is the estimator's noise.
    let mut from_truth = s.input.clone();
    from_truth.cameras = truth.clone();
    let optimum = calibrate(&from_truth, &settings, &mut |l| {
        eprintln!("truth-start: {l}")
    })
    .unwrap()
    .refined;
    let difference = |a: &Camera, b: &Camera| {
        let dr = a.rotation * b.rotation.transpose();
        (
            (a.centre_world() - b.centre_world()).norm() * 1e3,
            ((dr.trace() - 1.0) / 2.0)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees(),
            (a.focal_px() / b.focal_px() - 1.0).abs() * 100.0,
        )
    };
    let mut vs_optimum = (0.0f64, 0.0f64, 0.0f64);
    let mut worst_sigmas = 0.0f64;
    for (c, ((r, t), o)) in cal.refined.iter().zip(truth).zip(&optimum).enumerate() {
        let (dc, dr, df) = difference(r, t);
        let (oc, or, of) = difference(r, o);
        let sd = cal.parameter_std[c];
        let (sc, sr, sf) = (
            sd.centre_m * 1e3,
            sd.rotation_rad.to_degrees(),
            sd.focal_relative * 100.0,
        );
        println!(
            "{}: error vs truth: centre {dc:.3} mm (σ {sc:.3}), rotation {dr:.4}° (σ {sr:.4}), \
             focal {df:.3} % (σ {sf:.3}); vs the truth-started optimum {oc:.4} mm, {or:.5}°, {of:.4} %",
            r.id
        );
        if c > 0 {
            worst_sigmas = worst_sigmas.max(dc / sc).max(dr / sr);
        }
        worst_sigmas = worst_sigmas.max(df / sf);
        vs_optimum = (
            vs_optimum.0.max(oc),
            vs_optimum.1.max(or),
            vs_optimum.2.max(of),
        );
    }
    println!(
        "worst error vs truth: {worst_sigmas:.2} standard deviations; vs the truth-started \
         optimum: {:.4} mm, {:.5}°, {:.4} % (perturbation 5 mm, 0.5°, 2 %)",
        vs_optimum.0, vs_optimum.1, vs_optimum.2
    );
    // The errors left are the noise's (each within 4 σ of the estimate's own uncertainty) ...
    assert!(worst_sigmas < 4.0, "error of {worst_sigmas:.2} σ");
    // ... and the perturbed start reaches the optimum the truth-started one does.
    assert!(
        vs_optimum.0 < 0.5 && vs_optimum.1 < 0.05 && vs_optimum.2 < 0.2,
        "{vs_optimum:?}"
    );

    let kept = (cal.refined[4].centre_world() - cal.refined[0].centre_world()).norm();
    assert!(
        (kept - known).abs() < 1e-9 * known,
        "scale kept: {kept} vs {known}"
    );
    assert!(cal.gauge_description().contains("given"));

    let outliers: usize = s.outlier.iter().flatten().filter(|o| **o).count();
    let total: usize = s.outlier.iter().map(Vec::len).sum();
    let rejected: usize = cal.rejected_per_camera.iter().sum();
    // Clean observations are rejected too: beyond 3 σ̂ (a 2D Gaussian's tail, e^(−9/2) ≈ 1.1 %),
    // and the clean partner of an outlier in a two-view point (which of the two is wrong cannot
    // be told). Allowed: the partners and twice the Gaussian tail.
    let partners = s
        .outlier
        .iter()
        .filter(|o| o.len() == 2 && o.iter().filter(|x| **x).count() == 1)
        .count();
    let tail = 2.0 * (-4.5f64).exp() * (total - outliers) as f64;
    println!(
        "rejected {rejected} of {total} observations; {outliers} outliers planted, {partners} \
         clean partners in two-view points, allowed Gaussian tail {tail:.0}"
    );
    assert!(
        rejected >= outliers && rejected as f64 <= (outliers + partners) as f64 + tail,
        "rejected {rejected}, planted {outliers} + {partners} partners of {total}"
    );
}

/// Without a known distance the initial calibration's baseline sets the scale.
#[test]
fn default_gauge_keeps_the_initial_baseline() {
    let s = synthetic(11);
    let settings = CalibrateSettings {
        max_rounds: 2,
        ..Default::default()
    };
    let cal = calibrate(&s.input, &settings, &mut |_| {}).unwrap();
    let (f, k) = (cal.gauge.fixed_camera, cal.gauge.scale_camera);
    let d = |r: &[Camera]| (r[k].centre_world() - r[f].centre_world()).norm();
    assert_eq!(f, 0);
    assert!((d(&cal.refined) - d(&s.input.cameras)).abs() < 1e-12);
    assert_eq!(
        cal.refined[f].rotation, s.input.cameras[f].rotation,
        "fixed camera's pose held"
    );
    assert!(cal.gauge_description().contains("initial calibration"));
}

/// A camera looking straight at a plane of points cannot tell its focal length from its distance
/// to the plane (`u = f·X/Z` is unchanged when `f` and `Z` scale together): the result carries the
/// ill-conditioned status naming that camera's focal length or its centre along its axis.
#[test]
fn barely_determined_parameters_are_a_reported_status() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut rig = true_rig();
    // Above the origin looking down -z: rows x = (1, 0, 0), y = (0, −1, 0), z = (0, 0, −1).
    let r = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
    let centre = Vector3::new(0.0, 0.0, 1.2);
    rig.push(
        Camera::new(
            "top".into(),
            1280,
            1024,
            [1000.0, 1000.0, 640.0, 512.0],
            [0.0; 5],
            r,
            -(r * centre),
        )
        .unwrap(),
    );
    // Points on the plane z = 0, seen by every camera. The direction is exactly singular for
    // points on the plane; noise moves the refined points off it and lifts the singularity by
    // about (noise)², so it is kept at 0.001 px.
    let noise = Normal::new(0.0, 0.001).unwrap();
    let points: Vec<Vec<PixelObservation>> = (0..300)
        .map(|_| {
            let x = Point3::new(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
                0.0,
            );
            rig.iter()
                .enumerate()
                .map(|(c, cam)| PixelObservation {
                    camera: c,
                    uv: cam.project(&x).unwrap()
                        + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)),
                })
                .collect()
        })
        .collect();
    let input = CalibrationInput {
        source: "plane".into(),
        cameras_path: "plane-rig.toml".into(),
        cameras: rig,
        points,
        length_unit: "m".into(),
    };
    let settings = CalibrateSettings {
        bundle: softcap_capture::bundle::BundleSettings {
            refine: softcap_capture::bundle::Refine::parse("focal").unwrap(),
            ..Default::default()
        },
        max_rounds: 1,
        ..Default::default()
    };
    let cal = calibrate(&input, &settings, &mut |_| {}).unwrap();
    println!(
        "{} (condition number {:.3e})",
        cal.status_description(),
        cal.condition_number
    );
    match &cal.status {
        CalibrationStatus::IllConditioned {
            camera, parameter, ..
        } => {
            assert_eq!(camera.as_deref(), Some("top"));
            assert!(
                [Some("f"), Some("Cz")].contains(&parameter.as_deref()),
                "{parameter:?}"
            )
        }
        other => panic!("expected ill-conditioned, got {other:?}"),
    }
}

fn write_csv(path: &Path, s: &Synthetic, drop_camera: Option<usize>) {
    let mut t = String::from("point,camera,u,v\n");
    for (p, obs) in s.input.points.iter().enumerate() {
        for o in obs {
            if Some(o.camera) != drop_camera {
                t += &format!("{p},cam{},{},{}\n", o.camera, o.uv.x, o.uv.y);
            }
        }
    }
    std::fs::write(path, t).unwrap();
}

fn run(args: &[&std::ffi::OsStr]) -> (i32, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_softcap-capture"))
        .arg("calibrate")
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// The binary end to end on a CSV, then bad input: a camera no point sees, points on a line, a
/// malformed CSV line, a malformed .npz — each exit code 2 naming it, nothing written.
#[test]
fn command_writes_a_rig_and_rejects_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let s = synthetic(5);
    let rig = dir.path().join("rig.toml");
    std::fs::write(
        &rig,
        softcap_core::camera::cameras_toml(&s.input.cameras, 1.0),
    )
    .unwrap();
    let csv = dir.path().join("points.csv");
    write_csv(&csv, &s, None);
    let out = dir.path().join("refined.toml");
    let report = dir.path().join("report");
    let (code, stdout, stderr) = run(&[
        csv.as_os_str(),
        "--cameras".as_ref(),
        rig.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
        "--report".as_ref(),
        report.as_os_str(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    println!("{stdout}");
    assert!(stdout.contains("median per-point reprojection error") && stdout.contains("after"));
    let refined = softcap_capture::session::read_cameras_toml(&out, 1.0).unwrap();
    assert_eq!(refined.len(), 8);
    assert!(report.join("report.md").is_file());
    assert!(report.join("reprojection_cam3.png").is_file());

    let bad = |name: &str, args: Vec<&std::ffi::OsStr>, needles: &[&str]| {
        let out = dir.path().join(format!("{name}.toml"));
        let mut a = args;
        a.extend(["-o".as_ref(), out.as_os_str()]);
        let (code, _, stderr) = run(&a);
        println!("{name}: {stderr}");
        assert_eq!(code, 2, "{name}: {stderr}");
        for n in needles {
            assert!(stderr.contains(n), "{name}: stderr lacks `{n}`: {stderr}");
        }
        assert!(!out.exists(), "{name}: nothing written");
    };
    let unseen = dir.path().join("unseen.csv");
    write_csv(&unseen, &s, Some(6));
    bad(
        "unseen",
        vec![unseen.as_os_str(), "--cameras".as_ref(), rig.as_os_str()],
        &["cam6", "seen by no point"],
    );

    // All points on one line through the volume, seen by the true rig.
    let true_rig = dir.path().join("true-rig.toml");
    std::fs::write(&true_rig, softcap_core::camera::cameras_toml(&s.truth, 1.0)).unwrap();
    let line = dir.path().join("line.csv");
    let mut t = String::from("point,camera,u,v\n");
    for p in 0..200 {
        let x = Point3::new(-0.3 + 0.003 * p as f64, 0.1, 0.0);
        for (c, cam) in s.truth.iter().enumerate() {
            let uv = cam.project(&x).unwrap();
            t += &format!("{p},cam{c},{},{}\n", uv.x, uv.y);
        }
    }
    std::fs::write(&line, t).unwrap();
    bad(
        "line",
        vec![line.as_os_str(), "--cameras".as_ref(), true_rig.as_os_str()],
        &["line.csv", "lie on a line"],
    );

    let malformed = dir.path().join("malformed.csv");
    std::fs::write(
        &malformed,
        "point,camera,u,v\n0,cam0,1.0,2.0\n1,cam1,abc,2.0\n",
    )
    .unwrap();
    bad(
        "malformed",
        vec![malformed.as_os_str(), "--cameras".as_ref(), rig.as_os_str()],
        &["malformed.csv:3", "`u`"],
    );

    let npz = dir.path().join("broken.npz");
    std::fs::write(&npz, b"PK\x03\x04 truncated").unwrap();
    bad(
        "npz",
        vec![npz.as_os_str(), "--cameras".as_ref(), rig.as_os_str()],
        &["broken.npz", "npz"],
    );

    bad(
        "no-cameras",
        vec![csv.as_os_str()],
        &["points.csv", "--cameras"],
    );
}

/// A session folder: capture labels its markers from the detections, the rig given by
/// `--cameras` (one camera turned by 0.05°: ≈ 1 px, inside capture's 2 px epipolar gate, which
/// labels with the rig given) is refined back to the session's own, and
/// `Session::use_cameras` rejects a rig that lacks one of the session's cameras.
#[test]
fn session_folder_calibrates_from_the_markers_capture_labels() {
    use softcap_capture::calibrate::read_calibration_input;
    use softcap_capture::session::read_cameras_toml;
    let session = common::fixture("session-min");
    let truth = read_cameras_toml(&session.join("rig/cameras.toml"), 1e-3).unwrap();
    let mut turned = truth.clone();
    let axis = Unit::new_normalize(Vector3::new(0.3, -1.0, 0.5));
    let centre = turned[1].centre_world().coords;
    turned[1].rotation =
        Rotation3::from_axis_angle(&axis, 0.05f64.to_radians()).into_inner() * turned[1].rotation;
    turned[1].translation_m = -(turned[1].rotation * centre);
    let dir = tempfile::tempdir().unwrap();
    let rig = dir.path().join("turned.toml");
    std::fs::write(&rig, softcap_core::camera::cameras_toml(&turned, 1e3)).unwrap();

    let input = read_calibration_input(&session, Some(&rig)).unwrap();
    assert_eq!(input.length_unit, "mm");
    let cal = calibrate(&input, &CalibrateSettings::default(), &mut |_| {}).unwrap();
    let with_truth = softcap_capture::calibrate::reprojection_summary(&truth, &input.points);
    let angle = |a: &Camera, b: &Camera| {
        let dr = a.rotation * b.rotation.transpose();
        ((dr.trace() - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    };
    let sigma = cal.parameter_std[1].rotation_rad.to_degrees();
    println!(
        "session-min, cam1 turned 0.05°: median per-point error {:.4} → {:.4} px (the session's own \
         rig: {:.4} px); cam1 {:.4}° from the session's rig (σ {sigma:.4}°); {}",
        cal.before.median_point_error_px,
        cal.after.median_point_error_px,
        with_truth.median_point_error_px,
        angle(&cal.refined[1], &truth[1]),
        cal.status_description()
    );
    assert_eq!(cal.status, CalibrationStatus::Converged);
    assert!(cal.before.median_point_error_px > 1.5 * cal.after.median_point_error_px);
    // The detections' own noise is the floor: the refined rig reaches it ...
    assert!(cal.after.median_point_error_px <= with_truth.median_point_error_px * 1.01);
    // ... and cam1 comes back to within the estimate's uncertainty.
    assert!(angle(&cal.refined[1], &truth[1]) < 4.0 * sigma);

    let mut partial = softcap_capture::Session::load(&session).unwrap();
    let two = dir.path().join("two.toml");
    std::fs::write(&two, softcap_core::camera::cameras_toml(&truth[..2], 1e3)).unwrap();
    let e = partial.use_cameras(&two).unwrap_err().to_string();
    assert!(e.contains("two.toml") && e.contains("cam2"), "{e}");
}
