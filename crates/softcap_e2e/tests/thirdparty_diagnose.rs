//! The diagnosis on the third-party truth suite (`fixtures/thirdparty/`, made by
//! `scripts/thirdparty-suite` with FElupe and gmsh, not by softcap; docs/thirdparty.md): per case
//! the chain a user runs — capture from the unlabeled detections → tissue fit → diagnose — in
//! process through each stage's library API, and issue 38's acceptance rule:
//!
//! - a control (`effect = "none"` in `fixtures/thirdparty/suite.toml`) passes with the verdict
//!   `none`;
//! - an effect case passes when the verdict is its effect and the held-out error after modeling
//!   (on the effect's own cells) is ≥ 3× lower than before **or** within 1.25× of its paired
//!   control's held-out error of the default model on the same hypothesis's cells (the floor the
//!   model can reach: the same geometry, material and protocol without the effect);
//! - `clock-offset` (no trigger line): capture's data-driven clock sync removes the offset before
//!   the diagnosis sees the data, so the right answer downstream is `none` — the case passes when
//!   capture's offset is within [`CLOCK_OFFSET_TOLERANCE_S`] of `truth/clock.toml`, the verdict is
//!   `none` and the default model's held-out error is within 1.25× of the paired control's.
//!
//! - `gravity-preload`: the truth's markers differ from its paired control's by 0.008 mm RMS
//!   (`scripts/thirdparty-suite`'s `pairs` table), far below the marker noise, so no diagnosis can
//!   see it; the case passes with `none` when that truth-to-pair difference, computed here from the
//!   two `truth/markers.csv`, is below the noise σ the diagnosis measured.
//!
//! The material is `common::suite_fit_settings` (as the own-rig suite). A paired control's
//! diagnosis is computed once per test process and shared by the cases that need it. Each test
//! prints one `THIRDPARTY` row (case, expected, verdict, held-out before → after of the expected
//! effect, the pair's floor, seconds) that docs/thirdparty.md's confusion table is built from.
//! Only the assertions read `truth/` and `suite.toml`; the chain reads the raw session.
//!
//! Cases that do not pass yet stay here `#[ignore]`d with the measured reason.
//!
//! The `lookalike_*` tests follow the planner on issue 37's second look-alike pair
//! (`fixtures/thirdparty/lookalikes/`: a sensor lag and a clock offset of 50 ms on the clean
//! case's FElupe solution): the standard recording is `inconclusive` between the two and asks for
//! a re-recording ([`Diagnosis::next_experiment`]); the test diagnoses the session recorded under
//! that protocol, until the verdict names the effect with its delay within
//! [`LOOKALIKE_DELAY_TOLERANCE`] of the truth's.

mod common;

use softcap_capture::{CaptureSettings, MarkerSource, Session, capture, write_capture_mcap};
use softcap_diagnose::{DiagnoseSettings, Diagnosis, RankedHypothesis, RunConfig, StageSettings};
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// How far capture's camera ↔ DAQ offset may be from the truth's for the clock to count as
/// corrected by capture: a twentieth of the suite's 100 ms frame period (measured: 1.7 ms).
const CLOCK_OFFSET_TOLERANCE_S: f64 = 5e-3;

/// The paired-control floor factor and the reduction factor of issue 38's acceptance rule.
const FLOOR_FACTOR: f64 = 1.25;
const REDUCTION_FACTOR: f64 = 3.0;

/// The look-alike sessions' delay (sensor-lag τ, clock offset), s: `truth/case.toml` of
/// `fixtures/thirdparty/lookalikes/*-50ms*`.
const LOOKALIKE_DELAY_S: f64 = 0.05;

/// How far the named effect's fitted delay may be from [`LOOKALIKE_DELAY_S`], relative: a tenth,
/// 5 ms, a twentieth of the sessions' 100 ms frame period (measured: 47.6 and 53.1 ms).
const LOOKALIKE_DELAY_TOLERANCE: f64 = 0.1;

fn case_dir(case: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../fixtures/thirdparty")
        .join(case)
}

