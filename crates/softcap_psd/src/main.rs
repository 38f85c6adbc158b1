//! `softcap-psd`: pose-space details (thesis ch. 5).
//!
//! - `softcap-psd evaluate` — the Fig. 5.5 comparison on the ICT fixture, plot, report, renders
//!   (source face and detail transfer to the ICT identities).
//! - `softcap-psd markers` — write a marker (handle) trajectory from held-out poses (CSV, or MCAP
//!   `/capture/markers` when the output ends in `.mcap`).
//! - `softcap-psd animate` — synthesize a detailed face per frame of a marker trajectory (CSV or
//!   MCAP in; OBJ frames or an MCAP with `/face/mesh` + `/psd/large_scale` out).

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use softcap_psd::nalgebra::Vector3;
use softcap_psd::*;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "softcap-psd",
    version,
    about = "Pose-space details: learning, real-time synthesis, transfer"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
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
struct EvaluateArgs {
    /// ICT fixture folder (neutral.obj, expressions.scpose, identities.scpose).
    #[arg(long, default_value = "fixtures/ict-face")]
    fixtures: PathBuf,
    /// Output folder for plot, report.json and renders.
    #[arg(long, short)]
    out: PathBuf,
    /// Settings TOML (`EvaluationSettings`); defaults otherwise.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override the largest basis size.
    #[arg(long)]
    max_poses: Option<usize>,
}

#[derive(clap::Args, Debug)]
struct MarkersArgs {
    /// ICT fixture folder.
    #[arg(long, default_value = "fixtures/ict-face")]
    fixtures: PathBuf,
    /// Frames between consecutive held-out poses.
    #[arg(long, default_value_t = 10)]
    frames_per_pose: usize,
    /// Output: CSV (frame,handle,x_cm,y_cm,z_cm) or `.mcap` (`/capture/markers`, marker id =
    /// handle index, metres, 30 frames/s).
    #[arg(long, short)]
    out: PathBuf,
}

#[derive(clap::Args, Debug)]
struct AnimateArgs {
    /// ICT fixture folder (the model is trained on it).
    #[arg(long, default_value = "fixtures/ict-face")]
    fixtures: PathBuf,
    /// Marker trajectory: CSV (frame,handle,x_cm,y_cm,z_cm, one row per handle and frame) or
    /// `.mcap` (`/capture/markers`, marker id = handle index, metres).
    #[arg(long)]
    markers: PathBuf,
    /// Basis size P of the WPSD model (greedy least squares).
    #[arg(long, default_value_t = 6)]
    poses: usize,
    /// Output: folder for frame_NNNN.obj, or a `.mcap` file (`/face/mesh`, `/psd/large_scale`).
    #[arg(long, short)]
    out: PathBuf,
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
    let result = match &cli.command {
        Command::Evaluate(a) => a.run(),
        Command::Markers(a) => a.run(),
        Command::Animate(a) => a.run(),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            let bad_input = e.chain().any(|c| {
                matches!(
                    c.downcast_ref::<PsdError>(),
                    Some(
                        PsdError::BadPoseFile { .. }
                            | PsdError::BadMarkerFile { .. }
                            | PsdError::BadRecording { .. }
                            | PsdError::BadMessage { .. }
                            | PsdError::Mesh(_)
                            | PsdError::Io { .. }
                    )
                )
            });
            if bad_input {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}

fn to_f32(x: &[Vector3<f64>]) -> Vec<[f32; 3]> {
    x.iter()
        .map(|p| [p.x as f32, p.y as f32, p.z as f32])
        .collect()
}

impl EvaluateArgs {
    fn run(&self) -> Result<()> {
        let mut settings: EvaluationSettings = match &self.config {
            Some(p) => toml_settings(p)?,
            None => EvaluationSettings::default(),
        };
        if let Some(p) = self.max_poses {
            settings.max_poses = p;
        }
        let data = IctData::load(&self.fixtures)?;
        std::fs::create_dir_all(&self.out)
            .with_context(|| format!("creating {}", self.out.display()))?;
        let t0 = std::time::Instant::now();
        let rig = FaceRig::new(&data.mesh, &settings.rig)?;
        eprintln!(
            "rig: {} vertices, H = {}, F = {} ({:.1} s)",
            rig.num_vertices(),
            rig.handles.len(),
            rig.graph.len(),
            t0.elapsed().as_secs_f64()
        );
        let report = evaluate(&data, &rig, &settings)?;
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
        let json = serde_json::to_string_pretty(&report)?;
        write_atomic(&self.out.join("report.json"), json.as_bytes())?;
        let transfer = renders(&data, &rig, &settings, &self.out)?;
        let json = serde_json::to_string_pretty(&transfer)?;
        write_atomic(&self.out.join("transfer.json"), json.as_bytes())?;
        for t in &transfer {
            println!(
                "{}: large-scale only {:.3} mm, with transferred details {:.3} mm",
                t.identity, t.large_only_rms_mm, t.transferred_rms_mm
            );
        }
        Ok(())
    }
}

#[derive(serde::Serialize)]
struct TransferRow {
    identity: String,
    pose: String,
    large_only_rms_mm: f64,
    transferred_rms_mm: f64,
}

fn rms_mm(a: &[[f32; 3]], b: &[Vector3<f64>]) -> f64 {
    let s: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64) - y).norm_squared())
        .sum();
    10.0 * (s / a.len() as f64).sqrt()
}

