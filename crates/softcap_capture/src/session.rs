//! Reading a raw session folder (`docs/session-format.md`, version 1): `session.toml`, `rig/*.toml` and
//! the CSV files. Every length is converted to SI metres on reading; errors name file, line and field.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Point3, Vector3};
use serde::Deserialize;

use crate::camera::Camera;
use crate::error::{CaptureError, Result};

/// Marker paint colour (`template/markers.csv`, `detections/*.csv`, `rig/probe.toml`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum MarkerColor {
    /// blue
    Blue,
    /// green
    Green,
    /// red
    Red,
    /// yellow
    Yellow,
    /// magenta
    Magenta,
    /// cyan
    Cyan,
    /// white
    White,
    /// black
    Black,
}

impl MarkerColor {
    /// All colours, in a fixed order.
    pub const ALL: [MarkerColor; 8] = [
        MarkerColor::Blue,
        MarkerColor::Green,
        MarkerColor::Red,
        MarkerColor::Yellow,
        MarkerColor::Magenta,
        MarkerColor::Cyan,
        MarkerColor::White,
        MarkerColor::Black,
    ];

    /// Parses a lowercase colour name.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "blue" => MarkerColor::Blue,
            "green" => MarkerColor::Green,
            "red" => MarkerColor::Red,
            "yellow" => MarkerColor::Yellow,
            "magenta" => MarkerColor::Magenta,
            "cyan" => MarkerColor::Cyan,
            "white" => MarkerColor::White,
            "black" => MarkerColor::Black,
            _ => return None,
        })
    }

    /// The lowercase name.
    pub fn name(self) -> &'static str {
        match self {
            MarkerColor::Blue => "blue",
            MarkerColor::Green => "green",
            MarkerColor::Red => "red",
            MarkerColor::Yellow => "yellow",
            MarkerColor::Magenta => "magenta",
            MarkerColor::Cyan => "cyan",
            MarkerColor::White => "white",
            MarkerColor::Black => "black",
        }
    }
}

/// Session kind (`session.toml` `kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum SessionKind {
    /// Hand-held FSR probe (bickel2009 §5, thesis §6.2).
    Probe,
    /// Robot arm with a 6-axis force/torque sensor (thesis §6.3).
    ProbeRobot,
    /// Marker motion capture only (C3D).
    Mocap,
    /// Depth cameras (or fused point clouds) watching a freely moving object (wang2015); see
    /// [`crate::depth`].
    Dynamic,
}

/// A painted marker on the object at rest (`template/markers.csv`).
#[derive(Debug, Clone, PartialEq)]
pub struct TemplateMarker {
    /// Unique id.
    pub id: String,
    /// Rest position, world frame, metres.
    pub position_m: Point3<f64>,
    /// Paint colour.
    pub color: MarkerColor,
}

/// One 2D blob (`detections/<camera>.csv`, or found in an image).
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Frame index.
    pub frame: usize,
    /// Pixel column of the centroid.
    pub u: f64,
    /// Pixel row of the centroid.
    pub v: f64,
    /// Blob colour.
    pub color: MarkerColor,
    /// Marker id when the correspondence is given.
    pub label: Option<String>,
}

/// FSR wiring and calibration (`rig/fsr.toml`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct FsrConfig {
    /// Divider supply voltage.
    pub supply_v: f64,
    /// Divider resistor, ohm.
    pub divider_ohm: f64,
    /// Calibration table `[force_n, voltage_v]`, increasing in both.
    pub calibration: Vec<[f64; 2]>,
}

/// DAQ samples of the FSR (`fsr.csv`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FsrSamples {
    /// Sample times on the DAQ clock, s.
    pub t_daq_s: Vec<f64>,
    /// FSR divider voltage, V.
    pub voltage_v: Vec<f64>,
    /// Camera trigger line sampled by the DAQ, V (absent without a trigger line).
    pub trigger_v: Option<Vec<f64>>,
}

/// Probe tip shape.
#[derive(Debug, Clone, PartialEq)]
pub enum TipShape {
    /// Flat disk of the given radius (m), face perpendicular to the shaft.
    Disk {
        /// Radius, m.
        radius_m: f64,
    },
    /// Sphere of the given radius (m).
    Sphere {
        /// Radius, m.
        radius_m: f64,
    },
    /// Tip mesh (OBJ) in the probe frame.
    Mesh {
        /// Path of the OBJ file.
        path: PathBuf,
    },
}

