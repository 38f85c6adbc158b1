//! `softcap capture calibrate`: refine a multi-camera rig from labeled 2D points.
//!
//! Input: a session (its labeled detections, or the markers capture labels) or aniposelib-style
//! labeled points (`.npz` with `p2d`, or `point,camera,u,v` CSV) with a calibration
//! (`rig/cameras.toml` or aniposelib TOML). Output: the refined rig as `rig/cameras.toml`.
//!
//! Method ([`calibrate`]): every point is triangulated with the initial rig (DLT + LM,
//! [`crate::triangulate`](mod@crate::triangulate)); then rounds of
//! 1. residuals of all observations; noise scale σ̂ = 1.4826 · median |residual component| (the
//!    MAD about zero, robust to up to half the observations being outliers);
//! 2. observations farther than `outlier_threshold · σ̂` px from their point's projection are
//!    rejected for this round (re-admitted later if they fit), points keep ≥ 2 views;
//! 3. robust bundle adjustment ([`crate::bundle`]) of the rig and the points with loss scale
//!    `loss_scale · σ̂`;
//!
//! until the inlier set stops changing or `max_rounds`. Finally every point is triangulated again
//! with the refined rig from all its views — the reported errors are those of the plain
//! triangulation, before and after, so they compare rigs, not solvers.

pub mod report;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use nalgebra::Point3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::aniposelib::{read_labeled_points, read_npz_points};
use crate::bundle::{
    BundleSettings, BundleStatus, Gauge, Iteration, Observation, ParameterStd, RobustLoss,
    bundle_adjust,
};
use crate::camera::Camera;
use crate::error::{CaptureError, Result};
use crate::pipeline::{CaptureSettings, MarkerSource, capture, median_sorted};
use crate::session::{Session, read_rig};
use crate::triangulate::{PixelObservation, TriangulationSettings, triangulate, triangulate_dlt};

/// Settings of [`calibrate`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrateSettings {
    /// Bundle adjustment (refined intrinsics, loss, iterations).
    pub bundle: BundleSettings,
    /// Loss scale δ in units of the robust noise scale σ̂.
    pub loss_scale: f64,
    /// Outlier rejection threshold on the residual norm, in units of σ̂.
    pub outlier_threshold: f64,
    /// Rounds of rejection + bundle adjustment.
    pub max_rounds: usize,
    /// Camera whose pose is held (default: the first).
    pub fixed_camera: Option<String>,
    /// Camera whose distance to the fixed one sets the scale (default: the farthest from it).
    pub scale_camera: Option<String>,
    /// That distance, m (default: its value in the initial calibration).
    pub scale_distance_m: Option<f64>,
    /// Points whose inlier rays all lie within this angle of each other (degrees) are left out
    /// of the adjustment: their depth is barely determined and their nearly singular 3×3 blocks
    /// would spoil the reduced camera system (COLMAP's `min_tri_angle` plays the same role).
    pub min_triangulation_angle_deg: f64,
    /// Fewest observations a camera needs (its pose and intrinsics are refined from them).
    pub min_observations_per_camera: usize,
    /// Above this Jacobi-scaled condition number of the reduced camera system the result is
    /// reported as [`CalibrationStatus::IllConditioned`].
    pub max_condition_number: f64,
}

impl Default for CalibrateSettings {
    fn default() -> Self {
        CalibrateSettings {
            bundle: BundleSettings::default(),
            loss_scale: 2.0,
            outlier_threshold: 3.0,
            max_rounds: 5,
            fixed_camera: None,
            scale_camera: None,
            scale_distance_m: None,
            min_triangulation_angle_deg: 2.0,
            min_observations_per_camera: 10,
            max_condition_number: 1e12,
        }
    }
}

/// Labeled 2D points and the rig they were seen by.
#[derive(Debug, Clone)]
pub struct CalibrationInput {
    /// The labeled points file or session folder.
    pub source: PathBuf,
    /// The calibration file read.
    pub cameras_path: PathBuf,
    /// Initial cameras.
    pub cameras: Vec<Camera>,
    /// Observations per labeled point (points with fewer than two views are kept and skipped).
    pub points: Vec<Vec<PixelObservation>>,
    /// Length unit of the rig file to write (`"mm"` or `"m"`): the session's, else metres.
    pub length_unit: String,
}