/// Source-face renders and the identity transfer (thesis §5.4.4, Fig. 5.8 style).
fn renders(
    data: &IctData,
    rig: &FaceRig,
    settings: &EvaluationSettings,
    out: &Path,
) -> Result<Vec<TransferRow>> {
    let (training, heldout) = pose_sets(data, settings);
    let poses: Vec<_> = training.iter().map(|r| data.pose(r)).collect();
    let examples = rig.examples(&poses)?;
    let method = Method::Wpsd(FitMode::LeastSquares, rig.edge_weights.clone());
    let steps = greedy_selection(&examples, &method, 0, 12, |_, _| Ok(()))?;
    let basis = steps
        .last()
        .map(|s| s.basis.clone())
        .unwrap_or_else(|| vec![0]);
    let model = method.fit(&examples, &basis)?;
    // the held-out pose with the largest detail (error of the shell alone)
    let pick = heldout
        .iter()
        .map(|r| {
            let p = data.pose(r);
            let (x, _) = rig.large_scale(&rig.handle_positions(&p));
            rms_mm(&x, &p)
        })
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|x| x.0)
        .unwrap_or(0);
    let recipe = &heldout[pick];
    let tile = 200;
    let mut rows = Vec::new();
    let mut grid: Vec<image::RgbImage> = Vec::new();
    let mut targets = vec![("generic".to_string(), data.mesh.vertices.clone())];
    for k in 0..data.identities.names.len() {
        targets.push((
            data.identities.names[k].clone(),
            data.identities.combine(&data.mesh.vertices, &[(k, 1.0)]),
        ));
    }
    for (name, rest) in &targets {
        let mesh = softcap_mesh::TriMesh {
            vertices: rest.clone(),
            triangles: data.mesh.triangles.clone(),
        };
        let trig =
            FaceRig::with_handles(&mesh, rig.handles.clone(), Some(&rig.graph), &settings.rig)?;
        let tmodel = transfer_details(&model, &trig, &identity_correspondence(rest.len()))?;
        let truth = data.expressions.combine(rest, &recipe.weights);
        let hp = trig.handle_positions(&truth);
        let (large, large_n) = trig.large_scale(&hp);
        let mut anim = Animator::new(&trig, &tmodel)?;
        anim.frame(&hp)?;
        rows.push(TransferRow {
            identity: name.clone(),
            pose: recipe.name.clone(),
            large_only_rms_mm: rms_mm(&large, &truth),
            transferred_rms_mm: rms_mm(&anim.positions, &truth),
        });
        // panels: large-scale only | + details | ground truth | signed detail along the normal
        let truth32 = to_f32(&truth);
        let view = render::View::fit(&truth32, tile);
        let tris = &trig.topology.triangles;
        let normals_of = |x: &[[f32; 3]]| {
            let mut f = vec![[0.0; 3]; tris.len()];
            frames::face_normals(&trig.topology, x, &mut f);
            let mut n = vec![[0.0; 3]; x.len()];
            frames::vertex_normals(&trig.topology, &f, &mut n);
            n
        };
        let signed: Vec<[f32; 3]> = (0..large.len())
            .map(|v| {
                let d: f32 = (0..3)
                    .map(|k| (anim.positions[v][k] - large[v][k]) * large_n[v][k])
                    .sum();
                render::diverging(d / 0.2) // ±2 mm
            })
            .collect();
        grid.push(render::render(&view, &large, &large_n, tris, None));
        grid.push(render::render(
            &view,
            &anim.positions,
            &anim.normals,
            tris,
            None,
        ));
        grid.push(render::render(
            &view,
            &truth32,
            &normals_of(&truth32),
            tris,
            None,
        ));
        grid.push(render::render(
            &view,
            &anim.positions,
            &anim.normals,
            tris,
            Some(&signed),
        ));
    }
    let (tw, th) = (
        grid[0].width(),
        grid.iter().map(|g| g.height()).max().unwrap_or(0),
    );
    let mut sheet = image::RgbImage::from_pixel(
        4 * tw,
        th * targets.len() as u32,
        image::Rgb([255, 255, 255]),
    );
    for (i, img) in grid.iter().enumerate() {
        image::imageops::overlay(
            &mut sheet,
            img,
            ((i % 4) as u32 * tw) as i64,
            ((i / 4) as u32 * th) as i64,
        );
    }
    render::save_png(&sheet, &out.join("transfer_identities.png"))?;
    Ok(rows)
}

