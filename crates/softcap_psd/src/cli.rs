//! The `softcap-psd` command line: pose-space details (thesis ch. 5).
//!
//! - `softcap-psd evaluate` — the Fig. 5.5 comparison on the ICT fixture, plot, report, renders
//!   (source face and detail transfer to the ICT identities).
//! - `softcap-psd markers` — write a marker (handle) trajectory from held-out poses (CSV, or MCAP
//!   `/capture/markers` when the output ends in `.mcap`).
//! - `softcap-psd animate` — synthesize a detailed face per frame of a marker trajectory (CSV or
//!   MCAP in; OBJ frames or an MCAP with `/face/mesh` + `/psd/large_scale` out).

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};
use softcap_app::{Context, IntoError, Progress, Result, load_toml_or_default};

use crate::nalgebra::Vector3;
use crate::*;

#[derive(Parser, Debug)]
#[command(
    name = "softcap-psd",
    version,
    about = "Pose-space details: learning, real-time synthesis, transfer"
)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Fig. 5.5 comparison (held-out error vs. basis size), renders and transfer.
    Evaluate(EvaluateArgs),
    /// Write the handle trajectory of held-out poses, blended over time (CSV, or MCAP if `--out`
    /// ends in `.mcap`).
    Markers(MarkersArgs),
    /// Animate the WPSD face over a marker trajectory (CSV or `.mcap`); writes one OBJ per frame
    /// or, if `--out` ends in `.mcap`, the stage MCAP.
    Animate(AnimateArgs),
}

#[derive(clap::Args, Debug)]
pub struct EvaluateArgs {
    /// ICT fixture folder (neutral.obj, expressions.scpose, identities.scpose).
    #[arg(long, default_value = "fixtures/ict-face")]
    pub fixtures: PathBuf,
    /// Output folder for plot, report.json and renders.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Settings TOML (`EvaluationSettings`); defaults otherwise.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override the largest basis size.
    #[arg(long)]
    pub max_poses: Option<usize>,
}

#[derive(clap::Args, Debug)]
pub struct MarkersArgs {
    /// ICT fixture folder.
    #[arg(long, default_value = "fixtures/ict-face")]
    pub fixtures: PathBuf,
    /// Frames between consecutive held-out poses.
    #[arg(long, default_value_t = 10)]
    pub frames_per_pose: usize,
    /// Output: CSV (frame,handle,x_cm,y_cm,z_cm) or `.mcap` (`/capture/markers`, marker id =
    /// handle index, metres, 30 frames/s).
    #[arg(long, short)]
    pub out: PathBuf,
}

#[derive(clap::Args, Debug)]
pub struct AnimateArgs {
    /// ICT fixture folder (the model is trained on it).
    #[arg(long, default_value = "fixtures/ict-face")]
    pub fixtures: PathBuf,
    /// Marker trajectory: CSV (frame,handle,x_cm,y_cm,z_cm, one row per handle and frame) or
    /// `.mcap` (`/capture/markers`, marker id = handle index, metres).
    #[arg(long)]
    pub markers: PathBuf,
    /// Basis size P of the WPSD model (greedy least squares).
    #[arg(long, default_value_t = 6)]
    pub poses: usize,
    /// Output: folder for frame_NNNN.obj, or a `.mcap` file (`/face/mesh`, `/psd/large_scale`).
    #[arg(long, short)]
    pub out: PathBuf,
}

impl Cli {
    /// Runs the subcommand.
    pub fn run(self) -> Result<()> {
        match &self.command {
            Command::Evaluate(a) => a.run(),
            Command::Markers(a) => a.run(),
            Command::Animate(a) => a.run(),
        }
    }
}

