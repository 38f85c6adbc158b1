//! softcap capture stage: a raw session folder (`docs/session-format.md`) → per-frame markers, probe
//! pose and force, and the camera↔DAQ clock relation (bickel2009 §5, thesis §6.2–6.3).
//!
//! | module | what |
//! |---|---|
//! | [`session`] | reading `session.toml`, `rig/*.toml`, CSV files (errors name file, line, field) |
//! | [`aniposelib`] | aniposelib calibration TOML and labeled 2D points (real multi-camera rigs) |
//! | [`bundle`] | sparse bundle adjustment: robust LM on the Schur complement, explicit gauge |
//! | [`calibrate`] | `softcap capture calibrate`: outlier rounds around [`bundle`], refined rig, report |
//! | [`c3d`] | C3D takes (kind `mocap`): POINT trajectories in metres, ANALOG channels |
//! | [`depth`] | kind `dynamic`: depth images (or PLY clouds) → fused world-frame clouds with normals (wang2015 §4) |
//! | [`camera`] | re-export of `softcap_core::camera::Camera` (pinhole + Brown–Conrady projection, undistortion) |
//! | [`detect`] | marker blobs in images: CIELab thresholds, morphology, weighted centroids |
//! | [`correspond`] | epipolar multi-view matching, labeling to marker ids, tracking |
//! | [`triangulate`](mod@triangulate) | DLT + Levenberg–Marquardt on reprojection error |
//! | [`register`] | Horn's weighted absolute orientation |
//! | [`fill`] | bi-Laplacian linear shell fill-in of occluded markers |
//! | [`probe`] | shaft markers → probe pose; FSR voltage → force |
//! | [`robot`] | URDF forward kinematics of the tool, robot.csv F/T rotated into the world |
//! | [`sync`] | clock offset and drift from trigger edges or from the data |
//! | [`pipeline`] | [`capture`]: the whole stage |
//! | [`output`] | `capture.mcap` via `softcap_mcap` |
//! | [`cli`] | the `softcap-capture` command line ([`cli::Cli::run`]) |
//!
//! ```
//! use softcap_capture::{Camera, PixelObservation, TriangulationSettings, triangulate};
//! use softcap_capture::nalgebra::{Matrix3, Point3, Vector3};
//! let cam = |id: &str, tx: f64| {
//!     Camera::new(id.into(), 640, 480, [700.0, 700.0, 320.0, 240.0], [0.0; 5], Matrix3::identity(), Vector3::new(tx, 0.0, 0.5))
//!         .unwrap()
//! };
//! let cams = [cam("a", 0.1), cam("b", -0.1)];
//! let x = Point3::new(0.01, 0.02, 0.03);
//! let obs: Vec<_> = (0..2).map(|c| PixelObservation { camera: c, uv: cams[c].project(&x).unwrap() }).collect();
//! let t = triangulate(&cams, &obs, &TriangulationSettings::default()).unwrap();
//! assert!((t.position_m - x).norm() < 1e-9);
//! ```

pub mod aniposelib;
pub mod bundle;
pub mod c3d;
pub mod calibrate;
pub mod camera;
pub mod cli;
pub mod correspond;
pub mod depth;
pub mod detect;
pub mod error;
pub mod fill;
mod lm;
pub mod output;
pub mod pipeline;
pub mod probe;
pub mod register;
pub mod robot;
pub mod session;
pub mod sync;
pub mod triangulate;

pub use aniposelib::{read_aniposelib_calibration, read_labeled_points, read_npz_points};
pub use c3d::{AnalogChannels, C3dTake, read_c3d};
pub use camera::Camera;
pub use correspond::{Blob, Candidate, CorrespondenceSettings, find_candidates, label_candidates};
pub use depth::{
    CloudFrame, CloudSource, DepthCamera, DepthCaptureSettings, DynamicCapture, DynamicInputs,
    SupportMotion, capture_dynamic,
};
pub use detect::{DetectionSettings, detect_markers, detect_markers_in_file};
pub use error::{CaptureError, Result};
pub use fill::{FillSettings, FillShell};
pub use nalgebra;
pub use output::{report, write_capture_mcap, write_dynamic_capture_mcap};
pub use pipeline::{
    CameraStats, CaptureResult, CaptureSettings, FrameResult, MarkerObservations, MarkerSample,
    MarkerSource, MarkerState, ProbeSample, capture, capture_mocap,
};
pub use probe::{FsrConversion, FsrModel, ProbePose, probe_pose};
pub use register::{horn_weighted, weight_away_from_probe};
pub use robot::{RobotModel, RobotProbeState, RobotRig};
pub use session::{Detection, MarkerColor, Session, SessionKind, TemplateMarker};
pub use sync::{
    ClockSync, SyncMethod, refine_sync_least_squares, sync_from_data, sync_from_trigger,
    trigger_pulses,
};
pub use triangulate::{
    PixelObservation, Triangulated, TriangulationSettings, triangulate, triangulate_dlt,
};
