//! Every file reader softcap exposes to a user's file, as one function `(scratch dir, bytes) →
//! Result` per fuzz target.
//!
//! Each reader is driven through its public, path-taking entry point (the one the stage binary
//! calls): the input bytes are written to a file in a scratch folder first, next to whatever fixed
//! companion files the reader needs (a camera rig, a template mesh, the other files of a session).
//! The same table runs under libFuzzer (`fuzz/fuzz_targets/*.rs`) and in `make test`
//! (`crates/softcap_e2e/tests/fuzz_regressions.rs`, which replays every committed crash input and
//! the minimized corpora), so a reader added here is fuzzed and regression-tested at once.
//!
//! A reader may reject its input (an `Err`); it must never panic, hang or allocate without bound.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use softcap_app::{Error, Result};

/// One fuzz target: its name (the `fuzz/fuzz_targets/NAME.rs` file and `fuzz/corpus/NAME/`) and
/// the reader it drives.
pub struct Target {
    /// Target name.
    pub name: &'static str,
    /// Reads `bytes` as the target's file inside `dir` (a scratch folder it may write to).
    pub read: fn(&Path, &[u8]) -> Result<()>,
}

/// Every target, by name.
pub const TARGETS: &[Target] = &[
    Target {
        name: "mcap_recording",
        read: mcap_recording,
    },
    Target {
        name: "mcap_typed",
        read: mcap_typed,
    },
    Target {
        name: "session_toml",
        read: session_toml,
    },
    Target {
        name: "cameras_toml",
        read: cameras_toml,
    },
    Target {
        name: "depth_cameras_toml",
        read: depth_cameras_toml,
    },
    Target {
        name: "fsr_csv",
        read: fsr_csv,
    },
    Target {
        name: "fsr_toml",
        read: fsr_toml,
    },
    Target {
        name: "probe_toml",
        read: probe_toml,
    },
    Target {
        name: "trigger_csv",
        read: trigger_csv,
    },
    Target {
        name: "detections_csv",
        read: detections_csv,
    },
    Target {
        name: "markers_csv",
        read: markers_csv,
    },
    Target {
        name: "support_motion_csv",
        read: support_motion_csv,
    },
    Target {
        name: "interactions_csv",
        read: interactions_csv,
    },
    Target {
        name: "robot_csv",
        read: robot_csv,
    },
    Target {
        name: "obj",
        read: obj,
    },
    Target {
        name: "ply",
        read: ply,
    },
    Target {
        name: "msh",
        read: msh,
    },
    Target {
        name: "tetgen",
        read: tetgen,
    },
    Target {
        name: "c3d",
        read: c3d,
    },
    Target {
        name: "urdf",
        read: urdf,
    },
    Target {
        name: "aniposelib_toml",
        read: aniposelib_toml,
    },
    Target {
        name: "aniposelib_points",
        read: aniposelib_points,
    },
    Target {
        name: "depth_png",
        read: depth_png,
    },
    Target {
        name: "scenario_toml",
        read: scenario_toml,
    },
    Target {
        name: "reshape_target",
        read: reshape_target,
    },
    Target {
        name: "reshape_landmarks",
        read: reshape_landmarks,
    },
    Target {
        name: "settings",
        read: settings,
    },
];

/// The target called `name`.
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

/// Writes `bytes` to `dir/name` and returns the path.
fn put(dir: &Path, name: &str, bytes: &[u8]) -> Result<PathBuf> {
    let path = dir.join(name);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(Error::failure)?;
    }
    // Removed first, not truncated: ext4 (`auto_da_alloc`) writes a file's delayed blocks out
    // synchronously when it is opened with O_TRUNC over data, once per input (the corpus test's
    // 16k inputs took 49 s wall for 3.4 CPU-s; removed first, no flush).
    let _ = std::fs::remove_file(&path);
    std::fs::write(&path, bytes).map_err(Error::failure)?;
    Ok(path)
}

// ---- fixed companion files (compiled in, so the fuzzers and the test need no working dir) ----

