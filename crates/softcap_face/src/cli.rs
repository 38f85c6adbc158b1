//! The `softcap-face` command line.
//!
//! - `softcap-face landmarks --mocap TAKE.csv --face NEUTRAL.obj -o TABLE.csv`
//! - `softcap-face run --mocap TAKE.csv --face NEUTRAL.obj --landmarks TABLE.csv [--frames 0,150]
//!   [--stride N] [--wrinkles WRINKLES.json] -o face.mcap` (the stage output, `docs/formats.md`)
//! - `softcap-face animate --mocap TAKE.csv --face NEUTRAL.obj --landmarks TABLE.csv --frames 0,120,390 --out DIR`
//! - `softcap-face track TAKE/ --face NEUTRAL.obj --landmarks TABLE.csv -o wrinkles.mcap [--report DIR]`
//! - `softcap-face remove --face SCAN.obj (--region REGION.csv | --landmarks TABLE.csv --around MARKER
//!   --radius R) [--frames face.mcap] -o clean.mcap [--obj clean.obj]`
//! - `softcap-face synth-take --mocap TAKE.csv --face NEUTRAL.obj --landmarks TABLE.csv -o TAKE/ [--frames 60]
//!   [--motion steady|varying] [--seed 7]`

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};
use softcap_app::{Context, Error, IntoError, Progress, Result};
use softcap_mesh::nalgebra::Vector3;
use softcap_mesh::shell::ShellSettings;

use crate::take::read_take;
use crate::take_synth::{TakeMotion, TakeSynthSettings, face_from_mocap, synth_take};
use crate::take_track::{track_take, write_track_mcap};
use crate::video::VideoTrackSettings;
use crate::{
    FaceAnimator, FaceFrame, MocapTake, OrthoView, RemovalSettings, SynthesisSettings,
    WrinkleInput, derive_landmarks, landmarks_csv, parse_landmarks_csv, read_animface_csv,
    remove_wrinkles, render_mesh, synthesize_wrinkles, write_face_mcap,
};

