//! softcap's triangulation (DLT + Levenberg–Marquardt through the distortion model) on a real
//! 12-camera rig: the aniposelib mouse-outdoor calibration and labeled 2D points
//! (fixtures/aniposelib, a 3,000-point subset; no 3D truth). The reference figure is aniposelib
//! 0.8.0's own `CameraGroup.triangulate` of the same points, written to
//! fixtures/aniposelib/reference.toml by scripts/aniposelib_reference.py.

use crate::common;

use softcap_capture::pipeline::median_sorted;
use softcap_capture::{
    TriangulationSettings, read_aniposelib_calibration, read_labeled_points, triangulate,
    triangulate_dlt,
};

#[derive(serde::Deserialize)]
struct Figures {
    points: usize,
    observations: usize,
    median_point_mean_error_px: f64,
    median_observation_error_px: f64,
}

#[derive(serde::Deserialize)]
struct Reference {
    subset: Figures,
}

/// Per point, the mean over its views of the pixel reprojection error (aniposelib's
/// `reprojection_error(mean=True)`); per observation, each view's error.
fn errors(refine: bool) -> (Vec<f64>, Vec<f64>, usize) {
    let dir = common::fixture("aniposelib");
    let cams = read_aniposelib_calibration(&dir.join("calibration.toml"), 1.0).unwrap();
    assert_eq!(cams.len(), 12);
    let points = read_labeled_points(&dir.join("points.csv"), &cams).unwrap();
    let settings = TriangulationSettings {
        refine,
        ..Default::default()
    };
    let (mut per_point, mut per_obs, mut failed) = (Vec::new(), Vec::new(), 0);
    for obs in &points {
        let x = triangulate(&cams, obs, &settings)
            .map(|t| t.position_m)
            .or_else(|| triangulate_dlt(&cams, obs));
        let e: Vec<f64> = obs
            .iter()
            .map(|o| {
                x.and_then(|x| cams[o.camera].project(&x))
                    .map_or(f64::INFINITY, |uv| (uv - o.uv).norm())
            })
            .collect();
        if e.iter().any(|v| !v.is_finite()) {
            failed += 1;
        }
        per_point.push(e.iter().sum::<f64>() / e.len() as f64);
        per_obs.extend(e);
    }
    per_point.sort_by(f64::total_cmp);
    per_obs.sort_by(f64::total_cmp);
    (per_point, per_obs, failed)
}

#[test]
fn mouse_outdoor_median_reprojection_error_is_no_worse_than_aniposelib() {
    let text =
        std::fs::read_to_string(common::fixture("aniposelib").join("reference.toml")).unwrap();
    let reference: Reference = toml::from_str(&text).unwrap();
    let (per_point, per_obs, failed) = errors(true);
    let (dlt_point, dlt_obs, _) = errors(false);
    let median = median_sorted(&per_point);
    let median_obs = median_sorted(&per_obs);
    println!(
        "softcap DLT+LM: {} points, {} observations, median per-point mean error {median:.3} px, \
         median per-observation error {median_obs:.3} px, {failed} points not reconstructable",
        per_point.len(),
        per_obs.len()
    );
    println!(
        "softcap DLT only: median per-point {:.3} px, per-observation {:.3} px",
        median_sorted(&dlt_point),
        median_sorted(&dlt_obs)
    );
    println!(
        "aniposelib 0.8.0 triangulate: median per-point {:.3} px, per-observation {:.3} px",
        reference.subset.median_point_mean_error_px, reference.subset.median_observation_error_px
    );
    assert_eq!(per_point.len(), reference.subset.points);
    assert_eq!(per_obs.len(), reference.subset.observations);
    assert!(
        median <= reference.subset.median_point_mean_error_px,
        "median {median} px > aniposelib {} px",
        reference.subset.median_point_mean_error_px
    );
    assert!(median_obs <= reference.subset.median_observation_error_px);
}

#[derive(serde::Deserialize)]
struct BundleAdjustReference {
    points: usize,
    median_point_error_before_px: f64,
    median_point_error_after_px: f64,
    bundle_adjust_iter_seconds: f64,
}

/// `softcap capture calibrate` on the fixture subset (2,998 points): the median per-point error
/// (softcap's triangulation, each point from all its views) falls ≥ 3× below the initial rig's
/// and is no worse than with the rig refined by aniposelib's own `bundle_adjust_iter`
/// (fixtures/aniposelib/bundle_adjust_calibration.toml, written by
/// scripts/aniposelib-bundle-adjust), measured the same way.
#[test]
fn mouse_outdoor_calibration_is_no_worse_than_aniposelib_bundle_adjustment() {
    use softcap_capture::calibrate::{
        CalibrateSettings, calibrate, read_calibration_input, reprojection_summary,
    };
    let dir = common::fixture("aniposelib");
    let input =
        read_calibration_input(&dir.join("points.csv"), Some(&dir.join("calibration.toml")))
            .unwrap();
    let start = std::time::Instant::now();
    let cal = calibrate(&input, &CalibrateSettings::default(), &mut |l| {
        eprintln!("{l}")
    })
    .unwrap();
    let seconds = start.elapsed().as_secs_f64();
    let text = std::fs::read_to_string(dir.join("bundle_adjust_reference.toml")).unwrap();
    let reference: BundleAdjustReference = toml::from_str(&text).unwrap();
    let anipose_rig =
        read_aniposelib_calibration(&dir.join("bundle_adjust_calibration.toml"), 1.0).unwrap();
    let anipose = reprojection_summary(&anipose_rig, &input.points);
    println!(
        "median per-point error (softcap triangulation): initial rig {:.3} px, softcap calibrate \
         {:.3} px ({seconds:.2} s, test profile), aniposelib bundle_adjust_iter {:.3} px",
        cal.before.median_point_error_px,
        cal.after.median_point_error_px,
        anipose.median_point_error_px
    );
    println!(
        "aniposelib's own figures ({} points): {:.3} → {:.3} px in {:.1} s; status: {}",
        reference.points,
        reference.median_point_error_before_px,
        reference.median_point_error_after_px,
        reference.bundle_adjust_iter_seconds,
        cal.status_description()
    );
    assert_eq!(cal.before.points, reference.points);
    assert!((cal.before.median_point_error_px - 35.37).abs() < 0.01);
    assert!(cal.after.median_point_error_px <= cal.before.median_point_error_px / 3.0);
    assert!(cal.after.median_point_error_px <= anipose.median_point_error_px);
}
