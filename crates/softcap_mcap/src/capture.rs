//! Typed reading of a `capture.mcap` (the output of `softcap capture`): session information,
//! per-frame markers and probe samples, the clock relation, so every later stage (tissue,
//! diagnose) interprets a capture the same way.
//!
//! ```
//! use softcap_mcap::capture::{CaptureData, ProbeLocationSettings};
//! use softcap_mcap::{proto, topics, Provenance, Writer};
//! # fn main() -> Result<(), softcap_mcap::Error> {
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("capture.mcap");
//! let mut w = Writer::create(&path, &Provenance::new("capture", "0"))?;
//! let v = |x, y, z| Some(proto::Vec3 { x, y, z });
//! w.write_static(&topics::SESSION, &proto::SessionInfo {
//!     name: "demo".into(), kind: "probe".into(), marker_ids: vec!["m0".into()],
//!     object_markers: 1, rest_positions_m: vec![proto::Vec3 { x: 0.0, y: 0.0, z: 0.02 }],
//!     ..Default::default()
//! })?;
//! for frame in 0..3u64 {
//!     let z = 0.02 - 0.001 * frame as f64;
//!     let marker = proto::Marker { id: 0, position_m: v(0.0, 0.0, z), visible: true, ..Default::default() };
//!     w.write(&topics::MARKERS, frame * 100_000_000, &proto::MarkerFrame {
//!         frame, t_camera_s: 0.1 * frame as f64, markers: vec![marker] })?;
//!     w.write(&topics::PROBE, frame * 100_000_000, &proto::ProbeSample {
//!         frame, t_camera_s: 0.1 * frame as f64, tip_m: v(0.0, 0.0, z), axis: v(0.0, 0.0, -1.0),
//!         force_n: v(0.0, 0.0, -(frame as f64)), voltage_v: 0.0 })?;
//! }
//! w.finish()?;
//! let capture = CaptureData::read(&path)?;
//! assert_eq!(capture.frames.len(), 3);
//! assert!((capture.frames[2].marker(0).unwrap().position_m[2] - 0.018).abs() < 1e-15);
//! let locations = capture.probe_locations(&ProbeLocationSettings::default());
//! assert_eq!(locations.len(), 1);
//! # Ok(()) }
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::proto;
use crate::reader::Recording;
use crate::topics;

/// Session information of a capture (`/capture/session`, `softcap.SessionInfo`), with vectors as
/// arrays (SI, world frame).
#[derive(Debug, Clone, PartialEq)]
pub struct SessionInfo {
    /// Session name.
    pub name: String,
    /// `probe` | `probe-robot` | `mocap`.
    pub kind: String,
    /// Marker ids; `MarkerObservation::id` indexes this list.
    pub marker_ids: Vec<String>,
    /// Number of object markers at the start of `marker_ids`.
    pub object_markers: usize,
    /// Rest positions of the object markers, m (length `object_markers`).
    pub rest_positions_m: Vec<[f64; 3]>,
    /// Gravity, m/s².
    pub gravity_m_s2: [f64; 3],
    /// Support plane, if the session has one.
    pub support: Option<SupportPlane>,
    /// Density, kg/m³, if known.
    pub density_kg_m3: Option<f64>,
    /// Tip shape `disk` | `sphere` | `mesh` (empty without a probe).
    pub tip_shape: String,
    /// Tip radius, m (disk / sphere).
    pub tip_radius_m: f64,
    /// Tip mesh path (session-relative) for a mesh tip.
    pub tip_mesh_path: String,
    /// Convention of the probe axis (`handle-to-tip`).
    pub shaft_direction: String,
    /// True if the DAQ recorded the trigger line.
    pub trigger_present: bool,
}

/// Support plane: points with |n·x − offset| ≤ tolerance are attached.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SupportPlane {
    /// Unit normal (into the object).
    pub normal: [f64; 3],
    /// Offset along the normal, m.
    pub offset_m: f64,
    /// Tolerance, m.
    pub tolerance_m: f64,
}

impl SupportPlane {
    /// Signed distance n·x − offset of a point, m.
    pub fn signed_distance_m(&self, x: &[f64; 3]) -> f64 {
        self.normal[0] * x[0] + self.normal[1] * x[1] + self.normal[2] * x[2] - self.offset_m
    }
}