impl EvaluateArgs {
    fn run(&self) -> Result<()> {
        let mut settings: EvaluationSettings = load_toml_or_default(self.config.as_deref())?;
        if let Some(p) = self.max_poses {
            settings.max_poses = p;
        }
        let data = IctData::load(&self.fixtures)?;
        std::fs::create_dir_all(&self.out)
            .with_context(|| format!("creating {}", self.out.display()))?;
        let t0 = std::time::Instant::now();
        let spinner = Progress::default().spinner("building the face rig");
        let rig = FaceRig::new(&data.mesh, &settings.rig)?;
        spinner.finish_and_clear();
        eprintln!(
            "rig: {} vertices, H = {}, F = {} ({:.1} s)",
            rig.num_vertices(),
            rig.handles.len(),
            rig.graph.len(),
            t0.elapsed().as_secs_f64()
        );
        let spinner = Progress::default().spinner("evaluating PSD / WPSD / blend shapes");
        let report = evaluate(&data, &rig, &settings)?;
        spinner.finish_and_clear();
        eprintln!("evaluation done ({:.1} s)", t0.elapsed().as_secs_f64());
        for c in &report.curves {
            let cells: Vec<String> = c
                .basis_sizes
                .iter()
                .zip(&c.heldout_rms_mm)
                .map(|(p, e)| format!("P{p}:{e:.3}"))
                .collect();
            println!("{:22} {}", c.method, cells.join(" "));
        }
        println!("large-scale only: {:.3} mm", report.large_scale_only_rms_mm);
        plot::plot_error_vs_basis(&report, &self.out.join("error_vs_basis.png"))?;
        write_json(&self.out.join("report.json"), &report)?;
        let spinner = Progress::default().spinner("rendering the identity transfer");
        let transfer = transfer_sheet::transfer_sheet(&data, &rig, &settings, &self.out)?;
        spinner.finish_and_clear();
        write_json(&self.out.join("transfer.json"), &transfer)?;
        for t in &transfer {
            println!(
                "{}: large-scale only {:.3} mm, with transferred details {:.3} mm",
                t.identity, t.large_only_rms_mm, t.transferred_rms_mm
            );
        }
        Ok(())
    }
}

