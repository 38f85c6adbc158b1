//! The capture pipeline over one session (thesis §6.2.2): 2D markers (images or detections) →
//! multi-view correspondence and labeling → triangulation → registration to the template →
//! fill-in of occluded markers → probe pose and force → clock sync.

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::correspond::{
    Blob, Candidate, CorrespondenceSettings, MarkerPrediction, find_candidates, label_candidates,
    pick_shaft_pair,
};
use crate::detect::{DetectionSettings, detect_markers_in_file};
use crate::error::{CaptureError, Result};
use crate::fill::FillSettings;
use crate::probe::{FsrConversion, FsrModel, probe_pose};
use crate::register::{horn_weighted, weight_away_from_probe};
use crate::robot::RobotRig;
use crate::session::{Detection, MarkerColor, Session, TemplateMarker};
use crate::sync::{
    ClockSync, interpolate, refine_sync_least_squares, sync_from_data, sync_from_trigger,
    trigger_pulses,
};
use crate::triangulate::{PixelObservation, TriangulationSettings, triangulate};

/// Which 2D source to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum MarkerSource {
    /// Images when the session has them, else detections.
    #[default]
    Auto,
    /// Detect markers in `frames/`.
    Images,
    /// Read `detections/`.
    Detections,
}

/// Settings of [`capture`]. Every field has a default; loadable from TOML.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CaptureSettings {
    /// 2D source.
    pub source: MarkerSource,
    /// Marker detection in images.
    pub detection: DetectionSettings,
    /// Correspondence and labeling.
    pub correspondence: CorrespondenceSettings,
    /// Triangulation.
    pub triangulation: TriangulationSettings,
    /// FSR voltage → force.
    pub fsr_conversion: FsrConversion,
    /// Register each frame rigidly to the template (Horn, weighted away from the probe).
    pub register: bool,
    /// Length scale σ of the registration weight `1 − exp(−(d/σ)²)`, m.
    pub registration_sigma_m: f64,
    /// Fill occluded markers with the bi-Laplacian linear shell (needs a template surface).
    pub fill_occluded: bool,
    /// Linear-shell fill-in settings.
    pub fill: FillSettings,
    /// Grid step of the data-driven clock search, s.
    pub data_sync_step_s: f64,
    /// Ignore the trigger line and align clocks from the data.
    pub force_data_sync: bool,
    /// Bound on the relative clock drift fitted by the data-driven sync (crystal tolerance;
    /// 1e-4 = 100 ppm).
    pub data_sync_max_drift: f64,
    /// Longest run of frames without a probe pose (a shaft marker missing from all but one
    /// view) that is bridged by interpolating tip and axis between the frames around it; the
    /// FSR still reads the force in those frames, and without an axis downstream stages would
    /// read no force at all.
    pub probe_gap_frames: usize,
    /// Depth back-projection and downsampling of dynamic sessions.
    pub depth: crate::depth::DepthCaptureSettings,
}

impl Default for CaptureSettings {
    fn default() -> Self {
        CaptureSettings {
            source: MarkerSource::Auto,
            detection: DetectionSettings::default(),
            correspondence: CorrespondenceSettings::default(),
            triangulation: TriangulationSettings::default(),
            fsr_conversion: FsrConversion::PowerLaw,
            register: false,
            registration_sigma_m: 0.015,
            fill_occluded: true,
            fill: FillSettings::default(),
            data_sync_step_s: 0.002,
            force_data_sync: false,
            data_sync_max_drift: 1e-4,
            probe_gap_frames: 5,
            depth: crate::depth::DepthCaptureSettings::default(),
        }
    }
}

/// State of one marker in one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MarkerState {
    /// Triangulated from ≥ 2 views.
    Visible,
    /// Not reconstructable; position filled by the linear shell.
    Filled,
    /// Neither seen nor filled (position is the last known one).
    Missing,
}

/// One marker in one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerSample {
    /// Position, world frame (after registration when enabled), m.
    pub position_m: Point3<f64>,
    /// State.
    pub state: MarkerState,
    /// Number of views used (0 unless visible).
    pub views: usize,
    /// RMS reprojection error, px (NaN unless visible).
    pub reprojection_rms_px: f64,
}