/// A marker on the probe shaft.
#[derive(Debug, Clone, PartialEq)]
pub struct ShaftMarker {
    /// Marker id.
    pub id: String,
    /// Distance from the tip along the shaft, m.
    pub distance_from_tip_m: f64,
    /// Paint colour.
    pub color: MarkerColor,
}

/// The probe (`rig/probe.toml`).
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeConfig {
    /// Tip shape.
    pub tip: TipShape,
    /// Shaft markers (at least two), sorted by distance from the tip.
    pub shaft_markers: Vec<ShaftMarker>,
}

/// Where the object is attached (`[support]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Support {
    /// Unit plane normal, world frame.
    pub plane_normal: Vector3<f64>,
    /// Plane offset, m.
    pub plane_offset_m: f64,
    /// Tolerance, m.
    pub tolerance_m: f64,
}

/// Robot section of `session.toml`.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotConfig {
    /// URDF file.
    pub urdf: PathBuf,
    /// `robot.csv`.
    pub samples: PathBuf,
    /// Link whose origin is the probe tip (z along the shaft toward the tip).
    pub tool_link: String,
    /// Link in which forces/torques are expressed.
    pub ft_link: String,
}

/// A parsed session folder. Lengths are metres.
#[derive(Debug, Clone)]
pub struct Session {
    /// Session folder.
    pub root: PathBuf,
    /// `name`.
    pub name: String,
    /// `kind`.
    pub kind: SessionKind,
    /// Metres per `length_unit`.
    pub metres_per_unit: f64,
    /// Cameras (empty for C3D-only sessions). Path of the cameras file for error messages.
    pub cameras: Vec<Camera>,
    /// Cameras file.
    pub cameras_path: Option<PathBuf>,
    /// Template markers.
    pub markers: Vec<TemplateMarker>,
    /// Image folder.
    pub images: Option<PathBuf>,
    /// Detections folder.
    pub detections: Option<PathBuf>,
    /// C3D take.
    pub c3d: Option<PathBuf>,
    /// `(frame, t_camera_s)` rows of `trigger.csv`, sorted by frame.
    pub trigger: Vec<(usize, f64)>,
    /// FSR configuration.
    pub fsr: Option<FsrConfig>,
    /// FSR samples.
    pub fsr_samples: Option<FsrSamples>,
    /// Probe.
    pub probe: Option<ProbeConfig>,
    /// Robot.
    pub robot: Option<RobotConfig>,
    /// Template surface (OBJ, `length_unit`).
    pub surface: Option<PathBuf>,
    /// Template volume (Gmsh).
    pub volume: Option<PathBuf>,
    /// Gravity, m/s², world.
    pub gravity: Vector3<f64>,
    /// Support plane.
    pub support: Option<Support>,
    /// `[object] density_kg_m3`, if given.
    pub density_kg_m3: Option<f64>,
    /// The depth cameras, clouds, support and interactions of a `dynamic` session.
    pub dynamic: Option<crate::depth::DynamicInputs>,
}

#[derive(Deserialize)]
struct RawSession {
    format: Option<String>,
    name: Option<String>,
    kind: Option<String>,
    length_unit: Option<String>,
    #[serde(default)]
    files: RawFiles,
    world: Option<RawWorld>,
    support: Option<RawSupport>,
    robot: Option<RawRobot>,
    object: Option<RawObject>,
}

#[derive(Deserialize)]
struct RawObject {
    density_kg_m3: Option<f64>,
}

#[derive(Deserialize, Default)]
pub(crate) struct RawFiles {
    cameras: Option<String>,
    markers: Option<String>,
    images: Option<String>,
    detections: Option<String>,
    c3d: Option<String>,
    pub(crate) trigger: Option<String>,
    fsr: Option<String>,
    fsr_samples: Option<String>,
    probe: Option<String>,
    robot: Option<String>,
    robot_samples: Option<String>,
    pub(crate) surface: Option<String>,
    pub(crate) volume: Option<String>,
    pub(crate) depth_cameras: Option<String>,
    pub(crate) depth: Option<String>,
    pub(crate) points: Option<String>,
    pub(crate) support_motion: Option<String>,
    pub(crate) interactions: Option<String>,
}