/// One marker in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerObservation {
    /// Index into [`SessionInfo::marker_ids`].
    pub id: u32,
    /// Position, m, world frame.
    pub position_m: [f64; 3],
    /// Triangulated in this frame.
    pub visible: bool,
    /// Filled in (occluded; predicted, not measured).
    pub filled: bool,
}

/// The probe at one frame (fields absent when capture could not estimate them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeObservation {
    /// Tip position, m.
    pub tip_m: Option<[f64; 3]>,
    /// Unit shaft axis, handle → tip.
    pub axis: Option<[f64; 3]>,
    /// Force exerted by the probe on the object, N, world frame.
    pub force_n: Option<[f64; 3]>,
    /// Raw FSR voltage, V.
    pub voltage_v: f64,
}

impl ProbeObservation {
    /// |force|, N (0 when unknown).
    pub fn force_magnitude_n(&self) -> f64 {
        self.force_n.map(norm).unwrap_or(0.0)
    }
}

/// Markers and probe of one camera frame.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureFrame {
    /// Frame index (0 = rest).
    pub frame: u64,
    /// Camera time, s.
    pub t_camera_s: f64,
    /// Log time, ns.
    pub log_time_ns: u64,
    /// Markers present in this frame, sorted by id.
    pub markers: Vec<MarkerObservation>,
    /// Probe sample, if the frame has one.
    pub probe: Option<ProbeObservation>,
}

impl CaptureFrame {
    /// The marker with index `id`, if present in this frame.
    pub fn marker(&self, id: u32) -> Option<&MarkerObservation> {
        self.markers
            .binary_search_by_key(&id, |m| m.id)
            .ok()
            .map(|i| &self.markers[i])
    }
}

/// Phase of a frame in the probing protocol: rest, then per probe location a loading ramp, a
/// hold at the deepest point and an unloading ramp, then released until the next contact.
///
/// The one definition every stage uses: the virtual rig schedules its frames by it (the truth;
/// `truth/frames.csv` of a synthesized session), [`CaptureData::phases`] classifies a capture's
/// frames from the force trace, the diagnosis segments its recording by it and writes
/// [`Phase::name`] into diagnosis.mcap. It lives in the format crate, where the stages meet:
/// the shared probing layer (`softcap_probing`) sits on the FEM crates, which a format must not
/// depend on, and the rig depends on this crate for it. Serialized by its lowercase
/// [`Phase::name`].
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// Before the first contact of the session.
    Rest,
    /// In contact, probe advancing: force rising.
    Loading,
    /// In contact, probe (nearly) still at its deepest: force about constant at its peak.
    Hold,
    /// In contact, probe retracting: force falling.
    Unloading,
    /// Out of contact after some contact (probe lifted, moving to the next location).
    Released,
}

impl Phase {
    /// All phases in time order.
    pub const ALL: [Phase; 5] = [
        Phase::Rest,
        Phase::Loading,
        Phase::Hold,
        Phase::Unloading,
        Phase::Released,
    ];

    /// The lowercase name used in reports, JSON and CSV (`rest`, `loading`, `hold`,
    /// `unloading`, `released`).
    pub fn name(self) -> &'static str {
        match self {
            Phase::Rest => "rest",
            Phase::Loading => "loading",
            Phase::Hold => "hold",
            Phase::Unloading => "unloading",
            Phase::Released => "released",
        }
    }

    /// True while the probe touches the object.
    pub fn in_contact(self) -> bool {
        matches!(self, Phase::Loading | Phase::Hold | Phase::Unloading)
    }
}

/// Settings of the grouping of frames into probe locations.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProbeLocationSettings {
    /// A frame is in contact when |force| exceeds this, N.
    pub contact_force_n: f64,
    /// Consecutive contact frames whose tips (projected on the plane ⟂ the axis) stay within this
    /// distance of the location's first contact tip belong to one location, m.
    pub tip_radius_m: f64,
    /// |Δforce| below this fraction of the location's peak force counts as a hold.
    pub hold_fraction: f64,
}

impl Default for ProbeLocationSettings {
    fn default() -> Self {
        Self {
            contact_force_n: 0.02,
            tip_radius_m: 0.003,
            hold_fraction: 0.02,
        }
    }
}