const SESSION_CAMERAS: &[u8] = include_bytes!("../../fixtures/session-min/rig/cameras.toml");
const SESSION_FSR: &[u8] = include_bytes!("../../fixtures/session-min/rig/fsr.toml");
const SESSION_PROBE: &[u8] = include_bytes!("../../fixtures/session-min/rig/probe.toml");
const SESSION_MARKERS: &[u8] = include_bytes!("../../fixtures/session-min/template/markers.csv");
const SESSION_SURFACE: &[u8] = include_bytes!("../../fixtures/session-min/template/surface.obj");
const SESSION_VOLUME: &[u8] = include_bytes!("../../fixtures/session-min/template/volume.msh");
const SESSION_TRIGGER: &[u8] = include_bytes!("../../fixtures/session-min/trigger.csv");
const SESSION_FSR_SAMPLES: &[u8] = include_bytes!("../../fixtures/session-min/fsr.csv");
const ARM_URDF: &[u8] = include_bytes!("../../fixtures/robot/arm.urdf");
const ANIPOSE_CALIBRATION: &[u8] = include_bytes!("../../fixtures/aniposelib/calibration.toml");

/// The files of fixtures/session-min that `Session::load` reads besides session.toml.
fn session_folder(dir: &Path) -> Result<()> {
    if dir.join("template/volume.msh").exists() {
        return Ok(());
    }
    for (name, bytes) in [
        ("rig/cameras.toml", SESSION_CAMERAS),
        ("rig/fsr.toml", SESSION_FSR),
        ("rig/probe.toml", SESSION_PROBE),
        ("template/markers.csv", SESSION_MARKERS),
        ("template/surface.obj", SESSION_SURFACE),
        ("template/volume.msh", SESSION_VOLUME),
        ("trigger.csv", SESSION_TRIGGER),
        ("fsr.csv", SESSION_FSR_SAMPLES),
    ] {
        put(dir, name, bytes)?;
    }
    std::fs::create_dir_all(dir.join("frames")).map_err(Error::failure)?;
    std::fs::create_dir_all(dir.join("detections")).map_err(Error::failure)?;
    Ok(())
}

// ---- recordings ----

fn mcap_recording(dir: &Path, bytes: &[u8]) -> Result<()> {
    let r = softcap_mcap::Recording::from_bytes(dir.join("in.mcap"), bytes.to_vec())?;
    r.messages()?;
    r.metadata()?;
    r.provenance()?;
    r.digest()?;
    Ok(())
}

fn mcap_typed(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "typed.mcap", bytes)?;
    let capture = softcap_mcap::capture::CaptureData::read(&path);
    let material = softcap_mcap::material::MaterialData::read(&path);
    let track = softcap_mcap::dynamic::read_track(&path);
    capture?;
    material?;
    track?;
    Ok(())
}

// ---- raw session files ----

fn session_toml(dir: &Path, bytes: &[u8]) -> Result<()> {
    let dir = dir.join("session");
    session_folder(&dir)?;
    put(&dir, "session.toml", bytes)?;
    softcap_capture::Session::load(&dir)?;
    Ok(())
}

fn cameras_toml(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "cameras.toml", bytes)?;
    softcap_capture::session::read_cameras_toml(&path, 1e-3)?;
    Ok(())
}

fn depth_cameras_toml(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "depth_cameras.toml", bytes)?;
    softcap_capture::depth::read_depth_cameras_toml(&path, 1e-3)?;
    Ok(())
}

fn fsr_csv(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "fsr.csv", bytes)?;
    softcap_capture::session::read_fsr_csv(&path)?;
    Ok(())
}

fn fsr_toml(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "fsr.toml", bytes)?;
    softcap_capture::session::read_fsr_toml(&path)?;
    Ok(())
}

fn probe_toml(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "probe.toml", bytes)?;
    softcap_capture::session::read_probe_toml(&path, dir, 1e-3)?;
    Ok(())
}

fn trigger_csv(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "trigger.csv", bytes)?;
    softcap_capture::session::read_trigger_csv(&path)?;
    Ok(())
}

fn detections_csv(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "detections.csv", bytes)?;
    softcap_capture::session::read_detections_csv(&path)?;
    Ok(())
}

fn markers_csv(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "markers.csv", bytes)?;
    softcap_capture::session::read_markers_csv(&path, 1e-3)?;
    Ok(())
}