impl RawFiles {
    /// Every file name given, with its key.
    fn named(&self) -> impl Iterator<Item = (&'static str, &str)> {
        [
            ("files.cameras", &self.cameras),
            ("files.markers", &self.markers),
            ("files.images", &self.images),
            ("files.detections", &self.detections),
            ("files.c3d", &self.c3d),
            ("files.trigger", &self.trigger),
            ("files.fsr", &self.fsr),
            ("files.fsr_samples", &self.fsr_samples),
            ("files.probe", &self.probe),
            ("files.robot", &self.robot),
            ("files.robot_samples", &self.robot_samples),
            ("files.surface", &self.surface),
            ("files.volume", &self.volume),
            ("files.depth_cameras", &self.depth_cameras),
            ("files.depth", &self.depth),
            ("files.points", &self.points),
            ("files.support_motion", &self.support_motion),
            ("files.interactions", &self.interactions),
        ]
        .into_iter()
        .filter_map(|(key, name)| name.as_deref().map(|n| (key, n)))
    }
}

/// A session may only name files inside its folder ([`softcap_app::path_inside`]): the error
/// names the key and session.toml.
fn check_inside(manifest: &Path, dir: &Path, key: &str, name: &str) -> Result<PathBuf> {
    softcap_app::path_inside(dir, name).map_err(|m| CaptureError::field(manifest, 0, key, m))
}

#[derive(Deserialize)]
struct RawWorld {
    gravity: Option<[f64; 3]>,
}

#[derive(Deserialize)]
struct RawSupport {
    plane_normal: Option<[f64; 3]>,
    plane_offset: Option<f64>,
    tolerance: Option<f64>,
    nodes_file: Option<String>,
}

#[derive(Deserialize)]
struct RawRobot {
    tool_link: String,
    ft_link: String,
}

#[derive(Deserialize)]
struct RawCameras {
    camera: Vec<RawCamera>,
}

/// One `[[camera]]` table (shared with the other rig readers).
pub(crate) use softcap_core::CameraTable as RawCamera;

#[derive(Deserialize)]
struct RawProbe {
    tip: String,
    radius: Option<f64>,
    mesh: Option<String>,
    shaft_marker: Vec<RawShaftMarker>,
}

#[derive(Deserialize)]
struct RawShaftMarker {
    id: String,
    distance_from_tip: f64,
    color: String,
}

/// Reads a file into a string, naming it on failure.
pub(crate) fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|source| CaptureError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())]
        .bytes()
        .filter(|&b| b == b'\n')
        .count()
        + 1
}

/// Parses a TOML file into `T`, mapping errors to file + line.
pub(crate) fn parse_toml<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text = read_text(path)?;
    if let Some(bad) = softcap_app::non_finite(&text) {
        return Err(CaptureError::Toml {
            path: path.to_path_buf(),
            line: bad.line,
            message: format!("{} = {}: not a finite number", bad.key, bad.value),
        });
    }
    toml::from_str(&text).map_err(|e| CaptureError::Toml {
        path: path.to_path_buf(),
        line: e.span().map(|s| line_of(&text, s.start)).unwrap_or(0),
        message: e.message().trim().to_string(),
    })
}

/// A CSV table read with a header; fields looked up by column name.
pub(crate) struct CsvTable {
    pub path: PathBuf,
    pub header: Vec<String>,
    /// `(line, fields)` per data row.
    pub rows: Vec<(usize, Vec<String>)>,
}

impl CsvTable {
    pub fn read(path: &Path) -> Result<Self> {
        let text = read_text(path)?;
        Self::parse(path, &text)
    }

