//! wang2015 Table 1 from depth (issue 36): the bar with 8 control points (E linear from 8.0 to
//! 3.5·10⁵ Pa along it, ν 0.45, ρ 1100 kg/m³, α 0.8 1/s, β 1 ms), filmed in the Table 1 protocol's
//! seven motions (three off-axis bending pushes at 30 Hz, four 3 N twists at 120 Hz, each push's
//! interaction extended by 50 ms; `examples/fit_dynamic_table1.rs bar8ab --bends 3 --twists 4
//! --twist-mn 3000 --settle-ms 50`), each rendered by the virtual depth rig (two Kinect-like
//! cameras, depth-noise seed `seed + 1000 k`), captured, tracked with the default material
//! (wang2015 §5; the material's prediction in 4 steps a frame, `TrackSettings::substeps`) and
//! fitted jointly (§6: segments of 60 frames, the first two modes' share of every start fitted);
//! then tracked again with that fit (`track --material`, wang2015's tracking ↔ estimation: the
//! default E 100 kPa loses the fast bends) and fitted again. The chain of
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
/// `fit_dynamic_table1 bar8ab --bends 3 --twists 4 --twist-mn 3000 --settle-ms 50 --seed N`
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
    let specs = table1_motions(&bend, 3, &twist, 4, seed);
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
/// modes; returns the fit and its material for the next pass (`--next-material`: control points at
/// an E bound take their nearest free neighbour's E).
fn track_and_fit(
    dir: &Path,
    sessions: &[(PathBuf, PathBuf)],
    material: Option<&Path>,
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
            json: None,
            next_material: Some(next.clone()),
            previous_passes: Vec::new(),
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

/// Pass 1 (tracked with pass 0's fit) of `bar8ab` from depth on one seed meets Table 1's
/// tolerances (issue 36): E within 5 % at every control point the fit flags observable
/// (`DynamicFit::observable`: 1-σ ≤ 2.5 % on s²(JᵀJ)⁻¹ and the sandwich per segment, |correlation|
/// with a neighbour < 0.95, off the bounds; at least one),
/// α within 5 %, β within 20 %. Measured (scripts/fit-dynamic-table1-track, `--twists 8`, seed 11):
/// pass 1 α −1.4 %, β +1.6 %, but the flag marks E₀–E₅ at −21.0, +22.4, −7.8, −5.8, −0.7,
/// +12.3 % (1-σ 0.4–2.2 %, neighbour correlation 0.84–0.92): the tracker's bias, which the
/// residuals do not show (the same motions with 0.56 mm synthetic noise: E₀–E₆ within 4.4 %);
/// pass 2 −8.9, +13.9, −9.3, −3.5, +4.6, +3.0 %, pass 3 −3.6, +10.2, −10.5, −1.0, +8.0, −6.0 %
/// (E₂, E₄ drift away). Tracked with the truth's material (`TRUTH_MATERIAL=1`, an oracle) the
/// flagged E₀–E₄ are +3.5, +3.0, −7.6, +4.0, −2.3 % (E₅–E₇ +13.5, −7.2, +32.6 %): the tracker
/// has a bias of its own (RMS 0.51 mm, as at pass 2; seed 21 the same E within 0.7 points), so
/// more passes cannot meet 5 % either;
/// `data_weight` 256 (a weaker pull toward the material's one-step-per-frame prediction):
/// RMS 0.45 mm, E +1.3, +5.5, −7.8, +1.9, −2.0, +4.1 % (E₆, E₇ +16.7, +22.1 %).
/// That bias was the one Newmark step per 30 Hz frame (the bends' second modes at ω h 2.3–3.6):
/// with `substeps` 4 the truth material tracks at 0.28 mm (bends 0.78–0.84 → 0.28–0.29 mm) and
/// flags E₀–E₆ at +2.1, +1.0, −1.3, +0.8, −0.4, +0.5, +2.4 % (α +0.7 %, β −0.3 %). From the default
/// material with `substeps` 4 (8 twists, seed 11): pass 1 flags E₂–E₆ at +2.3, −9.0, −4.0, +7.1,
/// +45.0 % (E₀, E₁ −25.0, +20.7 %), pass 2 E₀–E₆ at −11.6, +10.3, +2.8, −8.6, −1.5, +3.8, +46.5 %
/// (α +0.8 %, β −0.3 %): tracking ↔ estimation now converges toward the truth at the ends (E₀
/// −56.5 → −25.0 → −11.6 %) but slowly, and E₆ stays at +45 % (pass 0 +26 %) with E₇ at its lower
/// bound from pass 0 on. Tracking with `--next-material` (E₇ at the bound takes E₆'s value): pass 1
/// E₆, E₇ +36.3, +13.5 % (flags E₂–E₅ at +2.2, −9.0, −4.1, +5.6 %), pass 2 flags E₀–E₆ at −12.0,
/// +10.5, +3.2, −8.7, −1.4, +3.8, +31.3 % (E₇ +4.7 %; α +0.7 %, β −0.2 %), pass 3 at −5.5, +5.7,
/// +2.6, −6.9, +0.2, +2.0, +23.4 % (E₇ +7.3 %; α +0.6 %, β −0.2 %), pass 4 at −1.9, +3.2, +1.7,
/// −5.0, +1.0, +0.5, +16.9 % (E₇ +15.7 %), pass 5 at +0.2, +2.0, +0.7, −3.3, +1.3, −0.5, +12.0 %
/// (E₇ +27.1 %): converging (E₀ × 0.46 a pass, E₆ × 0.71) while the unflagged E₇ climbs; E₆ needs
/// ≈ 3–4 more passes of ≈ 200 CPU-s.
#[test]
#[ignore = "fails on E: 8 twists, seed 11, substeps 4, --next-material: pass 1 flags E2-E5 at +2.2, -9.0, -4.1, +5.6 %, pass 2 E0-E6 at -12.0, +10.5, +3.2, -8.7, -1.4, +3.8, +31.3 %, pass 3 -5.5, +5.7, +2.6, -6.9, +0.2, +2.0, +23.4 %, pass 4 -1.9, +3.2, +1.7, -5.0, +1.0, +0.5, +16.9 %, pass 5 +0.2, +2.0, +0.7, -3.3, +1.3, -0.5, +12.0 % (truth material: E0-E6 within 2.4 %); alpha +1.6 %, beta -0.6 % pass; ≈ 500 CPU-s"]
fn bar8_from_depth_meets_table1() {
    let seed = 11;
    let tmp = tempfile::tempdir().unwrap();
    let scenarios = write_sessions(tmp.path(), seed);
    let sessions: Vec<(PathBuf, PathBuf)> =
        scenarios.iter().map(|s| render_and_capture(s)).collect();
    let (fit0, material) = track_and_fit(&tmp.path().join("pass0"), &sessions, None);
    let (fit1, _) = track_and_fit(&tmp.path().join("pass1"), &sessions, Some(&material));
    for (pass, fit) in [(0, &fit0), (1, &fit1)] {
        let (e, a, b) = errors(fit);
        eprintln!(
            "bar8ab seed {seed} pass {pass}: E {}, alpha {:+.1} %, beta {:+.1} %, trajectory RMS {:.3} mm, status {}",
            e.iter()
                .map(|(e, s)| format!("{:+.1} ({:.1})", 100.0 * e, 100.0 * s))
                .collect::<Vec<_>>()
                .join(", "),
            100.0 * a,
            100.0 * b,
            1e3 * fit.rms_m,
            fit.status
        );
    }
    let (e, a, b) = errors(&fit1);
    let observable: Vec<usize> = (0..e.len()).filter(|&c| fit1.observable[c]).collect();
    eprintln!(
        "observable {observable:?} (neighbour correlation {:?})",
        fit1.neighbour_correlation
    );
    assert!(!observable.is_empty(), "no control point observable: {e:?}");
    for &c in &observable {
        assert!(e[c].0.abs() <= 0.05, "E{c}: {:+.1} %", 100.0 * e[c].0);
    }
    assert!(a.abs() <= 0.05, "alpha {:+.1} %", 100.0 * a);
    assert!(b.abs() <= 0.20, "beta {:+.1} %", 100.0 * b);
}