/// Probe state in one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeSample {
    /// Tip centre, m (None when the shaft markers were not both reconstructed and the frame is
    /// not inside a short gap between frames that show the probe, see
    /// [`CaptureSettings::probe_gap_frames`]).
    pub tip_m: Option<Point3<f64>>,
    /// Unit pushing direction (from the shaft markers toward the tip).
    pub axis: Option<Vector3<f64>>,
    /// Force exerted by the probe on the object, world frame, N (`force_magnitude_n · axis`).
    pub force_n: Option<Vector3<f64>>,
    /// Axial force magnitude from the FSR, N.
    pub force_magnitude_n: f64,
    /// Raw FSR voltage at the frame's DAQ time, V.
    pub voltage_v: f64,
    /// Frame mid-exposure on the DAQ clock, s.
    pub t_daq_s: f64,
    /// True when tip and axis were interpolated from the neighbouring frames (a shaft marker was
    /// not reconstructed in this one).
    pub pose_interpolated: bool,
}

/// One reconstructed frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameResult {
    /// Frame index.
    pub frame: usize,
    /// Mid-exposure time on the camera clock, s.
    pub t_camera_s: f64,
    /// Markers, in the order of [`CaptureResult::marker_ids`].
    pub markers: Vec<MarkerSample>,
    /// Probe (probe sessions).
    pub probe: Option<ProbeSample>,
    /// Registration applied (identity when disabled), maps observed → template frame.
    pub registration: Isometry3<f64>,
}

/// Per-camera statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraStats {
    /// Camera id.
    pub id: String,
    /// 2D blobs seen over all frames.
    pub blobs: usize,
    /// Blobs used by a labeled marker.
    pub used: usize,
    /// Mean reprojection error of used blobs, px.
    pub mean_reprojection_px: f64,
    /// Median reprojection error of used blobs, px.
    pub median_reprojection_px: f64,
    /// Largest reprojection error of used blobs, px.
    pub max_reprojection_px: f64,
    /// RMS reprojection error of used blobs, px.
    pub rms_reprojection_px: f64,
}

/// Output of [`capture`].
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureResult {
    /// Session name.
    pub session: String,
    /// Marker ids: template markers, then shaft markers.
    pub marker_ids: Vec<String>,
    /// Number of template (object) markers at the start of `marker_ids`.
    pub object_markers: usize,
    /// Frames.
    pub frames: Vec<FrameResult>,
    /// Clock relation (probe sessions).
    pub sync: Option<ClockSync>,
    /// Per-camera statistics.
    pub cameras: Vec<CameraStats>,
    /// Which 2D source was used.
    pub source: MarkerSource,
    /// Analog channels of a C3D take (kind `mocap`), on the take's clock.
    pub analog: Option<crate::c3d::AnalogChannels>,
    /// The labeled 2D observations each marker was triangulated from, per frame (what
    /// `softcap capture calibrate` refines a rig from); empty for C3D takes.
    pub observations: Vec<MarkerObservations>,
}

/// The 2D observations of one marker in one frame that capture labeled (given or found).
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerObservations {
    /// Frame index.
    pub frame: usize,
    /// Index into [`CaptureResult::marker_ids`].
    pub marker: usize,
    /// One pixel position per camera that saw it (two or more).
    pub observations: Vec<PixelObservation>,
}

impl CaptureResult {
    /// A result without markers or frames (what the `/capture/session` of a dynamic session
    /// describes).
    pub fn empty(session: &str) -> Self {
        Self {
            session: session.to_string(),
            marker_ids: Vec::new(),
            object_markers: 0,
            frames: Vec::new(),
            sync: None,
            cameras: Vec::new(),
            source: MarkerSource::Auto,
            analog: None,
            observations: Vec::new(),
        }
    }
}

struct MarkerInfo {
    id: String,
    color: MarkerColor,
}