/// `(effect, pair)` of a case from `fixtures/thirdparty/suite.toml` (a small fixed-format file
/// written by the generator: `[case]`, `effect = "…"`, `pair = "…"`).
fn suite_entry(case: &str) -> (String, String) {
    let path = case_dir("suite.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let (mut current, mut effect, mut pair) = (String::new(), None, None);
    for line in text.lines().map(str::trim) {
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            current = name.to_string();
        } else if current == case
            && let Some((k, v)) = line.split_once('=')
        {
            let v = v.trim().trim_matches('"').to_string();
            match k.trim() {
                "effect" => effect = Some(v),
                "pair" => pair = Some(v),
                _ => {}
            }
        }
    }
    (
        effect.unwrap_or_else(|| panic!("{}: no effect for [{case}]", path.display())),
        pair.unwrap_or_default(),
    )
}

/// The chain's result on one case.
struct Outcome {
    diagnosis: Diagnosis,
    /// Capture's camera ↔ DAQ clock offset (`t_daq = offset + (1 + drift) t_camera`), s.
    clock_offset_s: Option<f64>,
    /// Seconds in capture, tissue fit, diagnose.
    seconds: [f64; 3],
}

/// capture (detections) → tissue fit → diagnose on `fixtures/thirdparty/<case>`.
///
/// Developer aids: `SOFTCAP_THIRDPARTY_CACHE=DIR` keeps each case's capture.mcap and
/// material.mcap in `DIR/<case>/` and reuses them (for iterating on the diagnose stage only; stale
/// when capture or tissue code changes); `SOFTCAP_THIRDPARTY_JSON=DIR` keeps the diagnosis JSON as
/// `DIR/<case>.json`.
fn chain(case: &str) -> Outcome {
    chain_with(case, DiagnoseSettings::default())
}

/// [`chain`] with the diagnosis's settings `diagnose`.
fn chain_with(case: &str, diagnose: DiagnoseSettings) -> Outcome {
    let dir = tempfile::tempdir().unwrap();
    let cache = std::env::var_os("SOFTCAP_THIRDPARTY_CACHE").map(|d| PathBuf::from(d).join(case));
    let work = cache.clone().unwrap_or_else(|| dir.path().to_path_buf());
    std::fs::create_dir_all(&work).unwrap();
    let capture_path = work.join("capture.mcap");
    let material = work.join("material.mcap");
    let t0 = Instant::now();
    let session = Session::load(&case_dir(case)).unwrap();
    let settings = CaptureSettings {
        source: MarkerSource::Detections,
        ..Default::default()
    };
    let captured = capture(&session, &settings).unwrap();
    let cached = cache.is_some() && capture_path.is_file() && material.is_file();
    if !cached {
        write_capture_mcap(&capture_path, &session, &captured, &settings, &[]).unwrap();
    }
    let t_capture = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    if !cached {
        common::fit_and_print(
            case,
            &softcap_tissue::fit::FitConfig {
                capture: capture_path.clone(),
                mesh: Some(session.volume.clone().expect("template/volume.msh")),
                output: material.clone(),
                report: None,
                settings: common::suite_fit_settings(),
                arguments: vec![],
            },
        );
    }
    let t_tissue = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let diagnosis = softcap_diagnose::run(&RunConfig {
        capture: capture_path,
        material,
        output: dir.path().join("diagnosis.mcap"),
        json: Some(dir.path().join("diagnosis.json")),
        report: None,
        settings: StageSettings {
            diagnose,
            material: common::suite_material_source(),
            ..StageSettings::default()
        },
        arguments: vec![],
        progress: false,
    })
    .unwrap();
    if let Some(keep) = std::env::var_os("SOFTCAP_THIRDPARTY_JSON").map(PathBuf::from) {
        let kept = keep.join(format!("{case}.json")); // a look-alike case is `lookalikes/<name>`
        std::fs::create_dir_all(kept.parent().unwrap()).unwrap();
        std::fs::copy(dir.path().join("diagnosis.json"), kept).unwrap();
    }
    Outcome {
        diagnosis,
        clock_offset_s: captured.sync.map(|s| s.offset_s),
        seconds: [t_capture, t_tissue, t0.elapsed().as_secs_f64()],
    }
}

