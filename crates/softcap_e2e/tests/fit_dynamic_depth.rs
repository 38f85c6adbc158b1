//! wang2015 Table 1 from depth (issue 36): the bar with 8 control points (E linear from 8.0 to
//! 3.5·10⁵ Pa along it, ν 0.45, ρ 1100 kg/m³, α 0.8 1/s, β 1 ms), filmed in the Table 1 protocol's
//! eleven motions (three off-axis bending pushes at 30 Hz, eight 3 N twists at 120 Hz, each push's
//! interaction extended by 50 ms; `examples/fit_dynamic_table1.rs bar8ab --bends 3 --twists 8
//! --twist-mn 3000 --settle-ms 50`), each rendered by the virtual depth rig (two Kinect-like
//! cameras, depth-noise seed `seed + 1000 k`), captured, tracked with the default material
//! (wang2015 §5; the material's prediction in 4 steps a frame, `TrackSettings::substeps`) and
//! fitted jointly (§6: segments of 60 frames, the first two modes' share of every start fitted);
//! then tracked again with that fit (`track --material`, wang2015's tracking ↔ estimation: the
//! default E 100 kPa loses the fast bends) and fitted again, pass after pass. The chain of
//! `scripts/fit-dynamic-table1-track` (`CASE=bar8ab`), run in-process; docs/dynamic-fit.md has
//! its rows.

use std::path::{Path, PathBuf};

use softcap_capture::{CaptureSettings, Session, capture_dynamic, write_dynamic_capture_mcap};
use softcap_mesh::nalgebra::Vector3;
use softcap_synth::{Scenario, synthesize};
use softcap_tissue::Progress;
use softcap_tissue::fit_dynamic::run::{FitDynamicConfig, run as fit_run};
use softcap_tissue::fit_dynamic::synthetic::{
    SyntheticSpec, TwistPush, clamped_box, table1_motions, write_depth_sessions,
};
use softcap_tissue::fit_dynamic::{
    Blending, DynamicFit, FitDynamicSettings, control_points as make_control_points,
};
use softcap_tissue::track::{TrackConfig, TrackSettings, run as track_run};

/// The truth's E at the 8 control points (`fit_dynamic_table1 bar8`), Pa.
const E_CP: [f64; 8] = [8.0e5, 7.0e5, 6.0e5, 5.5e5, 5.0e5, 4.5e5, 4.0e5, 3.5e5];

/// The seven motions' noise-free truth of `bar8ab` on noise seed `seed`, as
/// `fit_dynamic_table1 bar8ab --bends 3 --twists 8 --twist-mn 3000 --settle-ms 50 --seed N`
/// builds them, written for the depth rig in `dir`; returns the motions' scenario files.
fn write_sessions(dir: &Path, seed: u64) -> Vec<PathBuf> {
    let size = [0.2, 0.03, 0.02];
    let cells = [12, 2, 2];
    let (mesh, support, top_edge) = clamped_box(size, cells);
    let cp = make_control_points(&mesh, &support, E_CP.len(), Blending::Linear).unwrap();
    let off_axis: Vec<usize> = top_edge
        .iter()
        .copied()
        .filter(|&i| mesh.vertices[i].y >= 0.0)
        .collect();
    let bend = SyntheticSpec {
        rest_mesh: mesh.clone(),
        support_nodes: support,
        young_pa: cp.blend(&E_CP),
        push_nodes: off_axis,
        push_force_n: Vector3::new(0.0, 0.5, -0.4),
        frames: 60,
        noise_m: 0.0,
        seed,
        ..SyntheticSpec::small_clamped_bar()
    };
    let twist = TwistPush {
        nodes: top_edge,
        counter_nodes: Vec::new(),
        force_n: Vector3::new(0.0, 3.0, 0.0),
    };
    let specs = table1_motions(&bend, 3, &twist, 8, seed);
    write_depth_sessions(dir, "bar8ab", size, cells, &specs, &E_CP, 0.05, seed).unwrap();
    (0..specs.len())
        .map(|k| dir.join(format!("motion-{k}.toml")))
        .collect()
}