/// Groups 2D detections by frame: `frame → per camera blobs`.
fn group_detections(per_camera: &[Vec<Detection>], frames: usize) -> Vec<Vec<Vec<Blob>>> {
    let mut out = vec![vec![Vec::new(); per_camera.len()]; frames];
    for (c, dets) in per_camera.iter().enumerate() {
        for d in dets {
            if d.frame < frames {
                out[d.frame][c].push(Blob {
                    uv: nalgebra::Vector2::new(d.u, d.v),
                    color: d.color,
                    label: d.label.clone(),
                });
            }
        }
    }
    out
}

/// Runs the capture pipeline on a loaded session.
pub fn capture(session: &Session, settings: &CaptureSettings) -> Result<CaptureResult> {
    if session.kind == crate::session::SessionKind::Dynamic {
        return Err(CaptureError::field(
            &session.root.join("session.toml"),
            0,
            "kind",
            "a dynamic session has no markers: capture it with capture_dynamic",
        ));
    }
    if let Some(c3d) = &session.c3d {
        return capture_mocap(session, c3d);
    }
    let cams = &session.cameras;
    if cams.len() < 2 {
        return Err(CaptureError::field(
            session.cameras_path.as_deref().unwrap_or(&session.root),
            0,
            "camera",
            "need at least two cameras to triangulate",
        ));
    }
    let n_frames = session.trigger.last().map(|t| t.0 + 1).unwrap_or(0);
    let t_camera: BTreeMap<usize, f64> = session.trigger.iter().copied().collect();

    let source = match settings.source {
        MarkerSource::Auto if session.images.is_some() => MarkerSource::Images,
        MarkerSource::Auto => MarkerSource::Detections,
        s => s,
    };
    let detections = if source == MarkerSource::Detections {
        Some(session.read_detections()?)
    } else {
        None
    };
    let grouped = detections.as_ref().map(|d| group_detections(d, n_frames));

    let mut infos: Vec<MarkerInfo> = session
        .markers
        .iter()
        .map(|m| MarkerInfo {
            id: m.id.clone(),
            color: m.color,
        })
        .collect();
    let n_obj = infos.len();
    if let Some(p) = &session.probe {
        for s in &p.shaft_markers {
            infos.push(MarkerInfo {
                id: s.id.clone(),
                color: s.color,
            });
        }
    }
    let mut colors: Vec<MarkerColor> = infos.iter().map(|m| m.color).collect();
    colors.sort();
    colors.dedup();
    let index_of: BTreeMap<&str, usize> = infos
        .iter()
        .enumerate()
        .map(|(i, m)| (m.id.as_str(), i))
        .collect();

    let shell = if settings.fill_occluded {
        crate::fill::FillShell::for_session(session, &settings.fill)?
    } else {
        None
    };

    let mut prediction: Vec<Option<Point3<f64>>> =
        session.markers.iter().map(|m| Some(m.position_m)).collect();
    prediction.resize(infos.len(), None);
    let mut max_views = vec![0usize; infos.len()];
    let mut frames = Vec::with_capacity(n_frames);
    let mut blob_counts = vec![0usize; cams.len()];
    let mut residuals: Vec<Vec<f64>> = vec![Vec::new(); cams.len()];
    let mut marker_observations = Vec::new();

    for frame in 0..n_frames {
        let blobs: Vec<Vec<Blob>> = match (&grouped, &session.images) {
            (Some(g), _) => g[frame].clone(),
            (None, Some(dir)) => {
                let mut v = Vec::with_capacity(cams.len());
                for cam in cams {
                    let path = dir.join(&cam.id).join(format!("{frame:06}.png"));
                    v.push(detect_markers_in_file(
                        &path,
                        cam,
                        &colors,
                        &settings.detection,
                    )?);
                }
                v
            }
            (None, None) => unreachable!("source resolved above"),
        };
        for (c, b) in blobs.iter().enumerate() {
            blob_counts[c] += b.len();
        }

        // Per marker: the chosen observations.
        let mut chosen: Vec<Option<Vec<PixelObservation>>> = vec![None; infos.len()];
        let labeled = blobs.iter().flatten().any(|b| b.label.is_some());
        if labeled {
            let mut by_label: BTreeMap<usize, Vec<PixelObservation>> = BTreeMap::new();
            for (c, bs) in blobs.iter().enumerate() {
                for b in bs {
                    if let Some(&m) = b.label.as_deref().and_then(|l| index_of.get(l)) {
                        by_label.entry(m).or_default().push(PixelObservation {
                            camera: c,
                            uv: b.uv,
                        });
                    }
                }
            }
            for (m, obs) in by_label {
                max_views[m] = max_views[m].max(obs.len());
                if obs.len() >= 2 {
                    chosen[m] = Some(obs);
                }
            }
        } else {
            let cands: Vec<Candidate> = find_candidates(
                cams,
                &blobs,
                &settings.correspondence,
                &settings.triangulation,
            );
            let preds: Vec<MarkerPrediction> = (0..n_obj)
                .map(|m| MarkerPrediction {
                    color: infos[m].color,
                    position_m: prediction[m],
                    gate_m: settings.correspondence.marker_gate_m,
                    // With two cameras every candidate is a two-view one.
                    two_view_gate_m: if cams.len() >= 3 {
                        settings.correspondence.two_view_gate_m
                    } else {
                        settings.correspondence.marker_gate_m
                    },
                })
                .collect();
            let mut used = BTreeSet::new();
            let labels = label_candidates(&preds, &cands, &mut used);
            let obs_of = |c: &Candidate| -> Vec<PixelObservation> {
                c.blobs
                    .iter()
                    .map(|&(cam, k)| PixelObservation {
                        camera: cam,
                        uv: blobs[cam][k].uv,
                    })
                    .collect()
            };
            for (m, l) in labels.iter().enumerate() {
                if let Some(c) = l {
                    chosen[m] = Some(obs_of(&cands[*c]));
                }
            }
            if let Some(p) = &session.probe {
                let (a, b) = (&p.shaft_markers[0], &p.shaft_markers[1]);
                let prev = match (prediction[n_obj], prediction[n_obj + 1]) {
                    (Some(x), Some(y)) => Some((x, y)),
                    _ => None,
                };
                let spacing = b.distance_from_tip_m - a.distance_from_tip_m;
                if let Some((i, j)) = pick_shaft_pair(
                    (a.color, b.color),
                    spacing,
                    prev,
                    &cands,
                    &used,
                    &settings.correspondence,
                ) {
                    chosen[n_obj] = Some(obs_of(&cands[i]));
                    chosen[n_obj + 1] = Some(obs_of(&cands[j]));
                }
            }
            for (m, c) in chosen.iter().enumerate() {
                if let Some(o) = c {
                    max_views[m] = max_views[m].max(o.len());
                }
            }
        }

        // Triangulate the chosen observations.
        let mut samples: Vec<MarkerSample> = (0..infos.len())
            .map(|m| MarkerSample {
                position_m: prediction[m].unwrap_or(Point3::origin()),
                state: MarkerState::Missing,
                views: 0,
                reprojection_rms_px: f64::NAN,
            })
            .collect();
        for (m, obs) in chosen.iter().enumerate() {
            let Some(obs) = obs else { continue };
            marker_observations.push(MarkerObservations {
                frame,
                marker: m,
                observations: obs.clone(),
            });
            if let Some(t) = triangulate(cams, obs, &settings.triangulation) {
                for o in obs {
                    if let Some(uv) = cams[o.camera].project(&t.position_m) {
                        residuals[o.camera].push((uv - o.uv).norm());
                    }
                }
                samples[m] = MarkerSample {
                    position_m: t.position_m,
                    state: MarkerState::Visible,
                    views: t.views,
                    reprojection_rms_px: t.reprojection_rms_px,
                };
            }
        }

        // Probe pose.
        let pose = session.probe.as_ref().and_then(|p| {
            let (a, b) = (&samples[n_obj], &samples[n_obj + 1]);
            (a.state == MarkerState::Visible && b.state == MarkerState::Visible)
                .then(|| {
                    probe_pose(
                        &a.position_m,
                        p.shaft_markers[0].distance_from_tip_m,
                        &b.position_m,
                    )
                })
                .flatten()
        });

        // Registration to the template (observed → template frame), weighted away from the probe.
        let mut registration = Isometry3::identity();
        if settings.register {
            let (mut src, mut dst, mut w) = (Vec::new(), Vec::new(), Vec::new());
            for m in 0..n_obj {
                if samples[m].state == MarkerState::Visible {
                    src.push(samples[m].position_m);
                    dst.push(session.markers[m].position_m);
                    w.push(match &pose {
                        Some(p) => weight_away_from_probe(
                            (samples[m].position_m - p.tip_m).norm(),
                            settings.registration_sigma_m,
                        ),
                        None => 1.0,
                    });
                }
            }
            if let Some(t) = horn_weighted(&src, &dst, &w) {
                registration = t;
                for s in samples
                    .iter_mut()
                    .filter(|s| s.state == MarkerState::Visible)
                {
                    s.position_m = t * s.position_m;
                }
            }
        }
        let pose = pose.map(|p| crate::probe::ProbePose {
            tip_m: registration * p.tip_m,
            axis: registration * p.axis,
        });

        // Fill-in of occluded object markers.
        if let Some(shell) = &shell {
            let known: Vec<Option<Point3<f64>>> = (0..n_obj)
                .map(|m| {
                    (samples[m].state == MarkerState::Visible).then_some(samples[m].position_m)
                })
                .collect();
            if known.iter().any(|k| k.is_none()) && known.iter().any(|k| k.is_some()) {
                let filled = shell.fill(&known)?;
                for m in 0..n_obj {
                    if samples[m].state != MarkerState::Visible {
                        samples[m].position_m = filled[m];
                        samples[m].state = MarkerState::Filled;
                    }
                }
            }
        }

        for (m, s) in samples.iter().enumerate() {
            if s.state != MarkerState::Missing {
                prediction[m] = Some(s.position_m);
            }
        }
        frames.push(FrameResult {
            frame,
            t_camera_s: t_camera.get(&frame).copied().unwrap_or(f64::NAN),
            markers: samples,
            probe: pose.map(|p| ProbeSample {
                tip_m: Some(p.tip_m),
                axis: Some(p.axis),
                force_n: None,
                force_magnitude_n: 0.0,
                voltage_v: f64::NAN,
                t_daq_s: f64::NAN,
                pose_interpolated: false,
            }),
            registration,
        });
    }
    if session.probe.is_some() {
        bridge_probe_gaps(&mut frames, settings.probe_gap_frames);
    }

    // A marker never seen in two views can only come from the fill-in; without it, it is bad input.
    for (m, &v) in max_views.iter().enumerate() {
        if v < 2 && (m >= n_obj || shell.is_none()) {
            return Err(CaptureError::TooFewViews {
                marker: infos[m].id.clone(),
                max_views: v,
            });
        }
    }

    // Clock sync and forces.
    let mut sync = None;
    if let (Some(fsr), Some(samples)) = (&session.fsr, &session.fsr_samples) {
        let model = FsrModel::new(fsr, settings.fsr_conversion);
        let t_cam: Vec<f64> = frames.iter().map(|f| f.t_camera_s).collect();
        let from_trigger = match (&samples.trigger_v, settings.force_data_sync) {
            (Some(tr), false) => sync_from_trigger(&t_cam, &trigger_pulses(&samples.t_daq_s, tr)),
            _ => None,
        };
        sync = from_trigger.or_else(|| {
            let force: Vec<f64> = samples
                .voltage_v
                .iter()
                .map(|&v| model.force_n(v))
                .collect();
            let signal = probe_depth_signal(&frames, &session.markers)
                .unwrap_or_else(|| mean_marker_displacement(&frames, &session.markers));
            sync_from_data(
                &t_cam,
                &signal,
                &samples.t_daq_s,
                &force,
                settings.data_sync_step_s,
            )
            .map(|s| {
                let groups = contact_runs(&signal);
                refine_sync_least_squares(
                    &t_cam,
                    &signal,
                    &samples.t_daq_s,
                    &force,
                    Some(&groups),
                    settings.data_sync_max_drift,
                    &s,
                )
            })
        });
        if let Some(s) = &sync {
            for f in frames.iter_mut() {
                let t_daq = s.to_daq(f.t_camera_s);
                let v = interpolate(&samples.t_daq_s, &samples.voltage_v, t_daq);
                let mag = model.force_n(v);
                let p = f.probe.get_or_insert(ProbeSample {
                    tip_m: None,
                    axis: None,
                    force_n: None,
                    force_magnitude_n: 0.0,
                    voltage_v: f64::NAN,
                    t_daq_s: f64::NAN,
                    pose_interpolated: false,
                });
                p.t_daq_s = t_daq;
                p.voltage_v = v;
                p.force_magnitude_n = mag;
                p.force_n = p.axis.map(|a| a * mag);
            }
        }
    }

    // Robot rigs: tool pose by forward kinematics, F/T into the world, clocks from the data.
    if let Some(rc) = &session.robot {
        let rig = RobotRig::load(
            &rc.urdf,
            &rc.samples,
            &rc.tool_link,
            &rc.ft_link,
            session.metres_per_unit,
        )?;
        let t_cam: Vec<f64> = frames.iter().map(|f| f.t_camera_s).collect();
        let t_daq = &rig.samples.t_daq_s;
        // Axial force (along the tool axis) on the DAQ clock.
        let force: Vec<f64> = t_daq
            .iter()
            .map(|&t| rig.state_at(t).map_or(0.0, |s| s.force_n.dot(&s.axis)))
            .collect();
        let signal = probe_depth_signal(&frames, &session.markers)
            .unwrap_or_else(|| mean_marker_displacement(&frames, &session.markers));
        sync = sync_from_data(&t_cam, &signal, t_daq, &force, settings.data_sync_step_s).map(|s| {
            let groups = contact_runs(&signal);
            refine_sync_least_squares(
                &t_cam,
                &signal,
                t_daq,
                &force,
                Some(&groups),
                settings.data_sync_max_drift,
                &s,
            )
        });
        if let Some(s) = &sync {
            for f in frames.iter_mut() {
                let t = s.to_daq(f.t_camera_s);
                if let Some(st) = rig.state_at(t) {
                    f.probe = Some(ProbeSample {
                        tip_m: Some(f.registration * st.tip_m),
                        axis: Some(f.registration * st.axis),
                        force_n: Some(f.registration * st.force_n),
                        force_magnitude_n: st.force_n.dot(&st.axis),
                        voltage_v: f64::NAN,
                        t_daq_s: t,
                        pose_interpolated: false,
                    });
                }
            }
        }
    }

    let cameras = cams
        .iter()
        .enumerate()
        .map(|(c, cam)| {
            let mut r = residuals[c].clone();
            r.sort_by(f64::total_cmp);
            CameraStats {
                id: cam.id.clone(),
                blobs: blob_counts[c],
                used: r.len(),
                mean_reprojection_px: r.iter().sum::<f64>() / r.len().max(1) as f64,
                median_reprojection_px: median_sorted(&r),
                max_reprojection_px: r.last().copied().unwrap_or(0.0),
                rms_reprojection_px: (r.iter().map(|x| x * x).sum::<f64>() / r.len().max(1) as f64)
                    .sqrt(),
            }
        })
        .collect();

    Ok(CaptureResult {
        session: session.name.clone(),
        marker_ids: infos.into_iter().map(|m| m.id).collect(),
        object_markers: n_obj,
        frames,
        sync,
        cameras,
        source,
        analog: None,
        observations: marker_observations,
    })
}