#[derive(Parser, Debug)]
#[command(
    name = "softcap-face",
    version,
    about = "face stage: mocap → face correspondence, linear shell animation, wrinkles"
)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Derive the marker → scan-vertex landmark table (ICP + closest vertex).
    Landmarks {
        #[arg(long)]
        mocap: PathBuf,
        #[arg(long)]
        face: PathBuf,
        /// Marker on the nose tip.
        #[arg(long, default_value = "NoseHead")]
        nose: String,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Animate the scan with a mocap take (and synthesize tracked wrinkles) into face.mcap.
    Run {
        #[arg(long)]
        mocap: PathBuf,
        #[arg(long)]
        face: PathBuf,
        #[arg(long)]
        landmarks: PathBuf,
        /// Source frame numbers (default: every `stride`-th frame of the take).
        #[arg(long, value_delimiter = ',')]
        frames: Vec<u64>,
        #[arg(long, default_value_t = 1)]
        stride: usize,
        /// Tracked wrinkles: `wrinkles.mcap` of `face track`, or a JSON
        /// `softcap_face::WrinkleInput` (camera + curves).
        #[arg(long)]
        wrinkles: Option<PathBuf>,
        /// Length of one scan unit in metres (ICT face: cm).
        #[arg(long, default_value_t = 0.01)]
        metres_per_unit: f64,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Animate the scan with a mocap take and render frames to PNG.
    Animate {
        #[arg(long)]
        mocap: PathBuf,
        #[arg(long)]
        face: PathBuf,
        #[arg(long)]
        landmarks: PathBuf,
        /// Source frame numbers to render.
        #[arg(long, value_delimiter = ',')]
        frames: Vec<u64>,
        #[arg(long)]
        out: PathBuf,
        #[arg(long, default_value_t = 480)]
        width_px: usize,
    },
    /// Track the painted wrinkles of a face take (thesis §4.3) onto the animated face.
    Track {
        /// The take directory (cameras.toml, mocap.csv, frames/CAMERA/FRAME.png, labels/).
        take: PathBuf,
        #[arg(long)]
        face: PathBuf,
        #[arg(long)]
        landmarks: PathBuf,
        /// Length of one scan unit in metres (ICT face: cm).
        #[arg(long, default_value_t = 0.01)]
        metres_per_unit: f64,
        /// Tracker settings (JSON, `softcap_face::video::VideoTrackSettings`; defaults otherwise).
        #[arg(long)]
        settings: Option<PathBuf>,
        /// Write figures (tracked splines over the frames, (d, w) over time) into this directory.
        #[arg(long)]
        report: Option<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Remove medium-scale wrinkles from a region of a scan (thesis §3.3.2), and of every frame
    /// of a face.mcap when given.
    Remove {
        #[arg(long)]
        face: PathBuf,
        /// The region: a CSV with a `vertex` column (scan vertex indices).
        #[arg(long, conflicts_with_all = ["around", "radius"])]
        region: Option<PathBuf>,
        /// … or the vertices within `--radius` (scan units) of this marker's landmark vertex.
        #[arg(long, requires_all = ["radius", "landmarks"])]
        around: Option<String>,
        #[arg(long)]
        radius: Option<f64>,
        #[arg(long)]
        landmarks: Option<PathBuf>,
        /// A face.mcap whose `/face/mesh` frames (same topology as the scan) are cleaned too.
        #[arg(long)]
        frames: Option<PathBuf>,
        /// Length of one scan unit in metres (ICT face: cm).
        #[arg(long, default_value_t = 0.01)]
        metres_per_unit: f64,
        /// Also write the cleaned scan as OBJ.
        #[arg(long)]
        obj: Option<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Render a face take with known wrinkles (test data of `track`; docs/face.md).
    SynthTake {
        #[arg(long)]
        mocap: PathBuf,
        #[arg(long)]
        face: PathBuf,
        #[arg(long)]
        landmarks: PathBuf,
        /// Frames (the first N of the mocap take).
        #[arg(long, default_value_t = 60)]
        frames: usize,
        /// Stratified rays per pixel = N².
        #[arg(long, default_value_t = 12)]
        rays_per_axis: usize,
        /// How the wrinkles' depth and width change over the take (docs/face.md).
        #[arg(long, value_enum, default_value_t = TakeMotion::Steady)]
        motion: TakeMotion,
        /// Seed of the render's ray and noise streams.
        #[arg(long, default_value_t = 7)]
        seed: u64,
        #[arg(short, long)]
        output: PathBuf,
    },
}

fn bad(msg: String) -> Error {
    Error::bad_input(msg)
}

fn read_face(path: &Path) -> Result<softcap_mesh::TriMesh> {
    Ok(softcap_mesh::read_obj(path)?.to_tri_mesh())
}

fn read_landmarks(path: &Path) -> Result<Vec<crate::Landmark>> {
    let text = std::fs::read_to_string(path).context(path.display().to_string())?;
    Ok(parse_landmarks_csv(&text, path)?)
}

/// The animator of a take, face and landmark table.
fn animator(mocap: &Path, face: &Path, landmarks: &Path) -> Result<(MocapTake, FaceAnimator)> {
    let take = read_animface_csv(mocap)?;
    let animator = animator_of(&take, mocap, face, landmarks)?;
    Ok((take, animator))
}

/// The animator of an already read take.
fn animator_of(
    take: &MocapTake,
    mocap: &Path,
    face: &Path,
    landmarks: &Path,
) -> Result<FaceAnimator> {
    let mesh = read_face(face)?;
    let table = read_landmarks(landmarks)?;
    let mut handles = Vec::new();
    for name in &take.names {
        let Some(row) = table.iter().find(|r| &r.marker == name) else {
            return Err(bad(format!(
                "{}: no landmark for marker `{name}`",
                landmarks.display()
            )));
        };
        handles.push(row.vertex);
    }
    let animator = FaceAnimator::new(
        mesh,
        handles,
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .with_context(|| {
        format!(
            "rigging {} with {} and {}",
            face.display(),
            landmarks.display(),
            mocap.display()
        )
    })?;
    Ok(animator)
}

/// The `--wrinkles` input of `run`: a `wrinkles.mcap` of `face track` (one input per camera) or
/// a JSON [`WrinkleInput`].
fn read_wrinkle_inputs(path: &Path, metres_per_unit: f64) -> Result<Vec<WrinkleInput>> {
    if path.extension().and_then(|e| e.to_str()) == Some("mcap") {
        return Ok(crate::take_track::read_track_mcap(path, metres_per_unit)?);
    }
    let text = std::fs::read_to_string(path).context(path.display().to_string())?;
    let w: WrinkleInput =
        serde_json::from_str(&text).bad_input_with(|| path.display().to_string())?;
    w.validate()
        .map_err(|e| bad(format!("{}: {e}", path.display())))?;
    Ok(vec![w])
}

impl Command {
    /// Runs the subcommand.
    pub fn run(&self) -> Result<()> {
        match self {
            Command::Landmarks {
                mocap,
                face,
                nose,
                output,
            } => {
                let take = read_animface_csv(mocap)?;
                let mesh = read_face(face)?;
                let Some(n) = take.marker_index(nose) else {
                    return Err(bad(format!("{}: no marker `{nose}`", mocap.display())));
                };
                let rows =
                    derive_landmarks(&take.names, &take.positions_cm[0], &mesh.vertices, n, 30)?;
                softcap_app::write_atomic(output, landmarks_csv(&rows).as_bytes())
                    .with_context(|| format!("writing {}", output.display()))
            }
            Command::Run {
                mocap,
                face,
                landmarks,
                frames,
                stride,
                wrinkles,
                metres_per_unit,
                output,
            } => {
                if *stride == 0 {
                    return Err(bad("--stride must be ≥ 1".into()));
                }
                if !(*metres_per_unit > 0.0 && metres_per_unit.is_finite()) {
                    return Err(bad("--metres-per-unit must be positive".into()));
                }
                let inputs = match wrinkles {
                    Some(p) => read_wrinkle_inputs(p, *metres_per_unit)?,
                    None => Vec::new(),
                };
                let (take, animator) = animator(mocap, face, landmarks)?;
                let indices: Vec<usize> = if frames.is_empty() {
                    (0..take.frames.len()).step_by(*stride).collect()
                } else {
                    let mut v = Vec::new();
                    for f in frames {
                        let Some(t) = take.frames.iter().position(|x| x == f) else {
                            return Err(bad(format!("{}: no frame {f}", mocap.display())));
                        };
                        v.push(t);
                    }
                    v
                };
                for fw in inputs.iter().flat_map(|i| &i.frames) {
                    if !take.frames.contains(&fw.frame) {
                        let p = wrinkles.as_ref().map(|p| p.display().to_string());
                        return Err(bad(format!(
                            "{}: frame {} is not in {}",
                            p.unwrap_or_default(),
                            fw.frame,
                            mocap.display()
                        )));
                    }
                }
                let t0 = take.times_s.first().copied().unwrap_or(0.0);
                let mut out = Vec::with_capacity(indices.len());
                let bar = Progress::default().bar("animating frames", indices.len() as u64);
                for t in indices {
                    bar.inc(1);
                    let mut vertices = animator.frame(&take.positions_cm[t])?;
                    let mut wr = Vec::new();
                    for input in &inputs {
                        let (Some(cam), Some(fw)) = (
                            &input.camera,
                            input.frames.iter().find(|f| f.frame == take.frames[t]),
                        ) else {
                            continue;
                        };
                        if fw.wrinkles.is_empty() {
                            continue;
                        }
                        let res = synthesize_wrinkles(
                            &animator.mesh,
                            &vertices,
                            cam,
                            &fw.wrinkles,
                            &SynthesisSettings::default(),
                        )?;
                        vertices = res.vertices;
                        wr.extend(
                            fw.wrinkles
                                .iter()
                                .cloned()
                                .zip(res.projected.into_iter().map(Some)),
                        );
                    }
                    out.push(FaceFrame {
                        frame: take.frames[t],
                        t_s: take.times_s[t] - t0,
                        vertices,
                        wrinkles: wr,
                    });
                }
                bar.finish_and_clear();
                let mut provenance =
                    softcap_mcap::Provenance::new("face", env!("CARGO_PKG_VERSION"))
                        .with_arguments(std::env::args());
                for p in [Some(mocap), Some(face), Some(landmarks), wrinkles.as_ref()]
                    .into_iter()
                    .flatten()
                {
                    provenance.add_input(p)?;
                }
                write_face_mcap(output, &provenance, &animator.mesh, &out, *metres_per_unit)?;
                Ok(())
            }
            Command::Animate {
                mocap,
                face,
                landmarks,
                frames,
                out,
                width_px,
            } => {
                let (take, animator) = animator(mocap, face, landmarks)?;
                std::fs::create_dir_all(out)
                    .with_context(|| format!("creating {}", out.display()))?;
                let (view, h) = OrthoView::fit(&animator.mesh.vertices, *width_px);
                let bar = Progress::default().bar("rendering frames", frames.len() as u64);
                for f in frames {
                    bar.inc(1);
                    let Some(t) = take.frames.iter().position(|x| x == f) else {
                        return Err(bad(format!("{}: no frame {f}", mocap.display())));
                    };
                    let verts = animator.frame(&take.positions_cm[t])?;
                    let img = render_mesh(
                        &verts,
                        &animator.mesh.triangles,
                        &view,
                        *width_px,
                        h,
                        Vector3::new(0.3, 0.4, 1.0),
                        [0.85, 0.68, 0.6],
                    );
                    img.write_png(&out.join(format!("jaw_frame_{f:04}.png")))?;
                }
                Ok(())
            }
            Command::Track {
                take,
                face,
                landmarks,
                metres_per_unit,
                settings,
                report,
                output,
            } => track(
                take,
                face,
                landmarks,
                *metres_per_unit,
                settings.as_deref(),
                report.as_deref(),
                output,
            ),
            Command::Remove {
                face,
                region,
                around,
                radius,
                landmarks,
                frames,
                metres_per_unit,
                obj,
                output,
            } => {
                let around = match (around, radius, landmarks) {
                    (Some(m), Some(r), Some(l)) => Some((m.as_str(), *r, l.as_path())),
                    _ => None,
                };
                remove(
                    face,
                    region.as_deref(),
                    around,
                    frames.as_deref(),
                    *metres_per_unit,
                    obj.as_deref(),
                    output,
                )
            }
            Command::SynthTake {
                mocap,
                face,
                landmarks,
                frames,
                rays_per_axis,
                motion,
                seed,
                output,
            } => {
                let take = read_animface_csv(mocap)?;
                let mesh = read_face(face)?;
                let table = read_landmarks(landmarks)?;
                let mut s = TakeSynthSettings {
                    frames: *frames,
                    motion: *motion,
                    ..Default::default()
                };
                s.render.rays_per_axis = *rays_per_axis;
                s.render.seed = *seed;
                let bar = Progress::default().bar("rendering take frames", *frames as u64);
                synth_take(&mesh, &take, &table, output, &s, &|| bar.inc(1))?;
                bar.finish_and_clear();
                Ok(())
            }
        }
    }
}

/// `softcap face track`.
fn track(
    take_dir: &Path,
    face: &Path,
    landmarks: &Path,
    metres_per_unit: f64,
    settings: Option<&Path>,
    report: Option<&Path>,
    output: &Path,
) -> Result<()> {
    if !(metres_per_unit > 0.0 && metres_per_unit.is_finite()) {
        return Err(bad("--metres-per-unit must be positive".into()));
    }
    let settings: VideoTrackSettings = match settings {
        Some(p) => {
            let text = std::fs::read_to_string(p).context(p.display().to_string())?;
            serde_json::from_str(&text).bad_input_with(|| p.display().to_string())?
        }
        None => VideoTrackSettings::default(),
    };
    let take = read_take(take_dir)?;
    let animator = animator_of(&take.mocap, &take.mocap_path, face, landmarks)?;
    let table = read_landmarks(landmarks)?;
    let face_from_mocap = face_from_mocap(&take.mocap, &table, &animator.mesh)
        .with_context(|| format!("{} on {}", landmarks.display(), face.display()))?;
    let total = (take.n_frames() * take.cameras.len()) as u64;
    let bar = Progress::default().bar("tracking wrinkles (camera frames)", total);
    let tracks = track_take(&take, &animator, &face_from_mocap, &settings, &|| {
        bar.inc(1)
    })?;
    bar.finish_and_clear();
    let progress = Progress::default();
    for c in &tracks {
        for (t, row) in c.frames.iter().enumerate() {
            let states: Vec<String> = row
                .iter()
                .map(|w| format!("wrinkle {} {}", w.id, w.status.name()))
                .collect();
            progress.step(
                t + 1,
                c.frames.len(),
                &format!("{}: {}", c.id, states.join(", ")),
            );
        }
    }
    let mut provenance = softcap_mcap::Provenance::new("face", env!("CARGO_PKG_VERSION"))
        .with_arguments(std::env::args());
    provenance.add_input(take.dir.join("cameras.toml"))?;
    provenance.add_input(&take.mocap_path)?;
    for p in [face, landmarks] {
        provenance.add_input(p)?;
    }
    if let Some(dir) = report {
        crate::take_report::write_report(dir, &take, &tracks)?;
    }
    write_track_mcap(output, &provenance, &take, &tracks, metres_per_unit)?;
    Ok(())
}

/// The region of `remove`: a vertex CSV, or the vertices near a landmark.
fn removal_region(
    mesh: &softcap_mesh::TriMesh,
    region: Option<&Path>,
    around: Option<(&str, f64, &Path)>,
) -> Result<Vec<usize>> {
    if let Some(p) = region {
        let text = std::fs::read_to_string(p).context(p.display().to_string())?;
        let mut out = Vec::new();
        let mut lines = text.lines().enumerate();
        match lines.next() {
            Some((_, h)) if h.trim() == "vertex" => {}
            _ => {
                return Err(bad(format!(
                    "{}:1: expected the header `vertex`",
                    p.display()
                )));
            }
        }
        for (i, line) in lines {
            if line.trim().is_empty() {
                continue;
            }
            let v: usize = line.trim().parse().map_err(|_| {
                bad(format!(
                    "{}:{}: field `vertex`: `{line}` is not a vertex index",
                    p.display(),
                    i + 1
                ))
            })?;
            if v >= mesh.vertices.len() {
                return Err(bad(format!(
                    "{}:{}: field `vertex`: {v} ≥ {} vertices",
                    p.display(),
                    i + 1,
                    mesh.vertices.len()
                )));
            }
            out.push(v);
        }
        return Ok(out);
    }
    let Some((marker, radius, landmarks)) = around else {
        return Err(bad(
            "give --region FILE or --around MARKER --radius R --landmarks TABLE".into(),
        ));
    };
    if !(radius > 0.0 && radius.is_finite()) {
        return Err(bad("--radius must be positive".into()));
    }
    let table = read_landmarks(landmarks)?;
    let Some(row) = table.iter().find(|r| r.marker == marker) else {
        return Err(bad(format!(
            "{}: no marker `{marker}`",
            landmarks.display()
        )));
    };
    let Some(c) = mesh.vertices.get(row.vertex) else {
        return Err(bad(format!(
            "{}: vertex {} of `{marker}` is not in the scan",
            landmarks.display(),
            row.vertex
        )));
    };
    Ok((0..mesh.vertices.len())
        .filter(|&v| (mesh.vertices[v] - c).norm() <= radius)
        .collect())
}

/// `softcap face remove`.
#[allow(clippy::too_many_arguments)]
fn remove(
    face: &Path,
    region: Option<&Path>,
    around: Option<(&str, f64, &Path)>,
    frames: Option<&Path>,
    metres_per_unit: f64,
    obj: Option<&Path>,
    output: &Path,
) -> Result<()> {
    if !(metres_per_unit > 0.0 && metres_per_unit.is_finite()) {
        return Err(bad("--metres-per-unit must be positive".into()));
    }
    let scan = read_face(face)?;
    let region = removal_region(&scan, region, around)?;
    if region.is_empty() {
        return Err(bad("the wrinkle region is empty".into()));
    }
    let settings = RemovalSettings::default();
    let clean = softcap_mesh::TriMesh {
        vertices: remove_wrinkles(&scan, &region, &settings)?,
        triangles: scan.triangles.clone(),
    };
    let mut out = Vec::new();
    if let Some(p) = frames {
        let rec = softcap_mcap::reader::Recording::open(p)
            .map_err(|e| bad(format!("{}: {e}", p.display())))?;
        let meshes = rec
            .read(&softcap_mcap::topics::FACE_MESH)
            .map_err(|e| bad(format!("{}: {e}", p.display())))?;
        let bar = Progress::default().bar("removing wrinkles (frames)", meshes.len() as u64);
        for (k, (t_ns, m)) in meshes.iter().enumerate() {
            bar.inc(1);
            if m.positions_m.len() != 3 * scan.vertices.len() {
                return Err(bad(format!(
                    "{}: /face/mesh message {k} has {} vertices, {} has {}",
                    p.display(),
                    m.positions_m.len() / 3,
                    face.display(),
                    scan.vertices.len()
                )));
            }
            let mesh = softcap_mesh::TriMesh {
                vertices: m
                    .positions_m
                    .chunks(3)
                    .map(|c| Vector3::new(c[0], c[1], c[2]) / metres_per_unit)
                    .collect(),
                triangles: scan.triangles.clone(),
            };
            out.push(FaceFrame {
                frame: k as u64,
                t_s: *t_ns as f64 * 1e-9,
                vertices: remove_wrinkles(&mesh, &region, &settings)?,
                wrinkles: Vec::new(),
            });
        }
        bar.finish_and_clear();
    }
    let mut provenance = softcap_mcap::Provenance::new("face", env!("CARGO_PKG_VERSION"))
        .with_arguments(std::env::args());
    for p in [Some(face), frames].into_iter().flatten() {
        provenance.add_input(p)?;
    }
    if let Some(o) = obj {
        let m = softcap_mesh::ObjMesh {
            vertices: clean.vertices.clone(),
            polygons: clean.triangles.iter().map(|t| t.to_vec()).collect(),
            ..Default::default()
        };
        softcap_mesh::write_obj(o, &m).with_context(|| format!("writing {}", o.display()))?;
    }
    write_face_mcap(output, &provenance, &clean, &out, metres_per_unit)?;
    Ok(())
}

impl Cli {
    /// Runs the subcommand.
    pub fn run(self) -> Result<()> {
        self.command.run()
    }
}