/// One probe location: a contiguous run of contact frames (one ramp/hold/release).
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeLocation {
    /// Location index (order of first contact).
    pub index: usize,
    /// Indices into [`CaptureData::frames`] of the contact frames, increasing.
    pub frames: Vec<usize>,
    /// Phase of each of those frames.
    pub phases: Vec<Phase>,
    /// Tip at the first contact frame, m.
    pub first_tip_m: [f64; 3],
    /// Index into `frames` of the peak-force frame.
    pub peak: usize,
    /// Peak |force|, N.
    pub peak_force_n: f64,
}

/// A capture read into memory: [`CaptureData::read`].
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureData {
    /// The file read.
    pub path: PathBuf,
    /// `/capture/session`.
    pub session: SessionInfo,
    /// Frames sorted by frame index (markers and probe joined by frame).
    pub frames: Vec<CaptureFrame>,
    /// `/capture/clock_sync`, if present.
    pub clock_sync: Option<proto::ClockSync>,
    /// `/capture/report`, if present.
    pub report: Option<proto::Report>,
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

fn invalid(path: &Path, topic: &str, field: String, problem: &str) -> Error {
    Error::Invalid {
        path: path.to_path_buf(),
        topic: topic.to_string(),
        field,
        problem: problem.to_string(),
    }
}

fn vec3(
    path: &Path,
    topic: &str,
    field: impl Fn() -> String,
    v: &Option<proto::Vec3>,
) -> Result<Option<[f64; 3]>> {
    match v {
        None => Ok(None),
        Some(v) => {
            let a = [v.x, v.y, v.z];
            if a.iter().all(|c| c.is_finite()) {
                Ok(Some(a))
            } else {
                Err(invalid(path, topic, field(), "not finite"))
            }
        }
    }
}

impl SessionInfo {
    /// Converts and validates a `softcap.SessionInfo` read from `path`.
    pub fn from_proto(path: &Path, m: &proto::SessionInfo) -> Result<Self> {
        let topic = "/capture/session";
        let object_markers = m.object_markers as usize;
        if object_markers > m.marker_ids.len() {
            return Err(invalid(
                path,
                topic,
                "object_markers".into(),
                "larger than the number of marker_ids",
            ));
        }
        if m.rest_positions_m.len() != object_markers {
            return Err(invalid(
                path,
                topic,
                "rest_positions_m".into(),
                "length differs from object_markers",
            ));
        }
        let rest = m
            .rest_positions_m
            .iter()
            .enumerate()
            .map(|(i, v)| {
                vec3(path, topic, || format!("rest_positions_m[{i}]"), &Some(*v))
                    .map(|a| a.unwrap_or_default())
            })
            .collect::<Result<Vec<_>>>()?;
        let gravity = vec3(path, topic, || "gravity_m_s2".into(), &m.gravity_m_s2)?
            .unwrap_or([0.0, 0.0, 0.0]);
        let support = match &m.support {
            None => None,
            Some(s) => {
                let n = vec3(path, topic, || "support.normal".into(), &s.normal)?
                    .ok_or_else(|| invalid(path, topic, "support.normal".into(), "missing"))?;
                let len = norm(n);
                let valid = len > 0.0 && s.offset_m.is_finite() && s.tolerance_m >= 0.0;
                if !valid {
                    return Err(invalid(
                        path,
                        topic,
                        "support".into(),
                        "zero normal or non-finite offset / negative tolerance",
                    ));
                }
                Some(SupportPlane {
                    normal: [n[0] / len, n[1] / len, n[2] / len],
                    offset_m: s.offset_m,
                    tolerance_m: s.tolerance_m,
                })
            }
        };
        if let Some(d) = m.density_kg_m3
            && (d.is_nan() || d <= 0.0 || d.is_infinite())
        {
            return Err(invalid(
                path,
                topic,
                "density_kg_m3".into(),
                "must be positive",
            ));
        }
        let radius_ok = m.tip_radius_m >= 0.0 && m.tip_radius_m.is_finite();
        if !radius_ok {
            return Err(invalid(
                path,
                topic,
                "tip_radius_m".into(),
                "must be finite and non-negative",
            ));
        }
        Ok(Self {
            name: m.name.clone(),
            kind: m.kind.clone(),
            marker_ids: m.marker_ids.clone(),
            object_markers,
            rest_positions_m: rest,
            gravity_m_s2: gravity,
            support,
            density_kg_m3: m.density_kg_m3,
            tip_shape: m.tip_shape.clone(),
            tip_radius_m: m.tip_radius_m,
            tip_mesh_path: m.tip_mesh_path.clone(),
            shaft_direction: m.shaft_direction.clone(),
            trigger_present: m.trigger_present,
        })
    }
}

impl CaptureData {
    /// Reads and validates a capture: `/capture/session` (required), `/capture/markers`
    /// (required), `/capture/probe`, `/capture/clock_sync`, `/capture/report` (optional).
    /// Errors name the file, channel and field (non-finite values, marker ids out of range,
    /// duplicate frames).
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let recording = Recording::open(path)?;
        Self::from_recording(&recording)
    }

    /// As [`Self::read`] on an opened recording.
    pub fn from_recording(r: &Recording) -> Result<Self> {
        let path = r.path().to_path_buf();
        let session = SessionInfo::from_proto(&path, &r.read_static(&topics::SESSION)?)?;
        let mtopic = "/capture/markers";
        let mut frames: BTreeMap<u64, CaptureFrame> = BTreeMap::new();
        for (t, m) in r.read(&topics::MARKERS)? {
            let mut markers = Vec::with_capacity(m.markers.len());
            for (k, mk) in m.markers.iter().enumerate() {
                if mk.id as usize >= session.marker_ids.len() {
                    return Err(invalid(
                        &path,
                        mtopic,
                        format!("frame {} markers[{k}].id", m.frame),
                        "not an index into /capture/session marker_ids",
                    ));
                }
                let p = vec3(
                    &path,
                    mtopic,
                    || format!("frame {} markers[{k}].position_m", m.frame),
                    &mk.position_m,
                )?
                .ok_or_else(|| {
                    invalid(
                        &path,
                        mtopic,
                        format!("frame {} markers[{k}].position_m", m.frame),
                        "missing",
                    )
                })?;
                markers.push(MarkerObservation {
                    id: mk.id,
                    position_m: p,
                    visible: mk.visible,
                    filled: mk.filled,
                });
            }
            markers.sort_by_key(|m| m.id);
            if markers.windows(2).any(|w| w[0].id == w[1].id) {
                return Err(invalid(
                    &path,
                    mtopic,
                    format!("frame {} markers", m.frame),
                    "duplicate marker id",
                ));
            }
            if !m.t_camera_s.is_finite() {
                return Err(invalid(
                    &path,
                    mtopic,
                    format!("frame {} t_camera_s", m.frame),
                    "not finite",
                ));
            }
            let previous = frames.insert(
                m.frame,
                CaptureFrame {
                    frame: m.frame,
                    t_camera_s: m.t_camera_s,
                    log_time_ns: t,
                    markers,
                    probe: None,
                },
            );
            if previous.is_some() {
                return Err(invalid(
                    &path,
                    mtopic,
                    format!("frame {}", m.frame),
                    "frame logged twice",
                ));
            }
        }
        if r.channel(topics::PROBE.name()).is_some() {
            let ptopic = "/capture/probe";
            for (_, p) in r.read(&topics::PROBE)? {
                let f = p.frame;
                let obs = ProbeObservation {
                    tip_m: vec3(&path, ptopic, || format!("frame {f} tip_m"), &p.tip_m)?,
                    axis: vec3(&path, ptopic, || format!("frame {f} axis"), &p.axis)?,
                    force_n: vec3(&path, ptopic, || format!("frame {f} force_n"), &p.force_n)?,
                    voltage_v: p.voltage_v,
                };
                match frames.get_mut(&f) {
                    Some(frame) => frame.probe = Some(obs),
                    None => {
                        return Err(invalid(
                            &path,
                            ptopic,
                            format!("frame {f}"),
                            "probe sample of a frame absent from /capture/markers",
                        ));
                    }
                }
            }
        }
        let clock_sync = if r.channel(topics::CLOCK_SYNC.name()).is_some() {
            Some(r.read_static(&topics::CLOCK_SYNC)?)
        } else {
            None
        };
        let report = if r.channel(topics::CAPTURE_REPORT.name()).is_some() {
            Some(r.read_static(&topics::CAPTURE_REPORT)?)
        } else {
            None
        };
        Ok(Self {
            path,
            session,
            frames: frames.into_values().collect(),
            clock_sync,
            report,
        })
    }

    /// Groups the frames into probe locations (one ramp/hold/release each): a location is a
    /// maximal run of consecutive contact frames (|force| > `contact_force_n`) whose tips stay
    /// within `tip_radius_m` of the run's first tip (measured ⟂ the probe axis, so pressing
    /// deeper does not split a location). Phases: loading while the force rises, hold while it
    /// changes by less than `hold_fraction` × peak, unloading while it falls.
    pub fn probe_locations(&self, settings: &ProbeLocationSettings) -> Vec<ProbeLocation> {
        let mut out: Vec<ProbeLocation> = Vec::new();
        let mut current: Option<(Vec<usize>, [f64; 3], [f64; 3])> = None;
        let close = |run: &mut Option<(Vec<usize>, [f64; 3], [f64; 3])>,
                     out: &mut Vec<ProbeLocation>| {
            if let Some((frames, tip, _)) = run.take() {
                let forces: Vec<f64> = frames
                    .iter()
                    .map(|&i| {
                        self.frames[i]
                            .probe
                            .map(|p| p.force_magnitude_n())
                            .unwrap_or(0.0)
                    })
                    .collect();
                let (peak, peak_force) = forces.iter().copied().enumerate().fold(
                    (0, f64::NEG_INFINITY),
                    |(bi, bf), (i, f)| {
                        if f > bf { (i, f) } else { (bi, bf) }
                    },
                );
                let tol = settings.hold_fraction * peak_force;
                let phases = (0..forces.len())
                    .map(|k| {
                        let prev = if k == 0 { 0.0 } else { forces[k - 1] };
                        let d = forces[k] - prev;
                        if d.abs() <= tol {
                            Phase::Hold
                        } else if d > 0.0 {
                            Phase::Loading
                        } else {
                            Phase::Unloading
                        }
                    })
                    .collect();
                out.push(ProbeLocation {
                    index: out.len(),
                    frames,
                    phases,
                    first_tip_m: tip,
                    peak,
                    peak_force_n: peak_force,
                });
            }
        };
        for (i, f) in self.frames.iter().enumerate() {
            let contact = f.probe.and_then(|p| {
                (p.force_magnitude_n() > settings.contact_force_n).then_some(p.tip_m)?
            });
            match contact {
                Some(tip) => {
                    let axis = f.probe.and_then(|p| p.axis).unwrap_or([0.0, 0.0, 0.0]);
                    let same = current.as_ref().is_some_and(|(frames, t0, a0)| {
                        let last = *frames.last().unwrap_or(&usize::MAX);
                        let d = [tip[0] - t0[0], tip[1] - t0[1], tip[2] - t0[2]];
                        let along = d[0] * a0[0] + d[1] * a0[1] + d[2] * a0[2];
                        let perp = [
                            d[0] - along * a0[0],
                            d[1] - along * a0[1],
                            d[2] - along * a0[2],
                        ];
                        last + 1 == i && norm(perp) <= settings.tip_radius_m
                    });
                    if same {
                        if let Some((frames, _, _)) = current.as_mut() {
                            frames.push(i);
                        }
                    } else {
                        close(&mut current, &mut out);
                        current = Some((vec![i], tip, axis));
                    }
                }
                None => close(&mut current, &mut out),
            }
        }
        close(&mut current, &mut out);
        out
    }

    /// Phase of every frame: [`Phase::Rest`] before the first contact, the location's phase
    /// during contact, [`Phase::Released`] out of contact after some contact.
    pub fn phases(&self, locations: &[ProbeLocation]) -> Vec<Phase> {
        let mut phases = vec![Phase::Rest; self.frames.len()];
        let first = locations
            .iter()
            .flat_map(|l| l.frames.first())
            .min()
            .copied();
        if let Some(first) = first {
            for p in phases.iter_mut().skip(first) {
                *p = Phase::Released;
            }
        }
        for l in locations {
            for (&i, &ph) in l.frames.iter().zip(&l.phases) {
                phases[i] = ph;
            }
        }
        phases
    }

    /// Index into `frames` of the rest frame (frame 0 if present, else the first frame).
    pub fn rest_frame(&self) -> Option<usize> {
        if self.frames.is_empty() {
            None
        } else {
            Some(self.frames.iter().position(|f| f.frame == 0).unwrap_or(0))
        }
    }
}