/// `softcap synth` → `softcap capture` of one scenario; returns the session folder and the
/// capture.mcap.
fn render_and_capture(scenario: &Path) -> (PathBuf, PathBuf) {
    let s = Scenario::load(scenario).unwrap();
    let session_dir = scenario.with_extension("");
    synthesize(&s, &session_dir).unwrap();
    let session = Session::load(&session_dir).unwrap();
    let settings = CaptureSettings::default();
    let clouds = capture_dynamic(&session, &settings.depth).unwrap();
    let capture = session_dir.with_extension("capture.mcap");
    write_dynamic_capture_mcap(&capture, &session, &clouds, &settings, &["test".into()]).unwrap();
    (session_dir, capture)
}

/// `softcap tissue track` of every capture (with `material` if given; `substeps` 4), then
/// `tissue fit-dynamic` of all tracks jointly with 8 control points, segments of 60 frames, 2 start
/// modes, `--json dir/fit.json`; returns the fit and its material for the next pass
/// (`--next-material`: control points at an E bound take their nearest free neighbour's E;
/// Anderson-accelerated over `previous`, earlier passes' `fit.json`, when given).
fn track_and_fit(
    dir: &Path,
    sessions: &[(PathBuf, PathBuf)],
    material: Option<&Path>,
    previous: &[PathBuf],
) -> (DynamicFit, PathBuf) {
    std::fs::create_dir_all(dir).unwrap();
    let mesh = sessions[0].0.join("template/volume.msh");
    let tracks: Vec<PathBuf> = sessions
        .iter()
        .enumerate()
        .map(|(k, (session, capture))| {
            let output = dir.join(format!("motion-{k}-track.mcap"));
            track_run(&TrackConfig {
                capture: capture.clone(),
                mesh: session.join("template/volume.msh"),
                material: material.map(Path::to_path_buf),
                attach: None,
                output: output.clone(),
                settings: TrackSettings {
                    // the 30 Hz bends' second bending modes (ω h 2.3–3.6) predicted in 4 steps
                    substeps: 4,
                    progress: false,
                    ..Default::default()
                },
                arguments: vec!["test".into()],
            })
            .unwrap();
            output
        })
        .collect();
    let next = dir.join("next.mcap");
    let fit = fit_run(
        &FitDynamicConfig {
            track: tracks[0].clone(),
            more_tracks: tracks[1..].to_vec(),
            mesh,
            output: dir.join("dynamic.mcap"),
            report: None,
            json: Some(dir.join("fit.json")),
            next_material: Some(next.clone()),
            previous_passes: previous.to_vec(),
            settings: FitDynamicSettings {
                control_points: E_CP.len(),
                segment_frames: 60,
                start_state_modes: 2,
                progress: false,
                ..Default::default()
            },
            arguments: vec!["test".into()],
        },
        &Progress::hidden(),
    )
    .unwrap();
    (fit, next)
}

/// Per control point: (error, sandwich 1-σ per segment), both relative; then α's and β's errors.
fn errors(fit: &DynamicFit) -> (Vec<(f64, f64)>, f64, f64) {
    let e = fit
        .young_pa
        .iter()
        .zip(E_CP)
        .zip(&fit.segment_robust_sigma)
        .map(|((f, t), s)| (f / t - 1.0, *s))
        .collect();
    (
        e,
        fit.damping.alpha_per_s / 0.8 - 1.0,
        fit.damping.beta_s / 1.0e-3 - 1.0,
    )
}