/// The capture of a C3D take (session kind `mocap`, `files.c3d`): the template markers (by id =
/// POINT:LABELS) per frame, already reconstructed by the mocap system (state visible, 0 views,
/// no reprojection error); invalid points are missing (position = last known, else rest). Frame
/// `k` is at `t_camera_s = k / POINT:RATE`. The analog channels are carried in the result.
pub fn capture_mocap(session: &Session, c3d_path: &std::path::Path) -> Result<CaptureResult> {
    let take = crate::c3d::read_c3d(c3d_path)?;
    let columns: Vec<usize> = session
        .markers
        .iter()
        .map(|m| {
            take.marker_index(&m.id)
                .ok_or_else(|| CaptureError::Format {
                    path: c3d_path.to_path_buf(),
                    message: format!(
                        "marker `{}` of the template is not in POINT:LABELS ({} labels)",
                        m.id,
                        take.marker_labels.len()
                    ),
                })
        })
        .collect::<Result<_>>()?;
    let mut last: Vec<Point3<f64>> = session.markers.iter().map(|m| m.position_m).collect();
    let frames = take
        .positions_m
        .iter()
        .enumerate()
        .map(|(k, row)| FrameResult {
            frame: k,
            t_camera_s: take.frame_time_s(k),
            markers: columns
                .iter()
                .enumerate()
                .map(|(m, &c)| match row[c] {
                    Some(p) => {
                        last[m] = p;
                        MarkerSample {
                            position_m: p,
                            state: MarkerState::Visible,
                            views: 0,
                            reprojection_rms_px: f64::NAN,
                        }
                    }
                    None => MarkerSample {
                        position_m: last[m],
                        state: MarkerState::Missing,
                        views: 0,
                        reprojection_rms_px: f64::NAN,
                    },
                })
                .collect(),
            probe: None,
            registration: Isometry3::identity(),
        })
        .collect();
    Ok(CaptureResult {
        session: session.name.clone(),
        marker_ids: session.markers.iter().map(|m| m.id.clone()).collect(),
        object_markers: session.markers.len(),
        frames,
        sync: None,
        cameras: Vec::new(),
        source: MarkerSource::Auto,
        analog: Some(take.analog),
        observations: Vec::new(),
    })
}