/// The chain's outcome on `case`, run once per test process (a paired control serves several
/// effect cases; concurrent callers of one case wait for the first).
fn outcome(case: &str) -> Arc<Outcome> {
    type Cache = Mutex<HashMap<String, Arc<OnceLock<Arc<Outcome>>>>>;
    static CACHE: OnceLock<Cache> = OnceLock::new();
    let cell = CACHE
        .get_or_init(Default::default)
        .lock()
        .unwrap()
        .entry(case.to_string())
        .or_default()
        .clone();
    cell.get_or_init(|| Arc::new(chain(case))).clone()
}

fn ranked<'a>(d: &'a Diagnosis, hypothesis: &str) -> Option<(usize, &'a RankedHypothesis)> {
    d.ranked
        .iter()
        .enumerate()
        .find(|(_, r)| r.hypothesis == hypothesis)
        .map(|(k, r)| (k + 1, r))
}

fn summary(d: &Diagnosis) -> Vec<String> {
    d.ranked
        .iter()
        .map(|r| {
            format!(
                "{} {:.4} -> {:.4} mm params={:?}",
                r.hypothesis,
                1e3 * r.heldout_rmse_before_m,
                1e3 * r.heldout_rmse_after_m,
                r.params
            )
        })
        .collect()
}

/// Runs the chain on `case` (and its paired control) and asserts the acceptance rule.
fn check(case: &str) {
    let (effect, pair) = suite_entry(case);
    let o = outcome(case);
    let d = &o.diagnosis;
    let s = o.seconds;
    let times = format!(
        "capture {:.1} s, tissue {:.1} s, diagnose {:.1} s",
        s[0], s[1], s[2]
    );
    let all = summary(d);
    if let Some(top) = d.ranked.first() {
        println!(
            "{case} signatures: {}",
            top.evidence.to_json()["signatures"]
        );
    }
    if effect == "none" {
        let none = ranked(d, "none").map(|(_, r)| r.heldout_rmse_before_m);
        println!(
            "THIRDPARTY | {case} | none | {} | {:.4} | – | – | {times}",
            d.verdict,
            1e3 * none.unwrap_or(f64::NAN)
        );
        println!("{case} ranked: {all:#?}");
        assert_eq!(d.verdict, "none", "{case}: ranked {all:#?}");
        return;
    }
    let p = outcome(&pair);
    let (rank, r) = ranked(d, &effect).unwrap_or_else(|| panic!("{case}: {effect} not ranked"));
    let (before, after) = (r.heldout_rmse_before_m, r.heldout_rmse_after_m);
    let floor = ranked(&p.diagnosis, &effect)
        .map(|(_, r)| r.heldout_rmse_before_m)
        .unwrap_or_else(|| panic!("{pair}: {effect} not ranked"));
    println!(
        "THIRDPARTY | {case} | {effect} | {} | {:.4} -> {:.4} (rank {rank}) | {:.4} ({pair}) | {times}",
        d.verdict,
        1e3 * before,
        1e3 * after,
        1e3 * floor
    );
    println!("{case} ranked: {all:#?}");
    if effect == "clock-offset" {
        check_clock_corrected_by_capture(case, &o, before, floor);
        return;
    }
    if effect == "gravity-preload" {
        check_below_noise(case, &pair, d);
        return;
    }
    assert_eq!(d.verdict, effect, "{case}: ranked {all:#?}");
    assert!(
        REDUCTION_FACTOR * after <= before || after <= FLOOR_FACTOR * floor,
        "{case}: held-out {:.4} -> {:.4} mm is neither {REDUCTION_FACTOR}x lower nor within \
         {FLOOR_FACTOR}x of {pair}'s {:.4} mm",
        1e3 * before,
        1e3 * after,
        1e3 * floor
    );
}