fn support_motion_csv(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "support_motion.csv", bytes)?;
    softcap_capture::depth::read_support_motion_csv(&path, 1e-3)?;
    Ok(())
}

/// `interactions.csv` and `support_nodes.csv` of a dynamic session: the same bytes through both.
fn interactions_csv(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "interactions.csv", bytes)?;
    let interactions = softcap_capture::depth::read_interactions_csv(&path);
    let nodes = softcap_capture::depth::read_support_nodes_csv(&path);
    interactions?;
    nodes?;
    Ok(())
}

/// `robot.csv` against the tool and F/T chains of fixtures/robot/arm.urdf, as `RobotRig::load`
/// reads it; the URDF is fixed, so it is parsed once per process (the `urdf` target fuzzes it).
fn robot_csv(dir: &Path, bytes: &[u8]) -> Result<()> {
    use softcap_capture::robot::KinematicChain;
    static CHAINS: OnceLock<[KinematicChain; 2]> = OnceLock::new();
    let chains = match CHAINS.get() {
        Some(chains) => chains,
        None => {
            let urdf = put(dir, "arm.urdf", ARM_URDF)?;
            let model = softcap_capture::RobotModel::from_urdf(&urdf)?;
            let chains = [model.chain("probe_tip")?, model.chain("ft_sensor")?];
            CHAINS.get_or_init(|| chains)
        }
    };
    let path = put(dir, "robot.csv", bytes)?;
    softcap_capture::robot::read_robot_csv(&path, &[&chains[0], &chains[1]], 1e-3)?;
    Ok(())
}

fn urdf(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "robot.urdf", bytes)?;
    let model = softcap_capture::RobotModel::from_urdf(&path)?;
    for link in ["probe_tip", "ft_sensor", "forearm", "base"] {
        if let Ok(chain) = model.chain(link) {
            let q = chain.joints.iter().map(|j| (j.name.clone(), 0.1)).collect();
            chain.forward(&q);
        }
    }
    Ok(())
}

fn c3d(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "take.c3d", bytes)?;
    softcap_capture::read_c3d(&path)?;
    Ok(())
}

fn aniposelib_toml(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "calibration.toml", bytes)?;
    softcap_capture::read_aniposelib_calibration(&path, 1e-3)?;
    Ok(())
}

/// aniposelib labeled points: CSV, or `.npz` when the bytes are a zip archive.
/// The calibration is fixed, so it is read once per process (`aniposelib_toml` fuzzes it).
fn aniposelib_points(dir: &Path, bytes: &[u8]) -> Result<()> {
    static CAMERAS: OnceLock<Vec<softcap_capture::Camera>> = OnceLock::new();
    let cameras = match CAMERAS.get() {
        Some(cameras) => cameras,
        None => {
            let calibration = put(dir, "calibration.toml", ANIPOSE_CALIBRATION)?;
            let cameras = softcap_capture::read_aniposelib_calibration(&calibration, 1e-3)?;
            CAMERAS.get_or_init(|| cameras)
        }
    };
    if bytes.starts_with(b"PK") {
        let path = put(dir, "points.npz", bytes)?;
        softcap_capture::read_npz_points(&path, cameras)?;
    } else {
        let path = put(dir, "points.csv", bytes)?;
        softcap_capture::read_labeled_points(&path, cameras)?;
    }
    Ok(())
}

/// A 16-bit depth PNG for a 16 × 12 px depth camera.
fn depth_png(dir: &Path, bytes: &[u8]) -> Result<()> {
    let camera = softcap_capture::Camera::new(
        "depth0".into(),
        16,
        12,
        [20.0, 20.0, 8.0, 6.0],
        [0.0; 5],
        nalgebra::Matrix3::identity(),
        nalgebra::Vector3::zeros(),
    )
    .map_err(Error::failure)?;
    let path = put(dir, "000000.png", bytes)?;
    softcap_capture::depth::read_depth_png(&path, &camera)?;
    Ok(())
}

// ---- meshes ----

fn obj(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "mesh.obj", bytes)?;
    let m = softcap_mesh::read_obj(&path);
    let t = softcap_mesh::read_obj_tri_mesh(&path);
    m?;
    t?;
    Ok(())
}