    pub fn parse(path: &Path, text: &str) -> Result<Self> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty());
        let (_, header_line) = lines.next().ok_or_else(|| {
            CaptureError::field(path, 1, "header", "file is empty; expected a header row")
        })?;
        let header: Vec<String> = header_line
            .split(',')
            .map(|s| s.trim().to_string())
            .collect();
        let rows = lines
            .map(|(i, l)| {
                (
                    i + 1,
                    l.split(',')
                        .map(|s| s.trim().to_string())
                        .collect::<Vec<_>>(),
                )
            })
            .collect();
        Ok(CsvTable {
            path: path.to_path_buf(),
            header,
            rows,
        })
    }

    pub fn column(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    pub fn require(&self, name: &str) -> Result<usize> {
        self.column(name).ok_or_else(|| {
            CaptureError::field(
                &self.path,
                1,
                name,
                format!(
                    "required column missing (header: {})",
                    self.header.join(",")
                ),
            )
        })
    }

    pub fn str_at<'a>(
        &self,
        row: &'a (usize, Vec<String>),
        col: usize,
        name: &str,
    ) -> Result<&'a str> {
        row.1.get(col).map(|s| s.as_str()).ok_or_else(|| {
            CaptureError::field(
                &self.path,
                row.0,
                name,
                format!("row has {} fields", row.1.len()),
            )
        })
    }

    pub fn f64_at(&self, row: &(usize, Vec<String>), col: usize, name: &str) -> Result<f64> {
        let s = self.str_at(row, col, name)?;
        match s.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(CaptureError::field(
                &self.path,
                row.0,
                name,
                format!("expected a finite number, got `{s}`"),
            )),
        }
    }

    pub fn usize_at(&self, row: &(usize, Vec<String>), col: usize, name: &str) -> Result<usize> {
        let s = self.str_at(row, col, name)?;
        s.parse::<usize>().map_err(|_| {
            CaptureError::field(
                &self.path,
                row.0,
                name,
                format!("expected a non-negative integer, got `{s}`"),
            )
        })
    }

    pub fn color_at(
        &self,
        row: &(usize, Vec<String>),
        col: usize,
        name: &str,
    ) -> Result<MarkerColor> {
        let s = self.str_at(row, col, name)?;
        MarkerColor::parse(s).ok_or_else(|| {
            CaptureError::field(&self.path, row.0, name, format!("unknown colour `{s}`"))
        })
    }
}

/// Reads `template/markers.csv`, converting to metres.
pub fn read_markers_csv(path: &Path, metres_per_unit: f64) -> Result<Vec<TemplateMarker>> {
    let t = CsvTable::read(path)?;
    let (ci, cx, cy, cz, cc) = (
        t.require("id")?,
        t.require("x")?,
        t.require("y")?,
        t.require("z")?,
        t.require("color")?,
    );
    let mut out = Vec::with_capacity(t.rows.len());
    let mut seen = BTreeMap::new();
    for row in &t.rows {
        let id = t.str_at(row, ci, "id")?.to_string();
        if id.is_empty() {
            return Err(CaptureError::field(path, row.0, "id", "empty marker id"));
        }
        if let Some(first) = seen.insert(id.clone(), row.0) {
            return Err(CaptureError::field(
                path,
                row.0,
                "id",
                format!("duplicate marker id `{id}` (first on line {first})"),
            ));
        }
        let p = Point3::new(
            t.f64_at(row, cx, "x")?,
            t.f64_at(row, cy, "y")?,
            t.f64_at(row, cz, "z")?,
        ) * metres_per_unit;
        out.push(TemplateMarker {
            id,
            position_m: p,
            color: t.color_at(row, cc, "color")?,
        });
    }
    if out.is_empty() {
        return Err(CaptureError::field(path, 2, "id", "no markers"));
    }
    Ok(out)
}

/// Reads one `detections/<camera>.csv`.
pub fn read_detections_csv(path: &Path) -> Result<Vec<Detection>> {
    let t = CsvTable::read(path)?;
    let (cf, cu, cv, cc) = (
        t.require("frame")?,
        t.require("u")?,
        t.require("v")?,
        t.require("color")?,
    );
    let cl = t.column("label");
    let mut out = Vec::with_capacity(t.rows.len());
    for row in &t.rows {
        let label = match cl {
            Some(c) => Some(t.str_at(row, c, "label")?.to_string()).filter(|s| !s.is_empty()),
            None => None,
        };
        out.push(Detection {
            frame: t.usize_at(row, cf, "frame")?,
            u: t.f64_at(row, cu, "u")?,
            v: t.f64_at(row, cv, "v")?,
            color: t.color_at(row, cc, "color")?,
            label,
        });
    }
    Ok(out)
}