/// Writes `value` as pretty JSON to `path`, atomically.
fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let json = serde_json::to_string_pretty(value).failure_with(|| path.display().to_string())?;
    softcap_app::write_atomic(path, json.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

/// Frame rate of trajectories written by `markers` (log time = frame / rate).
const FRAME_RATE_HZ: f64 = 30.0;

fn is_mcap(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}

fn provenance(inputs: &[&Path], settings: String) -> Result<softcap_mcap::Provenance> {
    let mut p = softcap_mcap::Provenance::new("psd", env!("CARGO_PKG_VERSION"))
        .with_arguments(std::env::args())
        .with_settings(settings);
    for i in inputs {
        p.add_input(i)?;
    }
    Ok(p)
}

impl MarkersArgs {
    fn run(&self) -> Result<()> {
        let data = IctData::load(&self.fixtures)?;
        let settings = EvaluationSettings::default();
        let handles = farthest_point_handles(&data.mesh.vertices, settings.rig.handles);
        let (_, heldout) = pose_sets(&data, &settings);
        let fpp = self.frames_per_pose.max(1);
        let mut trajectory = HandleTrajectory::default();
        for w in heldout.windows(2) {
            let (a, b) = (data.pose(&w[0]), data.pose(&w[1]));
            for s in 0..fpp {
                let t = s as f64 / fpp as f64;
                let frame = trajectory.frames.len() as u64;
                trajectory.frames.push(HandleFrame {
                    frame,
                    log_time_ns: (frame as f64 / FRAME_RATE_HZ * 1e9).round() as u64,
                    positions: handles
                        .iter()
                        .map(|&v| a[v] * (1.0 - t) + b[v] * t)
                        .collect(),
                });
            }
        }
        if is_mcap(&self.out) {
            let prov = provenance(&[], format!("frames_per_pose = {fpp}"))?;
            write_handle_trajectory(&self.out, &prov, &trajectory, 0.01)?;
        } else {
            let mut text = String::from("frame,handle,x_cm,y_cm,z_cm\n");
            for f in &trajectory.frames {
                for (k, p) in f.positions.iter().enumerate() {
                    text.push_str(&format!(
                        "{},{k},{:.6},{:.6},{:.6}\n",
                        f.frame, p.x, p.y, p.z
                    ));
                }
            }
            softcap_app::write_atomic(&self.out, text.as_bytes())
                .with_context(|| format!("writing {}", self.out.display()))?;
        }
        eprintln!(
            "{}: {} frames × {} handles",
            self.out.display(),
            trajectory.frames.len(),
            handles.len()
        );
        Ok(())
    }
}

impl AnimateArgs {
    fn run(&self) -> Result<()> {
        let settings = EvaluationSettings::default();
        let out_settings = AnimateSettings::default();
        let h = settings.rig.handles;
        // read and validate the whole input before any work or output
        let trajectory = if is_mcap(&self.markers) {
            read_handle_trajectory(&self.markers, h, out_settings.metres_per_unit)?
        } else {
            HandleTrajectory {
                frames: read_handle_csv(&self.markers, h)?
                    .into_iter()
                    .enumerate()
                    .map(|(f, positions)| HandleFrame {
                        frame: f as u64,
                        log_time_ns: (f as f64 / FRAME_RATE_HZ * 1e9).round() as u64,
                        positions,
                    })
                    .collect(),
            }
        };
        let data = IctData::load(&self.fixtures)?;
        let spinner = Progress::default().spinner("training the WPSD model");
        let rig = FaceRig::new(&data.mesh, &settings.rig)?;
        let (training, _) = pose_sets(&data, &settings);
        let poses: Vec<_> = training.iter().map(|r| data.pose(r)).collect();
        let examples = rig.examples(&poses)?;
        let method = Method::Wpsd(FitMode::LeastSquares, rig.edge_weights.clone());
        let steps = greedy_selection(&examples, &method, 0, self.poses.max(1), |_, _| Ok(()))?;
        let basis = steps
            .last()
            .map(|s| s.basis.clone())
            .unwrap_or_else(|| vec![0]);
        let model = method.fit(&examples, &basis)?;
        spinner.finish_and_clear();
        let mut anim = Animator::new(&rig, &model)?;
        let frames = trajectory.frames.len();
        let total_s = if is_mcap(&self.out) {
            let prov = provenance(
                &[&self.markers],
                format!("poses = {}, basis = {basis:?}", self.poses),
            )?;
            let spinner = Progress::default().spinner("synthesizing frames");
            let summary = animate_to_mcap(&mut anim, &trajectory, &self.out, &prov, &out_settings)?;
            spinner.finish_and_clear();
            summary.synthesis_s
        } else {
            self.write_objs(&mut anim, &trajectory, &data.mesh.triangles)?
        };
        eprintln!(
            "{}: {frames} frames, P = {}, mean synthesis time {:.2} ms/frame",
            self.out.display(),
            basis.len(),
            1e3 * total_s / frames.max(1) as f64
        );
        Ok(())
    }

    /// One OBJ per frame into a temporary folder renamed when complete; returns synthesis time.
    fn write_objs(
        &self,
        anim: &mut Animator<'_>,
        trajectory: &HandleTrajectory,
        triangles: &[[usize; 3]],
    ) -> Result<f64> {
        let tmp = self.out.with_extension("partial");
        std::fs::create_dir_all(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
        let mut total = std::time::Duration::ZERO;
        let bar = Progress::default().bar("synthesizing frames", trajectory.frames.len() as u64);
        for (f, hp) in trajectory.frames.iter().enumerate() {
            bar.inc(1);
            let t = std::time::Instant::now();
            anim.frame(&hp.positions)?;
            total += t.elapsed();
            let mesh = softcap_mesh::TriMesh {
                vertices: anim
                    .positions
                    .iter()
                    .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
                    .collect(),
                triangles: triangles.to_vec(),
            };
            softcap_mesh::write_tri_mesh_obj(tmp.join(format!("frame_{f:04}.obj")), &mesh)?;
        }
        if self.out.exists() {
            std::fs::remove_dir_all(&self.out)
                .with_context(|| format!("replacing {}", self.out.display()))?;
        }
        std::fs::rename(&tmp, &self.out)
            .with_context(|| format!("renaming to {}", self.out.display()))?;
        Ok(total.as_secs_f64())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cli_parses_subcommands() {
        let s: EvaluationSettings = toml::from_str("max_poses = 5\n[rig]\nhandles = 40\n").unwrap();
        assert_eq!(
            (s.max_poses, s.rig.handles, s.rig.feature_edges),
            (5, 40, 243)
        );
        let c = Cli::try_parse_from(["softcap-psd", "evaluate", "--out", "x", "--max-poses", "8"])
            .unwrap();
        assert!(matches!(
            c.command,
            Command::Evaluate(EvaluateArgs {
                max_poses: Some(8),
                ..
            })
        ));
        assert!(Cli::try_parse_from(["softcap-psd", "animate", "--out", "x"]).is_err());
    }
}