/// Bridges runs of at most `max_gap` frames without a probe pose that lie between two frames with
/// one: the tip linearly in camera time, the axis by normalized linear interpolation. The probe
/// is a rigid body moving smoothly at the frame rate, so a frame in which a shaft marker dropped
/// out of all but one view keeps its pose (and so its force vector) instead of losing it.
pub fn bridge_probe_gaps(frames: &mut [FrameResult], max_gap: usize) {
    let pose = |f: &FrameResult| f.probe.as_ref().and_then(|p| Some((p.tip_m?, p.axis?)));
    let mut k = 0;
    while k < frames.len() {
        if pose(&frames[k]).is_some() {
            k += 1;
            continue;
        }
        let start = k;
        while k < frames.len() && pose(&frames[k]).is_none() {
            k += 1;
        }
        if start == 0 || k == frames.len() || k - start > max_gap {
            continue;
        }
        let (Some((tip0, axis0)), Some((tip1, axis1))) =
            (pose(&frames[start - 1]), pose(&frames[k]))
        else {
            continue;
        };
        let (t0, t1) = (frames[start - 1].t_camera_s, frames[k].t_camera_s);
        for f in &mut frames[start..k] {
            let s = if t1 > t0 {
                ((f.t_camera_s - t0) / (t1 - t0)).clamp(0.0, 1.0)
            } else {
                0.5
            };
            let axis = (axis0 * (1.0 - s) + axis1 * s).try_normalize(1e-12);
            let p = f.probe.get_or_insert(ProbeSample {
                tip_m: None,
                axis: None,
                force_n: None,
                force_magnitude_n: 0.0,
                voltage_v: f64::NAN,
                t_daq_s: f64::NAN,
                pose_interpolated: false,
            });
            p.tip_m = Some(tip0 + (tip1 - tip0) * s);
            p.axis = axis;
            p.pose_interpolated = axis.is_some();
        }
    }
}

