//! The `softcap-face` command line.
//!
//! - `softcap-face landmarks --mocap TAKE.csv --face NEUTRAL.obj -o TABLE.csv`
//! - `softcap-face run --mocap TAKE.csv --face NEUTRAL.obj --landmarks TABLE.csv [--frames 0,150]
//!   [--stride N] [--wrinkles WRINKLES.json] -o face.mcap` (the stage output, `docs/formats.md`)
//! - `softcap-face animate --mocap TAKE.csv --face NEUTRAL.obj --landmarks TABLE.csv --frames 0,120,390 --out DIR`

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};
use softcap_app::{Context, Error, IntoError, Progress, Result};
use softcap_mesh::nalgebra::Vector3;
use softcap_mesh::shell::ShellSettings;

use crate::{
    FaceAnimator, FaceFrame, MocapTake, OrthoView, SynthesisSettings, WrinkleInput,
    derive_landmarks, landmarks_csv, parse_landmarks_csv, read_animface_csv, render_mesh,
    synthesize_wrinkles, write_face_mcap,
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
        /// Tracked wrinkles and camera (JSON, `softcap_face::WrinkleInput`).
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
}

fn bad(msg: String) -> Error {
    Error::bad_input(msg)
}

fn read_face(path: &Path) -> Result<softcap_mesh::TriMesh> {
    Ok(softcap_mesh::read_obj(path)?.to_tri_mesh())
}

/// The animator of a take, face and landmark table.
fn animator(mocap: &Path, face: &Path, landmarks: &Path) -> Result<(MocapTake, FaceAnimator)> {
    let take = read_animface_csv(mocap)?;
    let mesh = read_face(face)?;
    let text = std::fs::read_to_string(landmarks).context(landmarks.display().to_string())?;
    let table = parse_landmarks_csv(&text, landmarks)?;
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
    Ok((take, animator))
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
                let input = match wrinkles {
                    Some(p) => {
                        let text = std::fs::read_to_string(p).context(p.display().to_string())?;
                        let w: WrinkleInput = serde_json::from_str(&text)
                            .bad_input_with(|| p.display().to_string())?;
                        w.validate()
                            .map_err(|e| bad(format!("{}: {e}", p.display())))?;
                        w
                    }
                    None => WrinkleInput::default(),
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
                for fw in &input.frames {
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
                    if let (Some(cam), Some(fw)) = (
                        &input.camera,
                        input.frames.iter().find(|f| f.frame == take.frames[t]),
                    ) {
                        let res = synthesize_wrinkles(
                            &animator.mesh,
                            &vertices,
                            cam,
                            &fw.wrinkles,
                            &SynthesisSettings::default(),
                        )?;
                        vertices = res.vertices;
                        wr = fw
                            .wrinkles
                            .iter()
                            .cloned()
                            .zip(res.projected.into_iter().map(Some))
                            .collect();
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
        }
    }
}

impl Cli {
    /// Runs the subcommand.
    pub fn run(self) -> Result<()> {
        self.command.run()
    }
}