fn ply(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "mesh.ply", bytes)?;
    let m = softcap_mesh::read_ply(&path);
    let t = softcap_mesh::read_ply_tri_mesh(&path);
    m?;
    t?;
    Ok(())
}

fn msh(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "mesh.msh", bytes)?;
    let m = softcap_mesh::read_msh(&path);
    let t = softcap_mesh::read_msh_tet_mesh(&path);
    m?;
    t?;
    Ok(())
}

/// TetGen `.node` and `.ele`: the bytes before the first NUL are the `.node` file, the rest the
/// `.ele` file.
fn tetgen(dir: &Path, bytes: &[u8]) -> Result<()> {
    let split = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    let node = put(dir, "mesh.node", &bytes[..split])?;
    let ele = put(dir, "mesh.ele", bytes.get(split + 1..).unwrap_or_default())?;
    softcap_mesh::read_tetgen(&node, &ele)?;
    Ok(())
}

// ---- scenario, reshape target, settings ----

fn scenario_toml(dir: &Path, bytes: &[u8]) -> Result<()> {
    let path = put(dir, "scenario.toml", bytes)?;
    softcap_synth::Scenario::load(&path)?;
    Ok(())
}

/// A template (a 20 mm cube of 2 × 2 × 2 cells) and a free-flying TARGET folder with four
/// landmarks and two ICP markers.
fn reshape_folder(dir: &Path) -> Result<(PathBuf, PathBuf)> {
    let template = dir.join("template.msh");
    let target = dir.join("target");
    if !template.exists() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [20.0; 3], [2, 2, 2]);
        softcap_mesh::write_msh(
            &template,
            &softcap_mesh::MshMesh::from_tet_mesh(&mesh, None),
        )?;
        put(
            &target,
            "target.toml",
            b"length_unit = \"mm\"\nfree_flying = true\n",
        )?;
        put(
            &target,
            "landmarks.csv",
            b"id,template_x,template_y,template_z,x,y,z\n\
              a,1,1,1,1.5,1,1\nb,19,1,1,19,1.2,1\nc,1,19,1,1,19,1.3\nd,10,10,19,10,10,20\n",
        )?;
        put(
            &target,
            "icp_markers.csv",
            b"id,x,y,z\ni0,5,5,20\ni1,15,15,20\n",
        )?;
    }
    Ok((template, target))
}

fn reshape_target(dir: &Path, bytes: &[u8]) -> Result<()> {
    let (template, target) = reshape_folder(dir)?;
    put(&target, "target.toml", bytes)?;
    softcap_tissue::reshape::target::load_target(&template, &target)?;
    Ok(())
}

fn reshape_landmarks(dir: &Path, bytes: &[u8]) -> Result<()> {
    let (template, target) = reshape_folder(dir)?;
    put(&target, "landmarks.csv", bytes)?;
    softcap_tissue::reshape::target::load_target(&template, &target)?;
    Ok(())
}

/// Every stage's `--settings` TOML: the first byte picks the settings type, the rest is the file.
fn settings(dir: &Path, bytes: &[u8]) -> Result<()> {
    use softcap_app::load_toml;
    let Some((&which, text)) = bytes.split_first() else {
        return Ok(());
    };
    let path = put(dir, "settings.toml", text)?;
    match which % 8 {
        0 => {
            softcap_capture::session::parse_settings_toml(&path)?;
        }
        1 => {
            load_toml::<softcap_tissue::FitSettings>(&path)?;
        }
        2 => {
            load_toml::<softcap_tissue::SimulateSettings>(&path)?;
        }
        3 => {
            load_toml::<softcap_tissue::TrackSettings>(&path)?;
        }
        4 => {
            load_toml::<softcap_tissue::reshape::ReshapeSettings>(&path)?;
        }
        5 => {
            load_toml::<softcap_diagnose::StageSettings>(&path)?;
        }
        6 => {
            load_toml::<softcap_psd::EvaluationSettings>(&path)?;
        }
        _ => {
            load_toml::<softcap_design::CaptureMappingSettings>(&path)?;
        }
    }
    Ok(())
}