/// Reads `trigger.csv`: `(frame, t_camera_s)`, checking frames start at 0 and times increase.
pub fn read_trigger_csv(path: &Path) -> Result<Vec<(usize, f64)>> {
    let t = CsvTable::read(path)?;
    let (cf, ct) = (t.require("frame")?, t.require("t_camera_s")?);
    let mut out: Vec<(usize, f64)> = Vec::with_capacity(t.rows.len());
    for row in &t.rows {
        let f = t.usize_at(row, cf, "frame")?;
        let time = t.f64_at(row, ct, "t_camera_s")?;
        if let Some(&(pf, pt)) = out.last()
            && (f <= pf || time <= pt)
        {
            return Err(CaptureError::field(
                path,
                row.0,
                "t_camera_s",
                "frames and times must increase",
            ));
        }
        out.push((f, time));
    }
    if out.is_empty() {
        return Err(CaptureError::field(path, 2, "frame", "no frames"));
    }
    Ok(out)
}

/// Reads `fsr.csv`.
pub fn read_fsr_csv(path: &Path) -> Result<FsrSamples> {
    let t = CsvTable::read(path)?;
    let (ct, cv) = (t.require("t_daq_s")?, t.require("voltage_v")?);
    let ctr = t.column("trigger_v");
    let mut s = FsrSamples {
        trigger_v: ctr.map(|_| Vec::new()),
        ..Default::default()
    };
    for row in &t.rows {
        let time = t.f64_at(row, ct, "t_daq_s")?;
        if let Some(&prev) = s.t_daq_s.last()
            && time <= prev
        {
            return Err(CaptureError::field(
                path,
                row.0,
                "t_daq_s",
                "sample times must increase",
            ));
        }
        s.t_daq_s.push(time);
        s.voltage_v.push(t.f64_at(row, cv, "voltage_v")?);
        if let (Some(c), Some(tr)) = (ctr, s.trigger_v.as_mut()) {
            tr.push(t.f64_at(row, c, "trigger_v")?);
        }
    }
    if s.t_daq_s.len() < 2 {
        return Err(CaptureError::field(
            path,
            2,
            "t_daq_s",
            "need at least two samples",
        ));
    }
    Ok(s)
}

/// The validated camera of a `[[camera]]` table (translation converted to metres); errors name
/// `path` and the id.
pub(crate) fn raw_camera(c: &RawCamera, path: &Path, metres_per_unit: f64) -> Result<Camera> {
    c.to_camera(metres_per_unit)
        .map_err(|e| CaptureError::Camera {
            path: path.to_path_buf(),
            camera: c.id.clone(),
            message: e.to_string(),
        })
}

/// Reads `rig/cameras.toml`, converting translations to metres and validating each camera.
pub fn read_cameras_toml(path: &Path, metres_per_unit: f64) -> Result<Vec<Camera>> {
    let raw: RawCameras = parse_toml(path)?;
    let mut out = Vec::new();
    for c in raw.camera {
        let cam = raw_camera(&c, path, metres_per_unit)?;
        if out.iter().any(|o: &Camera| o.id == c.id) {
            return Err(CaptureError::Camera {
                path: path.to_path_buf(),
                camera: c.id,
                message: "duplicate id".into(),
            });
        }
        out.push(cam);
    }
    if out.is_empty() {
        return Err(CaptureError::field(
            path,
            0,
            "camera",
            "no [[camera]] tables",
        ));
    }
    Ok(out)
}

/// Reads a rig in either format: `rig/cameras.toml` (`[[camera]]` tables) or an aniposelib
/// calibration (`[cam_N]` tables); translations are in units of `metres_per_unit` metres.
pub fn read_rig(path: &Path, metres_per_unit: f64) -> Result<Vec<Camera>> {
    let table: toml::Table = parse_toml(path)?;
    if table.contains_key("camera") {
        read_cameras_toml(path, metres_per_unit)
    } else {
        crate::aniposelib::read_aniposelib_calibration(path, metres_per_unit)
    }
}

/// Reads `rig/fsr.toml`, checking the calibration table increases in both columns.
pub fn read_fsr_toml(path: &Path) -> Result<FsrConfig> {
    let cfg: FsrConfig = parse_toml(path)?;
    if cfg.calibration.len() < 2 {
        return Err(CaptureError::field(
            path,
            0,
            "calibration",
            "need at least two [force_n, voltage_v] points",
        ));
    }
    for w in cfg.calibration.windows(2) {
        if w[1][0] <= w[0][0] || w[1][1] <= w[0][1] {
            return Err(CaptureError::field(
                path,
                0,
                "calibration",
                "must increase in both force and voltage",
            ));
        }
    }
    if !(cfg.supply_v > 0.0 && cfg.divider_ohm > 0.0) {
        return Err(CaptureError::field(
            path,
            0,
            "supply_v",
            "supply_v and divider_ohm must be positive",
        ));
    }
    Ok(cfg)
}