fn toml_settings<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    toml_parse(&text).with_context(|| format!("parsing {}", path.display()))
}

fn toml_parse<T: serde::de::DeserializeOwned>(text: &str) -> Result<T> {
    Ok(toml::from_str(text)?)
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))?;
    Ok(())
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
        p.add_input(i)
            .with_context(|| format!("hashing input {}", i.display()))?;
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
            write_atomic(&self.out, text.as_bytes())?;
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

/// Read `frame,handle,x_cm,y_cm,z_cm` rows into per-frame handle positions.
fn read_markers(path: &Path, handles: usize) -> Result<Vec<Vec<Vector3<f64>>>, PsdError> {
    let bad = |line: usize, field: &str, reason: String| PsdError::BadMarkerFile {
        path: path.into(),
        line,
        field: field.into(),
        reason,
    };
    let mut rdr = csv::Reader::from_path(path).map_err(|e| bad(1, "header", e.to_string()))?;
    let mut frames: Vec<Vec<Option<Vector3<f64>>>> = Vec::new();
    for (i, rec) in rdr.records().enumerate() {
        let line = i + 2;
        let rec = rec.map_err(|e| bad(line, "row", e.to_string()))?;
        let get = |k: usize, name: &str| -> Result<&str, PsdError> {
            rec.get(k).ok_or_else(|| bad(line, name, "missing".into()))
        };
        let frame: usize = get(0, "frame")?
            .trim()
            .parse()
            .map_err(|e| bad(line, "frame", format!("{e}")))?;
        let h: usize = get(1, "handle")?
            .trim()
            .parse()
            .map_err(|e| bad(line, "handle", format!("{e}")))?;
        if h >= handles {
            return Err(bad(line, "handle", format!("{h} ≥ {handles} handles")));
        }
        let mut p = Vector3::zeros();
        for (k, name) in ["x_cm", "y_cm", "z_cm"].iter().enumerate() {
            let x: f64 = get(2 + k, name)?
                .trim()
                .parse()
                .map_err(|e| bad(line, name, format!("{e}")))?;
            if !x.is_finite() {
                return Err(bad(line, name, "not finite".into()));
            }
            p[k] = x;
        }
        if frames.len() <= frame {
            frames.resize(frame + 1, vec![None; handles]);
        }
        frames[frame][h] = Some(p);
    }
    frames
        .into_iter()
        .enumerate()
        .map(|(f, hs)| {
            hs.into_iter()
                .enumerate()
                .map(|(h, p)| {
                    p.ok_or_else(|| {
                        bad(0, "handle", format!("frame {f} has no row for handle {h}"))
                    })
                })
                .collect()
        })
        .collect()
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
                frames: read_markers(&self.markers, h)?
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
        let mut anim = Animator::new(&rig, &model)?;
        let frames = trajectory.frames.len();
        let total_s = if is_mcap(&self.out) {
            let prov = provenance(
                &[&self.markers],
                format!("poses = {}, basis = {basis:?}", self.poses),
            )?;
            animate_to_mcap(&mut anim, &trajectory, &self.out, &prov, &out_settings)?.synthesis_s
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
        for (f, hp) in trajectory.frames.iter().enumerate() {
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
        let s: EvaluationSettings = toml_parse("max_poses = 5\n[rig]\nhandles = 40\n").unwrap();
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

    #[test]
    fn bad_marker_row_names_line_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.csv");
        std::fs::write(&p, "frame,handle,x_cm,y_cm,z_cm\n0,0,1,2,3\n0,1,1,zz,3\n").unwrap();
        let e = read_markers(&p, 2).unwrap_err().to_string();
        assert!(e.contains("line 3") && e.contains("y_cm"), "{e}");
        std::fs::write(&p, "frame,handle,x_cm,y_cm,z_cm\n0,0,1,2,3\n").unwrap();
        let e = read_markers(&p, 2).unwrap_err().to_string();
        assert!(e.contains("no row for handle 1"), "{e}");
    }
}