/// Probe depth below the rest surface per frame, the camera-side signal of the data-driven clock
/// sync: with the tip `p` and pushing axis `a`, the largest `(p − m)·a` over the rest template
/// markers `m` laterally within twice the third-nearest marker's distance from the probe axis
/// (the most upstream of them lie on the surface facing the probe; markers on side faces lie
/// further downstream), clamped at 0 (no contact). Frames without a probe pose get 0. `None`
/// when fewer than three frames show the probe in contact.
pub fn probe_depth_signal(frames: &[FrameResult], rest: &[TemplateMarker]) -> Option<Vec<f64>> {
    if rest.len() < 3 {
        return None;
    }
    let depth: Vec<f64> = frames
        .iter()
        .map(|f| {
            let Some((tip, axis)) = f.probe.as_ref().and_then(|p| Some((p.tip_m?, p.axis?))) else {
                return 0.0;
            };
            let mut near: Vec<(f64, f64)> = rest
                .iter()
                .map(|m| {
                    let d = tip - m.position_m;
                    let along = d.dot(&axis);
                    ((d - axis * along).norm(), along)
                })
                .collect();
            near.sort_by(|x, y| x.0.total_cmp(&y.0));
            let radius = 2.0 * near[2].0;
            near.iter()
                .take_while(|n| n.0 <= radius)
                .map(|n| n.1)
                .fold(f64::NEG_INFINITY, f64::max)
                .max(0.0)
        })
        .collect();
    (depth.iter().filter(|&&d| d > 0.0).count() >= 3).then_some(depth)
}