/// `clock-offset`: capture found the offset (no trigger line: from the data), so the diagnosis
/// sees aligned data — verdict `none`, held-out error at the paired control's floor.
fn check_clock_corrected_by_capture(case: &str, o: &Outcome, before: f64, floor: f64) {
    let text = std::fs::read_to_string(case_dir(case).join("truth/clock.toml")).unwrap();
    let truth: f64 = text
        .lines()
        .find_map(|l| l.strip_prefix("offset_s = "))
        .and_then(|v| v.trim().parse().ok())
        .expect("truth/clock.toml: offset_s");
    let found = o.clock_offset_s.expect("capture found no clock sync");
    println!(
        "{case}: capture's clock offset {found:.6} s, truth {truth:.6} s ({:.2} ms)",
        1e3 * (found - truth).abs()
    );
    assert!(
        (found - truth).abs() <= CLOCK_OFFSET_TOLERANCE_S,
        "{case}: capture's clock offset {found} s vs truth {truth} s"
    );
    assert_eq!(
        o.diagnosis.verdict,
        "none",
        "{case}: {:#?}",
        summary(&o.diagnosis)
    );
    assert!(
        before <= FLOOR_FACTOR * floor,
        "{case}: default model {:.4} mm vs the paired control's {:.4} mm",
        1e3 * before,
        1e3 * floor
    );
}

/// Marker positions of `truth/markers.csv` (object markers only, mm): `[frame][marker]`, the
/// markers in file order.
fn truth_markers(case: &str) -> Vec<Vec<[f64; 3]>> {
    let text = std::fs::read_to_string(case_dir(case).join("truth/markers.csv")).unwrap();
    let mut frames: Vec<Vec<[f64; 3]>> = Vec::new();
    for line in text.lines().skip(1).filter(|l| !l.is_empty()) {
        let v: Vec<&str> = line.split(',').collect();
        if v[1].starts_with("shaft") {
            continue;
        }
        let k: usize = v[0].parse().unwrap();
        let x: Vec<f64> = v[2..5].iter().map(|x| x.parse().unwrap()).collect();
        if frames.len() <= k {
            frames.resize(k + 1, Vec::new());
        }
        frames[k].push([x[0], x[1], x[2]]);
    }
    frames
}

/// RMS over frames and markers of the difference between two truths' marker displacements from
/// their frame 0, m (the `pairs` table of `scripts/thirdparty-suite`).
fn truth_pair_difference_m(case: &str, pair: &str) -> f64 {
    let (a, b) = (truth_markers(case), truth_markers(pair));
    assert_eq!(a.len(), b.len(), "{case} / {pair}: frame counts differ");
    let (mut sum, mut n) = (0.0, 0usize);
    for (fa, fb) in a.iter().zip(&b) {
        for m in 0..fa.len().min(fb.len()) {
            for c in 0..3 {
                let d = (fa[m][c] - a[0][m][c]) - (fb[m][c] - b[0][m][c]);
                sum += d * d;
            }
            n += 1;
        }
    }
    1e-3 * (sum / n.max(1) as f64).sqrt()
}

/// An effect whose truth differs from its paired control's by less than the marker noise σ
/// (per coordinate, as the diagnosis measured it) cannot be seen: the right verdict is `none`.
fn check_below_noise(case: &str, pair: &str, d: &Diagnosis) {
    let difference = truth_pair_difference_m(case, pair);
    let sigma = d.ranked[0].evidence.signatures.noise_sigma_m;
    println!(
        "{case}: truth differs from {pair} by {:.4} mm RMS; marker noise σ {:.4} mm",
        1e3 * difference,
        1e3 * sigma
    );
    assert!(
        difference < sigma,
        "{case}: the effect ({:.4} mm from {pair}) is above the noise ({:.4} mm): it must be named",
        1e3 * difference,
        1e3 * sigma
    );
    assert_eq!(d.verdict, "none", "{case}: {:#?}", summary(d));
}