/// Reads `rig/probe.toml`.
pub fn read_probe_toml(path: &Path, root: &Path, metres_per_unit: f64) -> Result<ProbeConfig> {
    let raw: RawProbe = parse_toml(path)?;
    let tip = match raw.tip.as_str() {
        "disk" | "sphere" => {
            let r = raw.radius.ok_or_else(|| {
                CaptureError::field(path, 0, "radius", "required for disk and sphere tips")
            })?;
            if r.is_nan() || r <= 0.0 {
                return Err(CaptureError::field(path, 0, "radius", "must be positive"));
            }
            if raw.tip == "disk" {
                TipShape::Disk {
                    radius_m: r * metres_per_unit,
                }
            } else {
                TipShape::Sphere {
                    radius_m: r * metres_per_unit,
                }
            }
        }
        "mesh" => TipShape::Mesh {
            path: check_inside(
                path,
                root,
                "mesh",
                &raw.mesh.ok_or_else(|| {
                    CaptureError::field(path, 0, "mesh", "required for mesh tips")
                })?,
            )?,
        },
        other => {
            return Err(CaptureError::field(
                path,
                0,
                "tip",
                format!("unknown tip `{other}`"),
            ));
        }
    };
    let mut shaft_markers = Vec::new();
    for m in raw.shaft_marker {
        let color = MarkerColor::parse(&m.color).ok_or_else(|| {
            CaptureError::field(
                path,
                0,
                "shaft_marker.color",
                format!("unknown colour `{}`", m.color),
            )
        })?;
        shaft_markers.push(ShaftMarker {
            id: m.id,
            distance_from_tip_m: m.distance_from_tip * metres_per_unit,
            color,
        });
    }
    if shaft_markers.len() < 2 {
        return Err(CaptureError::field(
            path,
            0,
            "shaft_marker",
            "need at least two shaft markers",
        ));
    }
    shaft_markers.sort_by(|a, b| a.distance_from_tip_m.total_cmp(&b.distance_from_tip_m));
    if shaft_markers[1].distance_from_tip_m - shaft_markers[0].distance_from_tip_m <= 0.0 {
        return Err(CaptureError::field(
            path,
            0,
            "shaft_marker.distance_from_tip",
            "shaft markers must be at distinct distances",
        ));
    }
    Ok(ProbeConfig { tip, shaft_markers })
}

