//! Issue 37's look-alike pairs on the third-party truth (`fixtures/thirdparty/lookalikes/`, made by
//! `scripts/diagnose_thirdparty_sessions.py` with the suite's FElupe code; its README has every
//! run): the chain a user runs (`thirdparty/mod.rs`, as `thirdparty_diagnose.rs`) on each session.
//!
//! The `lookalike_*_decided_by_*` tests follow the planner on the second pair (a sensor lag and a
//! clock offset of 50 ms on the clean case's FElupe solution): the standard recording is
//! `inconclusive` between the two and asks for a re-recording (`Diagnosis::next_experiment`);
//! the test diagnoses the session recorded under that protocol, until the verdict names the
//! effect with its delay within [`LOOKALIKE_DELAY_TOLERANCE`] of the truth's. The
//! `lookalike_slow_creep_*` and `lookalike_plastic_*` tests hold the first pair (slow creep against
//! plasticity) under position and force control; `lookalike_short_creep_*` and
//! `lookalike_late_clock_*` a third (a 0.3 s creep against a clock running late).

mod common;
mod thirdparty;

use softcap_diagnose::DiagnoseSettings;
use thirdparty::{chain_with, outcome, ranked, summary};

/// The look-alike sessions' delay (sensor-lag τ, clock offset), s: `truth/case.toml` of
/// `fixtures/thirdparty/lookalikes/*-50ms*`.
const LOOKALIKE_DELAY_S: f64 = 0.05;

/// How far the named effect's fitted delay may be from [`LOOKALIKE_DELAY_S`], relative: a tenth,
/// 5 ms, a twentieth of the sessions' 100 ms frame period (measured: 47.6 and 53.1 ms).
const LOOKALIKE_DELAY_TOLERANCE: f64 = 0.1;

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
        if let Some(n) = &d.next_experiment {
            let each: Vec<String> = n
                .protocols
                .iter()
                .map(|p| format!("{} {:.4} mm", p.protocol, 1e3 * p.predicted_difference_m))
                .collect();
            println!(
                "LOOKALIKE | {session} | predicted differences {each:?}, recorded {:.4} mm",
                1e3 * n.recorded_difference_m
            );
        }
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
            (value - truth).abs() <= tolerance * truth.abs(),
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

/// Issue 37's third pair on this rig: a short creep (`…/creep-g0.6-tau0.3s`: one 0.3 s Maxwell
/// branch μ₁ = 0.6 μ on the clean material) leads the force as a clock running late would; its
/// marker screen stays below the naming rule, so the force channel alone named `clock-offset`
/// (−0.07 s). The held force relaxes by 8 % of the peak (viscoelasticity support +1, the offset
/// 0) and the re-simulated Prony model explains the markers beyond the fold spread, no worse than
/// the offset (`marker_rivals`): `inconclusive` between the two. The planner, comparing the two
/// net of a stiffness refit, asks for `faster-ramps`, and the creep recorded so
/// (`…-faster-ramps`) is named `viscoelasticity` with τ within a tenth of the truth's (the
/// fixtures' README, pair 3). ≈ 180 CPU-s.
#[test]
fn lookalike_short_creep_decided_by_faster_ramps() {
    check_lookalike_chain(&Lookalike {
        case: "creep-g0.6-tau0.3s",
        pair: SHORT_CREEP_PAIR,
        protocol: "faster-ramps",
        rerecordings: 1,
        effect: "viscoelasticity",
        param: ("prony_tau_s", 0.3, 0.1),
    });
}

/// The candidates of pair 3's `inconclusive` recordings.
const SHORT_CREEP_PAIR: [&str; 2] = ["clock-offset", "viscoelasticity"];

/// Its look-alike's truth, a clock running 80 ms late (`…/clock-offset-m80ms`, the clean case's
/// solution, the force read 80 ms after the frame): named `clock-offset` at once, −0.08 s. ≈ 45
/// CPU-s.
#[test]
fn lookalike_late_clock_is_named() {
    late_clock("clock-offset-m80ms");
}

/// The late clock recorded under the protocol the planner asks for on the creep
/// (`…/clock-offset-m80ms-faster-ramps`): `clock-offset` −0.08 s again, so that recording
/// separates the pair both ways. ≈ 95 CPU-s.
#[test]
fn lookalike_late_clock_faster_ramps_is_named() {
    late_clock("clock-offset-m80ms-faster-ramps");
}

/// Pair 3's clock-offset truth (−80 ms) named at once from `fixtures/thirdparty/lookalikes/<case>`.
fn late_clock(case: &str) {
    check_lookalike_chain(&Lookalike {
        case,
        pair: SHORT_CREEP_PAIR,
        protocol: "faster-ramps",
        rerecordings: 0,
        effect: "clock-offset",
        param: ("offset_s", -0.08, LOOKALIKE_DELAY_TOLERANCE),
    });
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
/// 0.5006 → 0.1251 mm (rigid tip on 10-node tets: σ_y 2.73 kPa, H 1.36 kPa, ν 0.45 on the
/// homogeneous fit's E 23.4 kPa). Ignored: ≈ 260 CPU-s single-threaded. Generated with the vertical punch's nodal active set (before the walled disk of
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