/// Slope groups of the data-driven clock fit: each run of consecutive frames with a positive
/// signal (one press at one probe location) is a group; frames without contact (signal 0, so
/// their slope does not matter) join group 0.
pub fn contact_runs(signal: &[f64]) -> Vec<usize> {
    let mut out = vec![0; signal.len()];
    let (mut run, mut in_contact) = (0usize, false);
    for (k, &d) in signal.iter().enumerate() {
        if d > 0.0 {
            if !in_contact && signal[..k].iter().any(|&x| x > 0.0) {
                run += 1;
            }
            in_contact = true;
            out[k] = run;
        } else {
            in_contact = false;
        }
    }
    out
}

/// Mean displacement of the visible object markers from rest per frame (the fallback camera-side
/// signal of the data-driven clock sync when the probe is not tracked).
pub fn mean_marker_displacement(frames: &[FrameResult], rest: &[TemplateMarker]) -> Vec<f64> {
    frames
        .iter()
        .map(|f| {
            let (mut s, mut n) = (0.0, 0);
            for (m, r) in f.markers.iter().zip(rest) {
                if m.state == MarkerState::Visible {
                    s += (m.position_m - r.position_m).norm();
                    n += 1;
                }
            }
            if n > 0 { s / n as f64 } else { 0.0 }
        })
        .collect()
}