/// Pass 6 of `bar8ab` from depth on one seed meets Table 1's tolerances (issue 36): E within 5 %
/// at every control point the fit flags observable (`DynamicFit::observable`: 1-σ ≤ 2.5 % on
/// s²(JᵀJ)⁻¹ and the sandwich per segment, |correlation| with a neighbour < 0.95, off the bounds;
/// at least one), α within 5 %, β within 20 %. Passes 0–5 are the plain loop (pass 0 default
/// material, each later one tracked with the previous fit's `--next-material`); pass 5's next
/// material is Anderson-accelerated over passes 2–5 (`--previous-passes`, depth 2), pass 6
/// tracks with it. Measured with the CLI chain (`scripts/fit-dynamic-table1-track`, `ANDERSON=5`; 8 twists, seed 11, substeps 4): the plain loop converges linearly where the
/// tracker's pull toward its own material is strong, E₆ +26.2 (pass 0), +36.3, +31.3, +23.4,
/// +16.9, +12.0 % (pass 5, × 0.72 a pass; E₀–E₅ within 3.3 %); the accelerated material has
/// E₆ +1.8 % (E₇, unflagged, +66 %) and pass 6 flags E₀–E₆ at +3.1, +0.9, −2.9, +2.0, +0.6,
/// −2.2, +0.2 % (E₇ +79.9 %; α +0.6 %, β −0.2 %; tracking RMS 0.282 mm). A second accelerated
/// pass (7) overshoots along the loop's near-neutral directions (E₂/E₃ and E₆/E₇ trade; the fit
/// reproduces the material it was tracked with within 0.3 points): E₂ −5.7, E₃ +5.4, E₆ −5.4 %, so
/// the loop accelerates once; pass 7 plain after pass 6 stays within 3.4 % (+3.1, +1.1, −3.4, +2.6,
/// +0.2, −2.0, −1.1 %). Accelerated one pass earlier (pass 4 over passes 1–4) pass 5 meets it too,
/// with less margin: +4.0, +0.1, −2.1, +1.3, +1.5, −2.9, +1.2 % (`ITERATIONS=5 ANDERSON=4`). Pass 0 tracked with one step a frame (substeps 1) converges no
/// faster: E₆ +45.6, +39.5, +29.8 % at passes 0–2. This test, run end to end (its own renders,
/// `RAYON_NUM_THREADS=1`, session 50): every pass as the CLI chain above, pass 6 the same
/// +3.1 … +0.2 %; passed in 1,453 user CPU-s (24:49 wall at load 4–5).
#[test]
#[ignore = "passes (pass 6: E0-E6 within 3.1 %, alpha +0.6 %, beta -0.2 %) but costs 1,453 CPU-s (7 passes of ~35 tracking + 160-280 fitting CPU-s)"]
fn bar8_from_depth_meets_table1() {
    let seed = 11;
    let tmp = tempfile::tempdir().unwrap();
    let scenarios = write_sessions(tmp.path(), seed);
    let sessions: Vec<(PathBuf, PathBuf)> =
        scenarios.iter().map(|s| render_and_capture(s)).collect();
    let json = |pass: usize| tmp.path().join(format!("pass{pass}/fit.json"));
    let mut material: Option<PathBuf> = None;
    let mut fit = None;
    for pass in 0..=6 {
        // Pass 5's next material accelerated over passes 2-4 and itself.
        let previous: Vec<PathBuf> = if pass == 5 {
            (2..5).map(json).collect()
        } else {
            Vec::new()
        };
        let dir = tmp.path().join(format!("pass{pass}"));
        let (f, next) = track_and_fit(&dir, &sessions, material.as_deref(), &previous);
        let (e, a, b) = errors(&f);
        eprintln!(
            "bar8ab seed {seed} pass {pass}: E {}, alpha {:+.1} %, beta {:+.1} %, trajectory RMS {:.3} mm, status {}",
            e.iter()
                .map(|(e, s)| format!("{:+.1} ({:.1})", 100.0 * e, 100.0 * s))
                .collect::<Vec<_>>()
                .join(", "),
            100.0 * a,
            100.0 * b,
            1e3 * f.rms_m,
            f.status
        );
        material = Some(next);
        fit = Some(f);
    }
    let fit = fit.unwrap();
    let (e, a, b) = errors(&fit);
    let observable: Vec<usize> = (0..e.len()).filter(|&c| fit.observable[c]).collect();
    eprintln!(
        "observable {observable:?} (neighbour correlation {:?})",
        fit.neighbour_correlation
    );
    assert!(!observable.is_empty(), "no control point observable: {e:?}");
    for &c in &observable {
        assert!(e[c].0.abs() <= 0.05, "E{c}: {:+.1} %", 100.0 * e[c].0);
    }
    assert!(a.abs() <= 0.05, "alpha {:+.1} %", 100.0 * a);
    assert!(b.abs() <= 0.20, "beta {:+.1} %", 100.0 * b);
}