impl Session {
    /// Reads `DIR/session.toml` and every file it names (except images and detections, which are
    /// read per camera when needed).
    pub fn load(dir: &Path) -> Result<Session> {
        let manifest = dir.join("session.toml");
        let raw: RawSession = parse_toml(&manifest)?;
        for (key, name) in raw.files.named() {
            check_inside(&manifest, dir, key, name)?;
        }
        if let Some(name) = raw.support.as_ref().and_then(|s| s.nodes_file.as_deref()) {
            check_inside(&manifest, dir, "support.nodes_file", name)?;
        }
        let req = |v: Option<String>, field: &str| {
            v.ok_or_else(|| CaptureError::field(&manifest, 0, field, "required"))
        };
        let format = req(raw.format, "format")?;
        if format != "softcap-session/1" {
            return Err(CaptureError::field(
                &manifest,
                0,
                "format",
                format!("expected `softcap-session/1`, got `{format}`"),
            ));
        }
        let name = req(raw.name, "name")?;
        let kind = match req(raw.kind, "kind")?.as_str() {
            "probe" => SessionKind::Probe,
            "probe-robot" => SessionKind::ProbeRobot,
            "mocap" => SessionKind::Mocap,
            "dynamic" => SessionKind::Dynamic,
            other => {
                return Err(CaptureError::field(
                    &manifest,
                    0,
                    "kind",
                    format!("unknown kind `{other}`"),
                ));
            }
        };
        let metres_per_unit = match req(raw.length_unit, "length_unit")?.as_str() {
            "mm" => 1e-3,
            "m" => 1.0,
            other => {
                return Err(CaptureError::field(
                    &manifest,
                    0,
                    "length_unit",
                    format!("expected mm or m, got `{other}`"),
                ));
            }
        };
        let gravity = raw
            .world
            .and_then(|w| w.gravity)
            .map(Vector3::from)
            .unwrap_or(Vector3::new(0.0, 0.0, -9.81));
        let density_kg_m3 = raw.object.and_then(|o| o.density_kg_m3);
        if let Some(d) = density_kg_m3
            && !(d > 0.0 && d.is_finite())
        {
            return Err(CaptureError::field(
                &manifest,
                0,
                "object.density_kg_m3",
                "must be a positive number",
            ));
        }
        let (support, support_nodes_file) = match raw.support {
            Some(s) => parse_support(&manifest, s, metres_per_unit)?,
            None => (None, None),
        };
        if kind == SessionKind::Dynamic {
            let support_nodes_file = support_nodes_file.map(|p| dir.join(p));
            return crate::depth::load_dynamic(
                crate::depth::DynamicManifest {
                    dir,
                    manifest: &manifest,
                    name,
                    metres_per_unit,
                    gravity,
                    density_kg_m3,
                    support,
                    support_nodes_file,
                },
                raw.files,
            );
        }
        if support_nodes_file.is_some() {
            return Err(CaptureError::field(
                &manifest,
                0,
                "support.nodes_file",
                "only dynamic sessions take a node list",
            ));
        }
        let f = raw.files;
        let path = |p: &Option<String>| p.as_ref().map(|p| dir.join(p));
        let existing = |p: Option<PathBuf>, field: &str| -> Result<Option<PathBuf>> {
            match p {
                Some(p) if !p.exists() => Err(CaptureError::Io {
                    path: p,
                    source: std::io::Error::new(
                        std::io::ErrorKind::NotFound,
                        format!("named by session.toml files.{field}"),
                    ),
                }),
                p => Ok(p),
            }
        };
        let images = existing(path(&f.images), "images")?;
        let detections = existing(path(&f.detections), "detections")?;
        let c3d = existing(path(&f.c3d), "c3d")?;
        if images.is_none() && detections.is_none() && c3d.is_none() {
            return Err(CaptureError::field(
                &manifest,
                0,
                "files.images",
                "one of images / detections / c3d is required",
            ));
        }
        let markers_path = path(&f.markers)
            .ok_or_else(|| CaptureError::field(&manifest, 0, "files.markers", "required"))?;
        let markers = read_markers_csv(&markers_path, metres_per_unit)?;
        let cameras_path = path(&f.cameras);
        let cameras = match &cameras_path {
            Some(p) => read_cameras_toml(p, metres_per_unit)?,
            None if c3d.is_some() => Vec::new(),
            None => {
                return Err(CaptureError::field(
                    &manifest,
                    0,
                    "files.cameras",
                    "required unless c3d is given",
                ));
            }
        };
        let trigger = match path(&f.trigger) {
            Some(p) => read_trigger_csv(&p)?,
            None if images.is_some() || detections.is_some() => {
                return Err(CaptureError::field(
                    &manifest,
                    0,
                    "files.trigger",
                    "required with images or detections",
                ));
            }
            None => Vec::new(),
        };
        let (fsr, fsr_samples) = if kind == SessionKind::Probe {
            let p = path(&f.fsr).ok_or_else(|| {
                CaptureError::field(&manifest, 0, "files.fsr", "required for kind probe")
            })?;
            let s = path(&f.fsr_samples).ok_or_else(|| {
                CaptureError::field(&manifest, 0, "files.fsr_samples", "required for kind probe")
            })?;
            (Some(read_fsr_toml(&p)?), Some(read_fsr_csv(&s)?))
        } else {
            (None, None)
        };
        let probe = match (kind, path(&f.probe)) {
            (SessionKind::Mocap, _) => None,
            (_, Some(p)) => Some(read_probe_toml(&p, dir, metres_per_unit)?),
            (_, None) => {
                return Err(CaptureError::field(
                    &manifest,
                    0,
                    "files.probe",
                    "required for probe sessions",
                ));
            }
        };
        let robot = if kind == SessionKind::ProbeRobot {
            let r = raw.robot.ok_or_else(|| {
                CaptureError::field(&manifest, 0, "robot", "[robot] required for probe-robot")
            })?;
            Some(RobotConfig {
                urdf: existing(path(&f.robot), "robot")?
                    .ok_or_else(|| CaptureError::field(&manifest, 0, "files.robot", "required"))?,
                samples: existing(path(&f.robot_samples), "robot_samples")?.ok_or_else(|| {
                    CaptureError::field(&manifest, 0, "files.robot_samples", "required")
                })?,
                tool_link: r.tool_link,
                ft_link: r.ft_link,
            })
        } else {
            None
        };
        if raw_support_lacks_plane(&support) {
            return Err(CaptureError::field(
                &manifest,
                0,
                "support.plane_normal",
                "required ([support] needs plane_normal, plane_offset and tolerance)",
            ));
        }
        Ok(Session {
            root: dir.to_path_buf(),
            name,
            kind,
            metres_per_unit,
            cameras,
            cameras_path,
            markers,
            images,
            detections,
            c3d,
            trigger,
            fsr,
            fsr_samples,
            probe,
            robot,
            surface: existing(path(&f.surface), "surface")?,
            volume: existing(path(&f.volume), "volume")?,
            gravity,
            support: support.flatten(),
            density_kg_m3,
            dynamic: None,
        })
    }