/// Median of a sorted slice (NaN when empty).
pub fn median_sorted(v: &[f64]) -> f64 {
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(k: usize, tip_z: Option<f64>) -> FrameResult {
        FrameResult {
            frame: k,
            t_camera_s: 0.1 * k as f64,
            markers: Vec::new(),
            probe: tip_z.map(|z| ProbeSample {
                tip_m: Some(Point3::new(0.0, 0.0, z)),
                axis: Some(-Vector3::z()),
                force_n: None,
                force_magnitude_n: 0.0,
                voltage_v: f64::NAN,
                t_daq_s: f64::NAN,
                pose_interpolated: false,
            }),
            registration: Isometry3::identity(),
        }
    }

    #[test]
    fn a_frame_without_shaft_markers_gets_the_interpolated_pose() {
        let mut frames = vec![
            frame(0, Some(0.02)),
            frame(1, None),
            frame(2, Some(0.018)),
            frame(3, None),
            frame(4, None),
            frame(5, None),
        ];
        bridge_probe_gaps(&mut frames, 5);
        let p = frames[1].probe.as_ref().unwrap();
        assert!(p.pose_interpolated);
        assert!((p.tip_m.unwrap().z - 0.019).abs() < 1e-12);
        assert!((p.axis.unwrap() + Vector3::z()).norm() < 1e-12);
        // A gap at the end has no frame after it: left without a pose.
        assert!(frames[3..].iter().all(|f| f.probe.is_none()));
        // Longer gaps than the setting are not bridged.
        let mut frames = vec![
            frame(0, Some(0.02)),
            frame(1, None),
            frame(2, None),
            frame(3, Some(0.02)),
        ];
        bridge_probe_gaps(&mut frames, 1);
        assert!(frames[1].probe.is_none() && frames[2].probe.is_none());
    }
}