/// Reads the input of `softcap capture calibrate`: a session folder (its cameras unless
/// `cameras` is given; observations from [`capture`]'s labeling), an `.npz` (`p2d`) or a CSV
/// (`point,camera,u,v`) with `cameras` (session `[[camera]]` or aniposelib `[cam_N]` format).
pub fn read_calibration_input(input: &Path, cameras: Option<&Path>) -> Result<CalibrationInput> {
    if input.is_dir() {
        let mut session = Session::load(input)?;
        if let Some(path) = cameras {
            session.use_cameras(path)?;
        }
        // The session's detections when it has them (labeled already, and no image decoding).
        let settings = CaptureSettings {
            source: if session.detections.is_some() {
                MarkerSource::Detections
            } else {
                MarkerSource::Auto
            },
            ..CaptureSettings::default()
        };
        let result = capture(&session, &settings)?;
        let points = result
            .observations
            .into_iter()
            .map(|m| m.observations)
            .collect();
        return Ok(CalibrationInput {
            source: input.to_path_buf(),
            cameras_path: session
                .cameras_path
                .unwrap_or_else(|| input.join("session.toml")),
            cameras: session.cameras,
            points,
            length_unit: if session.metres_per_unit == 1.0 {
                "m".into()
            } else {
                "mm".into()
            },
        });
    }
    let cameras_path = cameras.ok_or_else(|| CaptureError::Format {
        path: input.to_path_buf(),
        message: "labeled points need the rig they were seen by: pass --cameras".into(),
    })?;
    let rig = read_rig(cameras_path, 1.0)?;
    let extension = input.extension().and_then(|e| e.to_str()).unwrap_or("");
    let points = match extension {
        "npz" => read_npz_points(input, &rig)?,
        "csv" => read_labeled_points(input, &rig)?,
        _ if !input.exists() => {
            return Err(CaptureError::Io {
                path: input.to_path_buf(),
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or folder"),
            });
        }
        _ => {
            return Err(CaptureError::Format {
                path: input.to_path_buf(),
                message: "expected a session folder, an .npz (p2d) or a .csv (point,camera,u,v)"
                    .into(),
            });
        }
    };
    Ok(CalibrationInput {
        source: input.to_path_buf(),
        cameras_path: cameras_path.to_path_buf(),
        cameras: rig,
        points,
        length_unit: "m".into(),
    })
}

/// Error statistics of one rig on all the labeled points (each triangulated from all its views).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ErrorSummary {
    /// Median over points of the mean over a point's views of the pixel reprojection error
    /// (aniposelib's `reprojection_error(mean=True)`); points that cannot be triangulated in
    /// front of all their cameras count as infinite.
    pub median_point_error_px: f64,
    /// Median over observations of the pixel reprojection error.
    pub median_observation_error_px: f64,
    /// Points with two or more views.
    pub points: usize,
    /// Of those, points whose estimate lies behind at least one of their cameras.
    pub failed_points: usize,
    /// Per camera, the reprojection error of each of its observations, px (finite ones).
    pub per_camera_px: Vec<Vec<f64>>,
}

/// One round of rejection and bundle adjustment.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Round {
    /// Robust noise scale σ̂, px.
    pub sigma_px: f64,
    /// Loss scale δ, px.
    pub loss_scale_px: f64,
    /// Observations kept (inliers of points with ≥ 2 of them).
    pub inliers: usize,
    /// Points in the adjustment.
    pub points: usize,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
    /// Robust cost before and after.
    pub initial_cost: f64,
    /// Robust cost after.
    pub final_cost: f64,
    /// How it ended.
    pub status: BundleStatus,
}

/// How a calibration ended.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum CalibrationStatus {
    /// Every round's adjustment converged and the gauge is well conditioned.
    Converged,
    /// The last round's adjustment stopped at its iteration cap or could not lower the cost.
    NotConverged(BundleStatus),
    /// The reduced camera system is nearly singular: some camera parameter is barely determined
    /// by the points (`camera`, `parameter`), so its refined value is unreliable.
    IllConditioned {
        /// Jacobi-scaled condition number.
        condition_number: f64,
        /// Camera id (`None`: the reduced system could not be formed at the solution).
        camera: Option<String>,
        /// Parameter (slot) name.
        parameter: Option<String>,
    },
}

