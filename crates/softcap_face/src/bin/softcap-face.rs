//! `softcap-face`: thin binary over the softcap_face library.
//!
//! - `softcap-face landmarks --mocap TAKE.csv --face NEUTRAL.obj -o TABLE.csv`
//! - `softcap-face animate --mocap TAKE.csv --face NEUTRAL.obj --landmarks TABLE.csv --frames 0,120,390 --out DIR`

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use clap::{Parser, Subcommand};
use softcap_face::{
    FaceAnimator, OrthoView, derive_landmarks, landmarks_csv, parse_landmarks_csv,
    read_animface_csv, render_mesh,
};
use softcap_mesh::nalgebra::Vector3;
use softcap_mesh::shell::ShellSettings;

#[derive(Parser, Debug)]
#[command(
    name = "softcap-face",
    about = "face stage: mocap → face correspondence, linear shell animation, wrinkles"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
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

fn read_face(path: &PathBuf) -> anyhow::Result<softcap_mesh::TriMesh> {
    let obj =
        softcap_mesh::read_obj(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(obj.to_tri_mesh())
}

impl Command {
    fn run(&self) -> anyhow::Result<()> {
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
                    bail!("{}: no marker `{nose}`", mocap.display())
                };
                let rows =
                    derive_landmarks(&take.names, &take.positions_cm[0], &mesh.vertices, n, 30)?;
                let tmp = output.with_extension("csv.tmp");
                std::fs::write(&tmp, landmarks_csv(&rows))
                    .with_context(|| format!("writing {}", tmp.display()))?;
                std::fs::rename(&tmp, output)?;
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
                let take = read_animface_csv(mocap)?;
                let mesh = read_face(face)?;
                let text = std::fs::read_to_string(landmarks)
                    .with_context(|| format!("reading {}", landmarks.display()))?;
                let table = parse_landmarks_csv(&text, landmarks)?;
                let mut handles = Vec::new();
                for name in &take.names {
                    let Some(row) = table.iter().find(|r| &r.marker == name) else {
                        bail!("{}: no landmark for marker `{name}`", landmarks.display())
                    };
                    handles.push(row.vertex);
                }
                let animator = FaceAnimator::new(
                    mesh,
                    handles,
                    &take.positions_cm[0],
                    &ShellSettings::default(),
                )?;
                std::fs::create_dir_all(out)?;
                let (view, h) = OrthoView::fit(&animator.mesh.vertices, *width_px);
                for f in frames {
                    let Some(t) = take.frames.iter().position(|x| x == f) else {
                        bail!("{}: no frame {f}", mocap.display())
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

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(2)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    match cli.command.run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            let bad_input = e.chain().any(|c| {
                c.downcast_ref::<softcap_face::FaceError>()
                    .is_some_and(|f| {
                        matches!(
                            f,
                            softcap_face::FaceError::Parse { .. }
                                | softcap_face::FaceError::InvalidInput { .. }
                                | softcap_face::FaceError::Io { .. }
                        )
                    })
            });
            ExitCode::from(if bad_input { 2 } else { 1 })
        }
    }
}
