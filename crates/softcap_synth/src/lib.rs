//! # softcap_synth — the virtual rig
//!
//! Writes raw probing sessions that conform to `docs/session-format.md` from a scenario file, with a
//! ground truth known exactly (`truth/`) and physical or sensor effects switched on per scenario,
//! so that every stage can be tested end to end and `softcap diagnose` can be proven on data where
//! an effect is concealed. See `docs/synth.md`.
//!
//! | module | what |
//! |---|---|
//! | [`scenario`] | scenario TOML (`fixtures/scenarios/*.toml`): object, material, probe, protocol, rig, FSR, clock, output, effects |
//! | [`truth`] | ground truth: stable neo-Hookean (+ Yeoh c₂) on a finer mesh, rigid-probe contact, frame schedule |
//! | `engine` | time stepping per physics: elastic, viscoelastic, plastic, nodal (friction / support), dynamic |
//! | [`rig`] | cameras in a triangle (`softcap_core::camera`), visibility and occlusion, noisy detections |
//! | [`render`] | PNG frames: anti-aliased painted discs, probe, textured background |
//! | [`robot`] | 4-DOF arm (URDF), closed-form IK / FK, joint log and 6-axis F/T in the sensor frame (`robot.csv`) |
//! | [`sensors`] | FSR power law + divider, DAQ clock (offset, drift), trigger line, sensor lag / hysteresis |
//! | [`write`](mod@write) | the session folder and `truth/` (atomic: temporary folder renamed into place) |
//! | [`dynamic`] | `kind = "dynamic"`: free motion (release, drop, shaken clamp) under gravity seen by depth cameras (wang2015) |
//! | [`error`] | [`SynthError`] |
//! | [`cli`] | the `softcap-synth` command line ([`cli::Cli::run`]) |
//!
//! ```no_run
//! use softcap_synth::{Scenario, synthesize};
//! let mut scenario = Scenario::default();
//! scenario.protocol.locations = 4;
//! let report = synthesize(&scenario, std::path::Path::new("/tmp/session"))?;
//! assert_eq!(report.frames, 1 + 4 * (5 + 3 + 3 + 3)); // rest + (ramp, hold, release, move) per location
//! # Ok::<(), softcap_synth::SynthError>(())
//! ```

pub mod cli;
pub mod dynamic;
pub(crate) mod engine;
pub mod error;
pub mod render;
pub mod rig;
pub mod robot;
pub mod scenario;
pub mod sensors;
pub mod truth;
pub mod write;

pub use error::{Result, SynthError};
pub use scenario::{
    ClockSettings, Effect, EffectSettings, FsrSettings, MaterialSettings, ObjectSettings,
    OutputSettings, ProbeSettings, ProtocolSettings, RigSettings, RobotSettings, Scenario,
};
pub use truth::{
    FrameSpec, FrameTruth, Phase, Truth, TruthModel, simulate, simulate_with_progress,
};

pub use nalgebra;

use softcap_app::Progress;
use std::path::{Path, PathBuf};

/// What one synthesis run produced.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthReport {
    /// The session folder.
    pub path: PathBuf,
    /// Frames written.
    pub frames: usize,
    /// Probe locations.
    pub locations: usize,
    /// Ground-truth tets.
    pub truth_tets: usize,
    /// Template (fit) tets.
    pub fit_tets: usize,
    /// Largest axial probe force, N.
    pub max_axial_force_n: f64,
    /// Largest marker displacement from the template, m.
    pub max_marker_displacement_m: f64,
    /// Detection rows written (all cameras).
    pub detections: usize,
    /// Images written.
    pub images: usize,
    /// Largest equilibrium iteration count of any frame.
    pub max_iterations: usize,
    /// Valid depth readings written (dynamic sessions).
    pub depth_readings: usize,
    /// Mean fraction of the truth surface's track points no depth camera sees (dynamic sessions).
    pub unseen_fraction: f64,
}

/// RNG streams, one per purpose.
mod streams {
    pub const TRUTH: u64 = 1;
    pub const FSR_CAL: u64 = 2;
    pub const DAQ: u64 = 3;
    pub const ROBOT: u64 = 4;
    pub const DETECTIONS: u64 = 10;
    pub const TRACK_POINTS: u64 = 20;
    /// Depth images: this + 1_000_000 × camera + frame.
    pub const DEPTH: u64 = 1_000;
}

/// Simulates the scenario and writes the session to `out` (which must not exist or be empty).
pub fn synthesize(scenario: &Scenario, out: &Path) -> Result<SynthReport> {
    synthesize_with_progress(scenario, out, &Progress::hidden())
}