/// Result of [`calibrate`].
#[derive(Debug, Clone)]
pub struct Calibration {
    /// Initial cameras (scaled to the gauge distance when one was given).
    pub initial: Vec<Camera>,
    /// Refined cameras.
    pub refined: Vec<Camera>,
    /// The gauge used.
    pub gauge: Gauge,
    /// Whether the gauge distance came from the user (else from the initial calibration).
    pub distance_given: bool,
    /// Errors with the initial rig.
    pub before: ErrorSummary,
    /// Errors with the refined rig.
    pub after: ErrorSummary,
    /// Rounds run.
    pub rounds: Vec<Round>,
    /// Observations rejected in the last round, per camera.
    pub rejected_per_camera: Vec<usize>,
    /// Observations per camera (of points with ≥ 2 views).
    pub observations_per_camera: Vec<usize>,
    /// Condition number of the final reduced camera system (Jacobi-scaled).
    pub condition_number: f64,
    /// Residual noise of the final adjustment, px per component (dof-corrected).
    pub residual_sigma_px: f64,
    /// Per camera, standard deviations of the refined parameters (final adjustment).
    pub parameter_std: Vec<ParameterStd>,
    /// Status.
    pub status: CalibrationStatus,
    /// Settings used.
    pub settings: CalibrateSettings,
}

/// Each point triangulated from all its views (DLT + LM, falling back to the DLT estimate when
/// the refinement ends behind a camera); `None` with fewer than two views or no estimate.
fn triangulate_points(
    cameras: &[Camera],
    points: &[Vec<PixelObservation>],
) -> Vec<Option<Point3<f64>>> {
    let settings = TriangulationSettings::default();
    points
        .par_iter()
        .map(|obs| {
            if obs.len() < 2 {
                return None;
            }
            triangulate(cameras, obs, &settings)
                .map(|t| t.position_m)
                .or_else(|| triangulate_dlt(cameras, obs))
        })
        .collect()
}

/// [`triangulate_points`], keeping only points in front of all their cameras.
fn triangulate_all(
    cameras: &[Camera],
    points: &[Vec<PixelObservation>],
) -> Vec<Option<Point3<f64>>> {
    triangulate_points(cameras, points)
        .into_iter()
        .zip(points)
        .map(|(x, obs)| x.filter(|x| obs.iter().all(|o| cameras[o.camera].project(x).is_some())))
        .collect()
}

/// The errors of a rig on labeled points, each triangulated from all its views (see
/// [`ErrorSummary`]).
pub fn reprojection_summary(cameras: &[Camera], points: &[Vec<PixelObservation>]) -> ErrorSummary {
    let positions = triangulate_points(cameras, points);
    let mut per_point = Vec::new();
    let mut per_obs = Vec::new();
    let mut per_camera_px = vec![Vec::new(); cameras.len()];
    let mut failed_points = 0;
    for (obs, x) in points.iter().zip(&positions) {
        if obs.len() < 2 {
            continue;
        }
        let mut sum = 0.0;
        for o in obs {
            let e = x
                .and_then(|x| cameras[o.camera].project(&x))
                .map_or(f64::INFINITY, |uv| (uv - o.uv).norm());
            sum += e;
            per_obs.push(e);
            if e.is_finite() {
                per_camera_px[o.camera].push(e);
            }
        }
        if !sum.is_finite() {
            failed_points += 1;
        }
        per_point.push(sum / obs.len() as f64);
    }
    per_point.sort_by(f64::total_cmp);
    per_obs.sort_by(f64::total_cmp);
    ErrorSummary {
        median_point_error_px: median_sorted(&per_point),
        median_observation_error_px: median_sorted(&per_obs),
        points: per_point.len(),
        failed_points,
        per_camera_px,
    }
}