    /// Replaces the session's rig by the one in `path` ([`read_rig`], the session's length unit),
    /// e.g. one refined by `softcap capture calibrate`. Every camera of the session must be in it
    /// (matched by id; the session's camera order is kept).
    pub fn use_cameras(&mut self, path: &Path) -> Result<()> {
        let rig = read_rig(path, self.metres_per_unit)?;
        if self.cameras.is_empty() {
            self.cameras = rig;
        } else {
            self.cameras =
                self.cameras
                    .iter()
                    .map(|c| {
                        rig.iter().find(|r| r.id == c.id).cloned().ok_or_else(|| {
                            CaptureError::Camera {
                                path: path.to_path_buf(),
                                camera: c.id.clone(),
                                message: "the session's camera is not in this rig".into(),
                            }
                        })
                    })
                    .collect::<Result<_>>()?;
        }
        self.cameras_path = Some(path.to_path_buf());
        Ok(())
    }

    /// Reads `detections/<camera>.csv` for every camera, in camera order.
    pub fn read_detections(&self) -> Result<Vec<Vec<Detection>>> {
        let dir = self.detections.as_ref().ok_or_else(|| {
            CaptureError::field(
                &self.root.join("session.toml"),
                0,
                "files.detections",
                "session has no detections",
            )
        })?;
        self.cameras
            .iter()
            .map(|c| read_detections_csv(&dir.join(format!("{}.csv", c.id))))
            .collect()
    }
}

/// `[support]`: `Some(Some(plane))` for a plane, `Some(None)` for a table without one, and the
/// node-list file of a dynamic session.
type ParsedSupport = (Option<Option<Support>>, Option<String>);

fn parse_support(manifest: &Path, s: RawSupport, metres_per_unit: f64) -> Result<ParsedSupport> {
    let plane = match (s.plane_normal, s.plane_offset, s.tolerance) {
        (Some(normal), Some(offset), Some(tolerance)) => {
            let n = Vector3::from(normal);
            let norm = n.norm();
            if !(norm > 0.0 && norm.is_finite()) {
                return Err(CaptureError::field(
                    manifest,
                    0,
                    "support.plane_normal",
                    "must be a non-zero vector",
                ));
            }
            Some(Support {
                plane_normal: n / norm,
                plane_offset_m: offset * metres_per_unit,
                tolerance_m: tolerance * metres_per_unit,
            })
        }
        (None, None, None) => None,
        _ => {
            return Err(CaptureError::field(
                manifest,
                0,
                "support.plane_normal",
                "a support plane needs plane_normal, plane_offset and tolerance",
            ));
        }
    };
    Ok((Some(plane), s.nodes_file))
}

/// True for a `[support]` table that gives no plane (only dynamic sessions may give a node list
/// instead).
fn raw_support_lacks_plane(support: &Option<Option<Support>>) -> bool {
    matches!(support, Some(None))
}

/// Reads a `CaptureSettings` TOML file.
pub fn parse_settings_toml(path: &Path) -> Result<crate::pipeline::CaptureSettings> {
    parse_toml(path)
}