/// [`synthesize`], with bars over the simulated frames and the rendered images on `progress`.
pub fn synthesize_with_progress(
    scenario: &Scenario,
    out: &Path,
    progress: &Progress,
) -> Result<SynthReport> {
    scenario
        .validate()
        .map_err(|message| SynthError::Scenario {
            path: PathBuf::from(format!("<scenario {}>", scenario.name)),
            message,
        })?;
    if scenario.kind == "dynamic" {
        return dynamic::synthesize(scenario, out);
    }
    write::SessionWriter::check_target(out)?;
    let truth = truth::simulate_with_progress(
        scenario,
        &mut truth::stream(scenario.seed, streams::TRUTH),
        progress,
    )?;
    // Robot log before anything is written: an unreachable pose is a scenario error.
    let robot = if scenario.kind == "probe-robot" {
        let arm = robot::Arm::new(&scenario.robot);
        let rec = robot::record(
            scenario,
            &arm,
            &truth.frames,
            &mut truth::stream(scenario.seed, streams::ROBOT),
        )
        .map_err(|message| SynthError::Unsupported {
            scenario: scenario.name.clone(),
            message,
        })?;
        Some((arm, rec))
    } else {
        None
    };
    let (mut report, path) = write::SessionWriter::atomically(out, |w| {
        write_all(scenario, &truth, robot.as_ref(), w, progress)
    })?;
    report.path = path;
    Ok(report)
}

fn write_all(
    s: &Scenario,
    truth: &Truth,
    robot: Option<&(robot::Arm, robot::RobotRecord)>,
    w: &write::SessionWriter,
    progress: &Progress,
) -> Result<SynthReport> {
    let cams = rig::cameras(s, &truth.block.size_m)?;
    let o = &s.output;
    w.text(
        "session.toml",
        &write::session_toml(s, o.images, o.detections, robot.is_some()),
    )?;
    w.text("rig/cameras.toml", &write::cameras_toml(&cams))?;
    w.text("rig/probe.toml", &write::probe_toml(s))?;
    w.text(
        "template/markers.csv",
        &write::markers_csv(truth, &s.object.marker_color),
    )?;
    write::write_template_meshes(w, &truth.template_fit_mesh)?;
    w.text("trigger.csv", &write::trigger_csv(truth))?;
    let (offset_s, drift, daq) = match robot {
        Some((arm, rec)) => {
            w.text("rig/robot.urdf", &arm.urdf())?;
            w.text("robot.csv", &robot::robot_csv(rec))?;
            (rec.offset_s, rec.drift, None)
        }
        None => {
            let cal = sensors::calibration(&s.fsr, &mut truth::stream(s.seed, streams::FSR_CAL));
            w.text("rig/fsr.toml", &write::fsr_toml(s, &cal))?;
            let daq = sensors::record(s, &truth.frames, &mut truth::stream(s.seed, streams::DAQ));
            w.text("fsr.csv", &write::fsr_csv(&daq))?;
            (daq.offset_s, daq.drift, Some(daq))
        }
    };

    let mut detections = 0;
    if o.detections {
        for (k, cam) in cams.iter().enumerate() {
            let rows = rig::detections(
                s,
                truth,
                cam,
                &mut truth::stream(s.seed, streams::DETECTIONS + k as u64),
            );
            let text = write::detections_csv(&rows, o.labeled);
            detections += text.lines().count() - 1;
            w.text(&format!("detections/{}.csv", cam.id), &text)?;
        }
    }
    let mut images = 0;
    if o.images {
        let bar = progress.bar("rendering images", (cams.len() * truth.frames.len()) as u64);
        for (k, cam) in cams.iter().enumerate() {
            let rays = render::CameraRays::new(cam);
            let base = render::background(&rays, &truth.block.size_m, o.texture_contrast, k as u64);
            let dir = w.path(&format!("frames/{}", cam.id));
            std::fs::create_dir_all(&dir).map_err(error::io_err(&dir))?;
            for f in &truth.frames {
                let img = render::render_frame(
                    &base,
                    &rays,
                    truth,
                    f,
                    &s.object.marker_color,
                    s.object.marker_radius_mm * 1e-3,
                    o.supersample,
                    true,
                );
                let p = dir.join(format!("{:06}.png", f.spec.frame));
                img.save_with_format(&p, image::ImageFormat::Png)
                    .map_err(|e| SynthError::Image {
                        path: p.clone(),
                        message: e.to_string(),
                    })?;
                images += 1;
                bar.inc(1);
            }
        }
        bar.finish_and_clear();
    }

    w.text("truth/markers.csv", &write::truth_markers_csv(truth))?;
    w.text("truth/probe.csv", &write::truth_probe_csv(truth))?;
    w.text("truth/frames.csv", &write::truth_frames_csv(truth))?;
    w.text("truth/clock.toml", &write::clock_toml(offset_s, drift))?;
    w.text(
        "truth/README.md",
        &write::truth_readme(s, truth, daq.as_ref()),
    )?;
    w.text(
        "truth/scenario.toml",
        &toml::to_string(s).unwrap_or_else(|e| format!("# scenario not serialisable: {e}\n")),
    )?;

    let max_disp = truth
        .frames
        .iter()
        .flat_map(|f| {
            f.markers_m
                .iter()
                .zip(&truth.template_markers_m)
                .map(|(a, b)| (a - b).norm())
        })
        .fold(0.0, f64::max);
    Ok(SynthReport {
        path: w.target.clone(),
        frames: truth.frames.len(),
        locations: truth.locations_m.len(),
        truth_tets: truth.block.truth_mesh.tets.len(),
        fit_tets: truth.block.fit_mesh.tets.len(),
        max_axial_force_n: truth
            .frames
            .iter()
            .map(|f| f.axial_force_n)
            .fold(0.0, f64::max),
        max_marker_displacement_m: max_disp,
        detections,
        images,
        max_iterations: truth.max_iterations,
        depth_readings: 0,
        unseen_fraction: 0.0,
    })
}