/// Drops a point's worst view while its error exceeds `threshold`, re-triangulating from the
/// remaining views (an outlier drags an all-view estimate toward itself and so hides among its
/// neighbours' errors), then re-admits every view within the threshold of the final estimate.
/// Returns the estimate and the inlier mask (all false: no two consistent views).
fn clean_point(
    cameras: &[Camera],
    obs: &[PixelObservation],
    start: Point3<f64>,
    threshold: f64,
) -> Option<(Point3<f64>, Vec<bool>)> {
    let error = |x: &Point3<f64>, o: &PixelObservation| {
        cameras[o.camera]
            .project(x)
            .map_or(f64::INFINITY, |uv| (uv - o.uv).norm())
    };
    let mut x = start;
    let mut views: Vec<PixelObservation> = obs.to_vec();
    loop {
        let (worst, e) = views
            .iter()
            .enumerate()
            .map(|(i, o)| (i, error(&x, o)))
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
        if e <= threshold {
            break;
        }
        if views.len() <= 2 {
            return Some((x, vec![false; obs.len()]));
        }
        views.remove(worst);
        x = triangulate(cameras, &views, &TriangulationSettings::default())
            .map(|t| t.position_m)
            .or_else(|| triangulate_dlt(cameras, &views))?;
    }
    let mask = obs.iter().map(|o| error(&x, o) <= threshold).collect();
    Some((x, mask))
}

/// Largest angle between two of the rays from `x` to the centres of the cameras `mask` selects,
/// rad: near zero, the point's depth is undetermined and its 3×3 block nearly singular.
fn triangulation_angle(
    cameras: &[Camera],
    obs: &[PixelObservation],
    mask: &[bool],
    x: &Point3<f64>,
) -> f64 {
    let rays: Vec<nalgebra::Vector3<f64>> = obs
        .iter()
        .zip(mask)
        .filter(|(_, m)| **m)
        .map(|(o, _)| (cameras[o.camera].centre_world() - x).normalize())
        .collect();
    let mut best: f64 = 0.0;
    for (i, a) in rays.iter().enumerate() {
        for b in &rays[i + 1..] {
            best = best.max(a.dot(b).clamp(-1.0, 1.0).acos());
        }
    }
    best
}

/// Robust noise scale: 1.4826 × the median absolute residual component.
fn robust_sigma(residuals: &[f64]) -> f64 {
    let mut a: Vec<f64> = residuals.iter().map(|r| r.abs()).collect();
    a.sort_by(f64::total_cmp);
    1.4826 * median_sorted(&a)
}