/// One look-alike chain the planner follows ([`check_lookalike_chain`]).
struct Lookalike<'a> {
    /// The first recording, `fixtures/thirdparty/lookalikes/<case>`.
    case: &'a str,
    /// The look-alike pair every `inconclusive` recording must name as its candidates (sorted).
    pair: [&'a str; 2],
    /// The next experiment the planner must ask for; its recording is `<session>-<protocol>`.
    protocol: &'a str,
    /// How many recordings are `inconclusive` before the last names the effect.
    rerecordings: usize,
    /// The effect the last recording must name.
    effect: &'a str,
    /// The named effect's parameter, its truth and the relative tolerance on it.
    param: (&'a str, f64, f64),
}

/// Follows the planner from `fixtures/thirdparty/lookalikes/<case>`: each of the first
/// `rerecordings` diagnoses must be `inconclusive` between the `pair` with the next experiment
/// `protocol`, and the test goes on with the session recorded under it (`<session>-<protocol>`);
/// the last must name `effect` with its parameter within the tolerance of the truth. Prints one
/// `LOOKALIKE` row per session (verdict, candidates with their mean fold gains, next experiment,
/// named effect, seconds).
fn check_lookalike_chain(c: &Lookalike<'_>) {
    let mut session = format!("lookalikes/{}", c.case);
    for step in 0..=c.rerecordings {
        let o = outcome(&session);
        let d = &o.diagnosis;
        let mean = |g: &[f64]| g.iter().sum::<f64>() / g.len().max(1) as f64;
        let candidates: Vec<String> = d
            .candidates
            .iter()
            .map(|c| format!("{} {:.3} {:?}", c.hypothesis, mean(&c.fold_gains), c.params))
            .collect();
        let named: Vec<String> = d
            .effects
            .iter()
            .map(|e| format!("{} {:.3} {:?}", e.hypothesis, mean(&e.fold_gains), e.params))
            .collect();
        let next = d.next_experiment.as_ref().map(|n| n.protocol.as_str());
        let s = o.seconds;
        println!(
            "LOOKALIKE | {session} | {} | {candidates:?} | {} | {named:?} | capture {:.1} s, tissue {:.1} s, diagnose {:.1} s",
            d.verdict,
            next.unwrap_or("-"),
            s[0],
            s[1],
            s[2]
        );
        let all = summary(d);
        if step < c.rerecordings {
            assert_eq!(d.verdict, "inconclusive", "{session}: ranked {all:#?}");
            let mut names: Vec<&str> = d.candidates.iter().map(|c| c.hypothesis.as_str()).collect();
            names.sort_unstable();
            assert_eq!(names, c.pair, "{session}: candidates");
            assert_eq!(next, Some(c.protocol), "{session}: next experiment");
            session = format!("{session}-{}", c.protocol);
            continue;
        }
        assert_eq!(d.verdict, c.effect, "{session}: ranked {all:#?}");
        let (param, truth, tolerance) = c.param;
        let value = d
            .effects
            .first()
            .and_then(|e| e.params.get(param))
            .copied()
            .unwrap_or_else(|| panic!("{session}: {} has no {param}", c.effect));
        assert!(
            (value - truth).abs() <= tolerance * truth,
            "{session}: {param} {value}, truth {truth}"
        );
    }
}

/// Issue 37's second pair on the look-alike sessions: a sensor lag or a clock offset of
/// [`LOOKALIKE_DELAY_S`], `inconclusive` until the ramps are fast enough.
fn force_pair(case: &str, rerecordings: usize, effect: &str, param: &str) {
    check_lookalike_chain(&Lookalike {
        case,
        pair: ["clock-offset", "sensor-lag"],
        protocol: "faster-ramps",
        rerecordings,
        effect,
        param: (param, LOOKALIKE_DELAY_S, LOOKALIKE_DELAY_TOLERANCE),
    })
}

macro_rules! cases {
    ($($(#[$attr:meta])* $test:ident => $case:literal),* $(,)?) => {
        $(
            #[test]
            $(#[$attr])*
            fn $test() {
                check($case);
            }
        )*
    };
}

cases! {
    clean => "clean",
    stiff_inclusion => "stiff-inclusion",
    strain_stiffening => "strain-stiffening",
    cylinder => "cylinder",
    plasticity_pair => "plasticity-pair",
    gravity_preload_pair => "gravity-preload-pair",
    probe_friction_pair => "probe-friction-pair",
    support_slip_pair => "support-slip-pair",
    viscoelasticity => "viscoelasticity",
    clock_offset => "clock-offset",
    gravity_preload => "gravity-preload",
    support_slip => "support-slip",
    /// Two HGO families φ 0, θ 30°, ratio 8, matrix ν 0.45 (k1 = 0.1 MPa), routed by the in-plane
    /// ellipse signature: 0.1964 → 0.1165 mm on contact/away-from-probe, within 1.25× of clean's
    /// 0.1080; ≈ 50 CPU-s.
    anisotropy => "anisotropy",
    /// Named on the force channel (0.2467 → 0.0691 N held-out; markers 0.1686 → 0.1436 mm, clean
    /// 0.1691); ≈ 35 CPU-s.
    sensor_lag => "sensor-lag",
    #[ignore = "passes (probe-friction, 0.3879 -> 0.3138 mm on contact/under-probe, mu 0.71 rigid tip, within 1.25x the pair's 0.2683 = 0.3354) but 1,250 CPU-s at load 5-11: the 4 frictional rigid-tip replays on the refined mesh (2 of them do not converge), past make test's budget and issue 38's 5 minutes"]
    probe_friction => "probe-friction",
    #[ignore = "verdict plasticity, 0.492 -> 0.185 mm (2.65x lower; the rule needs <= 0.164 or <= 0.109 mm, 1.25x the pair's 0.087; the 1 -> 8 linear-tet replay alone, even at the truth's sigma_y/E 0.09, H/E 0.08, reaches 0.168 mm); 451 CPU-s at load 3-6 (ranked on the fit mesh bisected once, one point replayed refined), more than make test's budget"]
    plasticity => "plasticity",
}

/// Issue 37 pair 2, the sensor lag: standard `inconclusive` → faster ramps name it.
#[test]
fn lookalike_sensor_lag_decided_by_faster_ramps() {
    force_pair("sensor-lag-50ms", 1, "sensor-lag", "tau_s");
}

/// Issue 37 pair 2, the clock offset: standard and faster ramps `inconclusive` → ramps four
/// times as fast name it.
#[test]
fn lookalike_clock_offset_decided_by_faster_ramps_twice() {
    force_pair("clock-offset-50ms", 2, "clock-offset", "offset_s");
}

/// A slow creep's standard recording (`fixtures/thirdparty/lookalikes/<case>`): `none`, neither
/// `plasticity` nor `inconclusive`, with the held force's drift in `hold_drift` (under position
/// control a relaxation beyond 1 %, viscoelasticity signature support +1; under force control
/// none) and not beyond the hold rule (`Signatures::holds_relax`); the tip creeps under the held
/// force (`Signatures::holds_creep`) exactly when `force_control`. Prints its released set against
/// 3σ, the set's persistence, the hold drift and the tip's creep.
fn check_creep_standard(case: &str, hold_drift: std::ops::Range<f64>, force_control: bool) {
    let session = format!("lookalikes/{case}");
    let o = outcome(&session);
    let d = &o.diagnosis;
    let (_, p) = ranked(d, "plasticity").expect("plasticity ranked");
    let s = &p.evidence.signatures;
    println!(
        "LOOKALIKE | {session} | {} | set {:.4} mm (3σ {:.4}), persistence {:?} ± {:?}, hold drift {:.4}, tip creep {:.4} ± {:?}",
        d.verdict,
        1e3 * s.released_set_m,
        3e3 * s.noise_sigma_m,
        s.released_set_persistence,
        s.released_set_persistence_se,
        s.hold_force_drift,
        s.hold_tip_creep,
        s.hold_tip_creep_se
    );
    assert_eq!(d.verdict, "none", "{session}: {:#?}", summary(d));
    assert!(
        hold_drift.contains(&s.hold_force_drift) && !s.holds_relax(),
        "{s:?}"
    );
    assert_eq!(s.holds_creep(), force_control, "{s:?}");
}

/// A slow creep's held force under position control: relaxing by more than 1 % of the peak.
const POSITION_CONTROL_DRIFT: std::ops::Range<f64> = -1.0..-0.01;

/// A slow creep re-recorded under the planner's `longer-holds`: the verdict is `effect`, and
/// plasticity is ruled out by the relaxing holds (`Hypothesis::ruled_out`) however its set
/// persists.
fn check_creep_longer_holds(case: &str, effect: &str) {
    let session = format!("lookalikes/{case}");
    let o = outcome(&session);
    let d = &o.diagnosis;
    println!("LOOKALIKE | {session} | {} | {:#?}", d.verdict, summary(d));
    assert_eq!(d.verdict, effect, "{session}: {:#?}", summary(d));
    let (_, p) = ranked(d, "plasticity").expect("plasticity ranked");
    assert!(
        p.evidence
            .confirmation_failed
            .as_deref()
            .is_some_and(|w| w.starts_with("ruled out")),
        "{session}: {:?}",
        p.evidence.confirmation_failed
    );
}

/// Issue 37 pair 1 on this rig, slow creep g 2, τ 30 s (`…/slow-creep-30s`): its released set
/// (0.120 mm) is below 3σ (0.144 mm), so plasticity is contradicted (support −1), and the
/// linearised creep screen stays below the 30 % gain (0.109). A look-alike must not rank below the
/// verdict by its signatures, and the relaxing holds give viscoelasticity +1, so plasticity could
/// only be its look-alike with a set above 3σ that persists within 2 SE of permanent (the
/// fixtures' README, "Pair 1"). ≈ 5 CPU-s.
#[test]
fn lookalike_slow_creep_standard_is_none() {
    check_creep_standard("slow-creep-30s", POSITION_CONTROL_DRIFT, false);
}

/// The same creep under `longer-holds`: its set persists as a plastic one would (0.954 ± 0.028)
/// and the linearised plasticity screen qualifies (0.604), but the held force relaxes by
/// 0.0508 ± 0.0081 of the peak, which rules plasticity out: not the wrong `plasticity` of main
/// before that rule, but `none` — viscoelasticity's force-driven Prony re-simulation stays below
/// the 30 % gain, 0.1762 → 0.1571 mm (the fixtures' README, "Pair 1"). ≈ 93 CPU-s: the 15 Prony
/// re-simulations of 367 frames.
#[test]
fn lookalike_slow_creep_longer_holds_rules_out_plasticity() {
    check_creep_longer_holds("slow-creep-30s-longer-holds", "none");
}

/// Slow creep g 4, τ 23 s (`…/slow-creep-g4-tau23s`): set 0.143 mm at 3σ, persistence
/// 1.000 ± 0.036, hold drift −0.0271: `none` (plasticity's released cells 0.149 mm are below the
/// focus rule's 2√3σ). ≈ 5 CPU-s.
#[test]
fn lookalike_slow_creep_g4_standard_is_none() {
    check_creep_standard("slow-creep-g4-tau23s", POSITION_CONTROL_DRIFT, false);
}

/// The g 4, τ 23 s creep under `longer-holds`: its set persists as a plastic one (1.015 ± 0.021)
/// and the plasticity screen qualifies (0.729), but the holds relax (−0.0794 ± 0.0068): plasticity
/// is ruled out and `viscoelasticity` named, 0.2075 → 0.1482 mm (Prony g 0.90, τ 11.8 s with the
/// compliance scale 1.74, the template grid's longest τ around the screen's centre — whose creep
/// time sits at the top of its grid, 9.49 s — not the truth's g 4, τ 23 s). ≈ 87 CPU-s.
#[test]
fn lookalike_slow_creep_g4_named_under_longer_holds() {
    check_creep_longer_holds("slow-creep-g4-tau23s-longer-holds", "viscoelasticity");
}

/// Issue 37 pair 1 under force control, the creep side (`…/slow-creep-g4-tau23s-force`: the g 4,
/// τ 23 s creep held at its position-controlled twin's peak forces, the disk a solid with a side
/// wall; the tip sinks 53–80 µm over each 1.2 s hold): the held force does not drift (0.0002 ±
/// 0.0011 of the peak), the set (0.145 mm) is below plasticity's focus rule (2√3σ, 0.160 mm) and
/// persists (0.929 ± 0.038), the tip creeps under the held force (0.049 ± 0.011 of its depth: plasticity
/// ruled out), the linearised creep screen gains 0.152 (0.1792 → 0.1650 mm, τ at its grid's top):
/// `none`, as under position control — not its look-alike `plasticity` (the fixtures' README, "Pair 1
/// under force control"). ≈ 6 CPU-s.
#[test]
fn lookalike_slow_creep_g4_force_is_none() {
    check_creep_standard("slow-creep-g4-tau23s-force", -0.01..0.01, true);
}

/// The force-controlled creep re-recorded under `longer-holds` (`…/slow-creep-g4-tau23s-force-longer-holds`:
/// the tip sinks 154–235 µm over each 3.6 s hold at a held force): under force control the holds
/// do not relax (−0.0013 ± 0.0011) and the set persists (1.038 ± 0.020), but the tip creeps under
/// the held force, 0.109 ± 0.009 of its depth (`Signatures::holds_creep`), which rules plasticity
/// out as its position-controlled twin's relaxing holds do; `viscoelasticity` is named, 0.2231 →
/// 0.1541 mm (Prony g 1.35, τ 11.3 s, compliance scale 1.82). Ignored: ≈ 125 CPU-s (15 Prony
/// re-simulations of 367 frames), past `make test`'s budget.
#[test]
#[ignore = "passes (viscoelasticity, 0.2231 -> 0.1541 mm; plasticity ruled out by the tip creeping 0.109 +- 0.009 under the held force) but ≈ 125 CPU-s"]
fn lookalike_slow_creep_g4_force_named_under_longer_holds() {
    check_creep_longer_holds("slow-creep-g4-tau23s-force-longer-holds", "viscoelasticity");
}

/// The creep rule of force control must not rule out a rate-independent set (`…/plastic-force`,
/// the FElupe J2 body held at its peak forces): its tip does not creep under the held force
/// (0.0027 ± 0.0092 of its depth; `Signatures::holds_creep` false), its holds do not relax, and
/// plasticity is not ruled out but leads the screen (the signatures and the linearised screen
/// alone: `confirm_with_resimulation = false`; the re-simulated verdict is the ignored test
/// below). ≈ 10 CPU-s.
#[test]
fn lookalike_plastic_force_is_not_ruled_out() {
    let session = "lookalikes/plastic-force";
    let o = chain_with(
        session,
        DiagnoseSettings {
            confirm_with_resimulation: false,
            ..DiagnoseSettings::default()
        },
    );
    let d = &o.diagnosis;
    let (rank, p) = ranked(d, "plasticity").expect("plasticity ranked");
    let s = &p.evidence.signatures;
    println!(
        "LOOKALIKE | {session} | screen only: {} | plasticity rank {rank}, tip creep {:.4} ± {:?}, hold drift {:.4}",
        d.verdict, s.hold_tip_creep, s.hold_tip_creep_se, s.hold_force_drift
    );
    assert!(!s.holds_creep() && !s.holds_relax(), "{s:?}");
    assert!(
        p.evidence.confirmation_failed.is_none(),
        "{:?}",
        p.evidence.confirmation_failed
    );
    assert_eq!(
        (d.verdict.as_str(), rank),
        ("plasticity", 1),
        "{:#?}",
        summary(d)
    );
}

/// Issue 37 pair 1 under force control, the plastic side (`…/plastic-force`: J2 σ_y 4.5 kPa,
/// H 4 kPa, E 50 kPa, the probe held at the plasticity case's peak forces): `plasticity` at once,
/// 0.5006 → 0.1906 mm (σ_y 2.04 kPa, H 1.36 kPa on the homogeneous fit's E 23.4 kPa). Ignored:
/// ≈ 510 CPU-s. Generated with the vertical punch's nodal active set (before the walled disk of
/// its look-alike above, on which the J2 body's first unloading frame does not converge).
#[test]
#[ignore]
fn lookalike_plastic_force_named_plasticity() {
    let session = "lookalikes/plastic-force";
    let o = outcome(session);
    let d = &o.diagnosis;
    println!("LOOKALIKE | {session} | {} | {:#?}", d.verdict, summary(d));
    assert_eq!(d.verdict, "plasticity", "{session}: {:#?}", summary(d));
    let (_, p) = ranked(d, "plasticity").expect("plasticity ranked");
    assert!(
        p.heldout_rmse_after_m < 0.5 * p.heldout_rmse_before_m,
        "{session}: {} -> {} m",
        p.heldout_rmse_before_m,
        p.heldout_rmse_after_m
    );
}