/// Checks the input can determine a rig: every camera sees enough triangulable points, the
/// cameras are connected through shared points, and the points span more than a line.
fn check_configuration(
    input: &CalibrationInput,
    positions: &[Option<Point3<f64>>],
    settings: &CalibrateSettings,
) -> Result<Vec<usize>> {
    let degenerate = |message: String| CaptureError::Degenerate {
        path: input.source.clone(),
        message,
    };
    let cams = &input.cameras;
    if cams.len() < 2 {
        return Err(degenerate(format!(
            "{} camera(s) in {}; calibration needs two or more",
            cams.len(),
            input.cameras_path.display()
        )));
    }
    let mut counts = vec![0usize; cams.len()];
    let mut parent: Vec<usize> = (0..cams.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut used: Vec<Point3<f64>> = Vec::new();
    for (obs, x) in input.points.iter().zip(positions) {
        if x.is_none() {
            continue;
        }
        for o in obs {
            counts[o.camera] += 1;
            let (a, b) = (
                root(&mut parent, obs[0].camera),
                root(&mut parent, o.camera),
            );
            parent[a] = b;
        }
        used.extend(x);
    }
    for (c, &n) in counts.iter().enumerate() {
        if n == 0 {
            return Err(degenerate(format!(
                "camera `{}` is seen by no point with two or more views",
                cams[c].id
            )));
        }
        if n < settings.min_observations_per_camera {
            return Err(degenerate(format!(
                "camera `{}` sees only {n} triangulable point(s); at least {} are needed to \
                 refine its pose and intrinsics",
                cams[c].id, settings.min_observations_per_camera
            )));
        }
    }
    let groups: BTreeSet<usize> = (0..cams.len()).map(|c| root(&mut parent, c)).collect();
    if groups.len() > 1 {
        let first = root(&mut parent, 0);
        let apart: Vec<&str> = (0..cams.len())
            .filter(|&c| root(&mut parent, c) != first)
            .map(|c| cams[c].id.as_str())
            .collect();
        return Err(degenerate(format!(
            "cameras {} share no point with camera `{}`'s group: the rig falls apart into {} \
             independently placed groups",
            apart.join(", "),
            cams[0].id,
            groups.len()
        )));
    }
    let mean = used
        .iter()
        .map(|p| p.coords)
        .sum::<nalgebra::Vector3<f64>>()
        / used.len() as f64;
    let cov = used
        .iter()
        .map(|p| (p.coords - mean) * (p.coords - mean).transpose())
        .sum::<nalgebra::Matrix3<f64>>();
    let mut eig: Vec<f64> = cov.symmetric_eigenvalues().iter().copied().collect();
    eig.sort_by(f64::total_cmp);
    // Points on a line leave every camera's rotation about it undetermined.
    if eig[1].is_nan() || eig[1] <= 1e-8 * eig[2] {
        return Err(degenerate(format!(
            "the {} triangulated points lie on a line (RMS spread {:.3e} m across it, {:.3e} m \
             along it); they cannot determine the rig",
            used.len(),
            (eig[1] / used.len() as f64).sqrt(),
            (eig[2] / used.len() as f64).sqrt()
        )));
    }
    Ok(counts)
}

/// Resolves the gauge from the settings (camera ids → indices; default fixed camera: the first;
/// default scale camera: the one farthest from it; default distance: the initial one).
fn resolve_gauge(input: &CalibrationInput, settings: &CalibrateSettings) -> Result<(Gauge, bool)> {
    let cams = &input.cameras;
    let find = |id: &str, what: &str| {
        cams.iter()
            .position(|c| c.id == id)
            .ok_or_else(|| CaptureError::Camera {
                path: input.cameras_path.clone(),
                camera: id.to_string(),
                message: format!("{what}: no such camera"),
            })
    };
    let fixed = match &settings.fixed_camera {
        Some(id) => find(id, "--fix-camera")?,
        None => 0,
    };
    let origin = cams[fixed].centre_world();
    let scale = match &settings.scale_camera {
        Some(id) => find(id, "--scale-camera")?,
        None => (0..cams.len())
            .filter(|&c| c != fixed)
            .max_by(|&a, &b| {
                let d = |c: usize| (cams[c].centre_world() - origin).norm();
                d(a).total_cmp(&d(b))
            })
            .unwrap_or(0),
    };
    let bad = |message: String| CaptureError::Degenerate {
        path: input.cameras_path.clone(),
        message,
    };
    if scale == fixed {
        return Err(bad(format!(
            "the scale camera must differ from the fixed camera `{}`",
            cams[fixed].id
        )));
    }
    let initial = (cams[scale].centre_world() - origin).norm();
    if initial.is_nan() || initial <= 1e-9 {
        return Err(bad(format!(
            "cameras `{}` and `{}` have the same centre; their distance cannot set the scale",
            cams[fixed].id, cams[scale].id
        )));
    }
    let distance_m = match settings.scale_distance_m {
        Some(d) if d > 0.0 && d.is_finite() => d,
        Some(d) => {
            return Err(bad(format!(
                "scale distance {d} m: must be a positive number"
            )));
        }
        None => initial,
    };
    Ok((
        Gauge {
            fixed_camera: fixed,
            scale_camera: scale,
            distance_m,
        },
        settings.scale_distance_m.is_some(),
    ))
}

/// Refines the rig of `input` (see module docs). `progress` receives one line per round and per
/// Levenberg–Marquardt iteration. Errors only on a configuration that cannot determine a rig
/// (bad input); non-convergence and ill-conditioning are a [`CalibrationStatus`].
pub fn calibrate(
    input: &CalibrationInput,
    settings: &CalibrateSettings,
    progress: &mut dyn FnMut(&str),
) -> Result<Calibration> {
    let initial_positions = triangulate_all(&input.cameras, &input.points);
    let observations_per_camera = check_configuration(input, &initial_positions, settings)?;
    let (gauge, distance_given) = resolve_gauge(input, settings)?;
    let before = reprojection_summary(&input.cameras, &input.points);
    progress(&format!(
        "{} points with ≥ 2 views, {} observations; median per-point reprojection error {:.3} px",
        before.points,
        observations_per_camera.iter().sum::<usize>(),
        before.median_point_error_px
    ));

    let mut cameras = input.cameras.clone();
    let mut positions: Vec<Point3<f64>> = initial_positions
        .iter()
        .map(|p| p.unwrap_or(Point3::origin()))
        .collect();
    let mut valid: Vec<bool> = initial_positions.iter().map(Option::is_some).collect();
    let mut rounds = Vec::new();
    let mut previous_inliers: Option<Vec<Observation>> = None;
    let mut rejected_per_camera = vec![0usize; cameras.len()];
    let mut condition_number = f64::NAN;
    let mut weakest: Option<(usize, &str)> = None;
    let mut residual_sigma_px = f64::NAN;
    let mut parameter_std = vec![ParameterStd::default(); cameras.len()];
    for round in 1..=settings.max_rounds.max(1) {
        // Noise scale from the residuals of every observation at its point's current estimate.
        let mut components = Vec::new();
        let mut total = 0;
        for (p, obs) in input.points.iter().enumerate() {
            if !valid[p] {
                continue;
            }
            for o in obs {
                let e = cameras[o.camera]
                    .project(&positions[p])
                    .map_or(nalgebra::Vector2::repeat(f64::INFINITY), |uv| uv - o.uv);
                components.extend([e.x, e.y]);
                total += 1;
            }
        }
        let sigma = robust_sigma(&components);
        let threshold = settings.outlier_threshold * sigma;
        let cleaned: Vec<Option<(Point3<f64>, Vec<bool>)>> = input
            .points
            .par_iter()
            .enumerate()
            .map(|(p, obs)| {
                valid[p]
                    .then(|| clean_point(&cameras, obs, positions[p], threshold))
                    .flatten()
            })
            .collect();
        let mut inliers: Vec<Observation> = Vec::new();
        let mut views = vec![0usize; input.points.len()];
        rejected_per_camera.fill(0);
        let min_angle = settings.min_triangulation_angle_deg.to_radians();
        let mut weak = 0;
        for (p, c) in cleaned.into_iter().enumerate() {
            let Some((x, mut mask)) = c else { continue };
            positions[p] = x;
            if triangulation_angle(&cameras, &input.points[p], &mask, &x) < min_angle
                && mask.iter().any(|m| *m)
            {
                // Not an outlier: kept out of the adjustment for its geometry.
                weak += 1;
                mask.fill(false);
                continue;
            }
            views[p] = mask.iter().filter(|m| **m).count();
            for (o, keep) in input.points[p].iter().zip(mask) {
                if keep && views[p] < 2 {
                    // The one view left of a point: it constrains nothing but its own ray (and
                    // would leave the point's 3×3 block singular); not an outlier either.
                    continue;
                } else if keep {
                    inliers.push(Observation {
                        camera: o.camera,
                        point: p,
                        uv: o.uv,
                    });
                } else {
                    rejected_per_camera[o.camera] += 1;
                }
            }
        }
        if previous_inliers.as_ref() == Some(&inliers) {
            progress(&format!("round {round}: inlier set unchanged; done"));
            break;
        }
        let delta = settings.loss_scale * sigma;
        let n_points = views.iter().filter(|&&v| v >= 2).count();
        progress(&format!(
            "round {round}: σ̂ = {sigma:.3} px, {} of {} observations within {threshold:.2} px, \
             {n_points} points ({weak} more left out: rays within {:.1}°), loss scale {delta:.2} px",
            inliers.len(),
            total,
            settings.min_triangulation_angle_deg
        ));
        let report = bundle_adjust(
            &cameras,
            &positions,
            &inliers,
            &gauge,
            delta,
            &settings.bundle,
            &mut |it: &Iteration| {
                progress(&format!(
                    "  LM {:3}: cost {:.6e}, λ {:.2e}, {}",
                    it.iteration,
                    it.cost,
                    it.damping,
                    if it.accepted { "accepted" } else { "rejected" }
                ))
            },
        );
        progress(&format!(
            "round {round}: {:?} after {} iterations, cost {:.6e} → {:.6e}, condition number {:.2e} \
             (least determined: {})",
            report.status,
            report.iterations,
            report.initial_cost,
            report.final_cost,
            report.condition_number,
            report
                .weakest_parameter
                .map_or("not computable".to_string(), |(c, p)| format!(
                    "{} {p}",
                    cameras[c].id
                ))
        ));
        rounds.push(Round {
            sigma_px: sigma,
            loss_scale_px: delta,
            inliers: inliers.len(),
            points: n_points,
            iterations: report.iterations,
            initial_cost: report.initial_cost,
            final_cost: report.final_cost,
            status: report.status,
        });
        cameras = report.cameras;
        positions = report.points;
        condition_number = report.condition_number;
        weakest = report.weakest_parameter;
        residual_sigma_px = report.residual_sigma_px;
        parameter_std = report.parameter_std;
        // Points outside the adjustment: triangulate again with the refined rig.
        let outside: Vec<usize> = (0..input.points.len())
            .filter(|&p| views[p] < 2 && input.points[p].len() >= 2)
            .collect();
        let again = triangulate_all(
            &cameras,
            &outside
                .iter()
                .map(|&p| input.points[p].clone())
                .collect::<Vec<_>>(),
        );
        for (&p, x) in outside.iter().zip(again) {
            valid[p] = x.is_some();
            if let Some(x) = x {
                positions[p] = x;
            }
        }
        previous_inliers = Some(inliers);
    }
    let after = reprojection_summary(&cameras, &input.points);
    progress(&format!(
        "median per-point reprojection error {:.3} px → {:.3} px",
        before.median_point_error_px, after.median_point_error_px
    ));
    // Ill-conditioning first: it names the parameter that is barely determined, which is also
    // the usual reason an adjustment stops at its iteration cap.
    let status = match rounds.last().map(|r| r.status) {
        _ if condition_number.is_nan() || condition_number > settings.max_condition_number => {
            CalibrationStatus::IllConditioned {
                condition_number,
                camera: weakest.map(|(c, _)| cameras[c].id.clone()),
                parameter: weakest.map(|(_, p)| p.to_string()),
            }
        }
        Some(s @ (BundleStatus::MaxIterations | BundleStatus::DampingOverflow)) => {
            CalibrationStatus::NotConverged(s)
        }
        _ => CalibrationStatus::Converged,
    };
    let mut initial = input.cameras.clone();
    if distance_given {
        // The initial rig in the gauge's scale, so changes compare like with like.
        let origin = initial[gauge.fixed_camera].centre_world().coords;
        let k =
            gauge.distance_m / (initial[gauge.scale_camera].centre_world().coords - origin).norm();
        for c in initial.iter_mut() {
            let centre = origin + k * (c.centre_world().coords - origin);
            c.translation_m = -(c.rotation * centre);
        }
    }
    Ok(Calibration {
        initial,
        refined: cameras,
        gauge,
        distance_given,
        before,
        after,
        rounds,
        rejected_per_camera,
        observations_per_camera,
        condition_number,
        residual_sigma_px,
        parameter_std,
        status,
        settings: settings.clone(),
    })
}

impl Calibration {
    /// Per-camera parameter changes: rotation angle (deg), centre shift (m), focal (relative),
    /// principal point (px), distortion.
    pub fn changes(&self) -> Vec<CameraChange> {
        self.initial
            .iter()
            .zip(&self.refined)
            .map(|(a, b)| {
                let dr = b.rotation * a.rotation.transpose();
                let angle = ((dr.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos();
                CameraChange {
                    id: a.id.clone(),
                    rotation_deg: angle.to_degrees(),
                    centre_m: (b.centre_world() - a.centre_world()).norm(),
                    focal_relative: b.focal_px() / a.focal_px() - 1.0,
                    principal_px: [
                        b.intrinsics[2] - a.intrinsics[2],
                        b.intrinsics[3] - a.intrinsics[3],
                    ],
                    distortion: std::array::from_fn(|k| b.distortion[k] - a.distortion[k]),
                }
            })
            .collect()
    }

    /// Cameras whose refinement deserves a look: most of their observations rejected in the
    /// last round (the rest may not determine them), or a focal length changed by more than 20 %
    /// (a camera pulled away from the points can trade focal length against its pose).
    pub fn warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (c, change) in self.changes().iter().enumerate() {
            let (rejected, seen) = (self.rejected_per_camera[c], self.observations_per_camera[c]);
            if 2 * rejected > seen {
                out.push(format!(
                    "camera `{}`: {rejected} of its {seen} observations rejected in the last round",
                    change.id
                ));
            }
            if change.focal_relative.abs() > 0.2 {
                out.push(format!(
                    "camera `{}`: focal length changed by {:+.1} %",
                    change.id,
                    100.0 * change.focal_relative
                ));
            }
        }
        out
    }

    /// One-line description of the gauge.
    pub fn gauge_description(&self) -> String {
        let g = &self.gauge;
        format!(
            "camera `{}` pose held; |C({}) − C({})| = {:.6} m ({})",
            self.refined[g.fixed_camera].id,
            self.refined[g.fixed_camera].id,
            self.refined[g.scale_camera].id,
            g.distance_m,
            if self.distance_given {
                "given"
            } else {
                "initial calibration"
            }
        )
    }

    /// One-line description of the status.
    pub fn status_description(&self) -> String {
        match &self.status {
            CalibrationStatus::Converged => {
                format!("converged (condition number {:.2e})", self.condition_number)
            }
            CalibrationStatus::NotConverged(s) => format!("not converged ({s:?})"),
            CalibrationStatus::IllConditioned {
                condition_number,
                camera,
                parameter,
            } => format!(
                "ill-conditioned gauge or parameters: condition number {condition_number:.2e} > \
                 {:.0e}; least determined: {}",
                self.settings.max_condition_number,
                match (camera, parameter) {
                    (Some(c), Some(p)) => format!("camera `{c}` {p}"),
                    _ =>
                        "not computable (a point behind a camera or a singular point block)".into(),
                }
            ),
        }
    }
}

/// How one camera moved.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CameraChange {
    /// Camera id.
    pub id: String,
    /// Angle of the rotation change, degrees.
    pub rotation_deg: f64,
    /// Distance the centre moved, m.
    pub centre_m: f64,
    /// Relative focal change.
    pub focal_relative: f64,
    /// Principal point change, px.
    pub principal_px: [f64; 2],
    /// Distortion change (k1, k2, p1, p2, k3).
    pub distortion: [f64; 5],
}

/// The refined rig as `rig/cameras.toml`, with a comment header naming the input, gauge, status
/// and errors; translations in `length_unit` (`"mm"` or `"m"`).
pub fn refined_cameras_toml(input: &CalibrationInput, cal: &Calibration) -> String {
    let units_per_metre = if input.length_unit == "mm" { 1e3 } else { 1.0 };
    let rejected: usize = cal.rejected_per_camera.iter().sum();
    let total: usize = cal.observations_per_camera.iter().sum();
    format!(
        "# softcap capture calibrate: {} refined by bundle adjustment from {}\n\
         # refined: extrinsics + {}; loss {:?}; outliers rejected: {rejected} of {total} observations\n\
         # gauge: {}\n\
         # status: {}\n\
         # median per-point reprojection error: {:.3} px before, {:.3} px after\n\
         # translations in {}\n\n{}",
        input.cameras_path.display(),
        input.source.display(),
        cal.settings.bundle.refine.describe(),
        cal.settings.bundle.loss,
        cal.gauge_description(),
        cal.status_description(),
        cal.before.median_point_error_px,
        cal.after.median_point_error_px,
        input.length_unit,
        softcap_core::camera::cameras_toml(&cal.refined, units_per_metre)
    )
}

/// Loss name for the command line.
pub fn parse_loss(name: &str) -> Option<RobustLoss> {
    match name {
        "squared" => Some(RobustLoss::Squared),
        "huber" => Some(RobustLoss::Huber),
        "cauchy" => Some(RobustLoss::Cauchy),
        _ => None,
    }
}

/// [`softcap_app::write_atomic`] (nothing half-written) with the error naming `path`.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    softcap_app::write_atomic(path, bytes).map_err(|e| CaptureError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// What `softcap capture calibrate` runs: read the input, calibrate, write the report (when
/// `report_dir` is given) and then the refined rig to `output`. Bad input is detected before
/// anything is written.
pub fn run_calibrate(
    input: &Path,
    cameras: Option<&Path>,
    output: &Path,
    report_dir: Option<&Path>,
    settings: &CalibrateSettings,
    progress: &mut dyn FnMut(&str),
) -> Result<(CalibrationInput, Calibration)> {
    let data = read_calibration_input(input, cameras)?;
    let cal = calibrate(&data, settings, progress)?;
    if let Some(dir) = report_dir {
        report::write_report(dir, &data, &cal)?;
    }
    write_atomic(output, refined_cameras_toml(&data, &cal).as_bytes())?;
    Ok((data, cal))
}
