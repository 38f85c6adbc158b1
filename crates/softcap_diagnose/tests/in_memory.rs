//! Diagnosis of small in-memory recordings built with softcap_fem directly: a 4 × 4 × 2 cm block
//! (648 tets, E = 20 kPa, ν = 0.45) on a fixed support, 25 + 8 surface markers, four probe
//! locations (ramp 5 / hold 5 / unload 4 / released 3 frames at 20 fps), marker noise σ = 5 µm.
//! The "recording" is the model's own simulation with ONE effect switched on in the data (or two,
//! from different families: [`session_with`]); the model the diagnosis runs is the default one.
//! Each case asserts the verdict and that the held-out error drops at least 3× (effects) or that
//! the answer is `none` (controls).

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use softcap_diagnose::protocols::Protocol;
use softcap_diagnose::signal::low_pass;
use softcap_diagnose::{
    DiagnoseSettings, Extension, FemProbeSimulator, FemSimSettings, Frame, ProbeLoad,
    ProbeSimulator, Recording, SegmentSettings, Segmentation, SequenceFrame, SimLoad, SupportPlane,
    diagnose, surface_normals,
};
use softcap_fem::{CorotationalModel, LinearParams};
use softcap_mesh::TetMesh;

const SIZE: [f64; 3] = [0.04, 0.04, 0.02];
const DT: f64 = 0.05;
const PEAK_N: f64 = 0.25;

fn mesh() -> TetMesh {
    softcap_mesh::box_tet_mesh([0.0; 3], SIZE, [6, 6, 3])
}

fn markers() -> Vec<Vector3<f64>> {
    let mut m = Vec::new();
    for i in 0..5 {
        for j in 0..5 {
            m.push(Vector3::new(
                0.004 + 0.008 * i as f64,
                0.004 + 0.008 * j as f64,
                SIZE[2],
            ));
        }
    }
    // side markers: mid-height and on the support (attached)
    for &x in &[0.01, 0.03] {
        m.push(Vector3::new(x, 0.0, 0.01));
        m.push(Vector3::new(x, SIZE[1], 0.01));
        m.push(Vector3::new(x, 0.0, 0.0));
        m.push(Vector3::new(x, SIZE[1], 0.0));
    }
    m
}

fn simulator(young_pa: f64) -> FemProbeSimulator {
    let mesh = mesh();
    let model = CorotationalModel::homogeneous(
        &mesh,
        LinearParams::from_young_poisson(young_pa, 0.45).unwrap(),
    )
    .unwrap();
    let fixed = FemProbeSimulator::nodes_on_plane(&mesh, &Vector3::z(), 0.0, 1e-9);
    FemProbeSimulator::new(&mesh, model, &fixed, &markers(), FemSimSettings::default())
        .unwrap()
        .with_support_plane(&Vector3::z(), 0.0)
}

/// The force profile of one location (fraction of peak) and its phases.
const PROFILE: [f64; 17] = [
    0.2, 0.4, 0.6, 0.8, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.75, 0.5, 0.25, 0.0, 0.0, 0.0, 0.0,
];

/// What the data contain besides the default model.
#[derive(Clone, Copy)]
enum Effect {
    Clean,
    SensorLag(f64),
    ClockOffset(f64),
    Creep {
        g: f64,
        tau_s: f64,
    },
    Gravity(f64),
    Friction(f64),
    /// Total tangential support stiffness, N/m (`Extension::SupportSprings`).
    SupportSlip(f64),
    /// J2 plasticity (`Extension::Plastic`).
    Plastic {
        yield_pa: f64,
        hardening_pa: f64,
    },
    Stiffer(f64),
    /// Transversely isotropic stiffening along the fibre [0.707, 0, 0.707], fibre / transverse
    /// Young's modulus (`Extension::Anisotropic`).
    Anisotropic(f64),
    /// Stiffness-proportional Rayleigh damping β, s, without mass (`Extension::Dynamic` at
    /// ρ 10⁻³ kg/m³): a Kelvin–Voigt solid, the response a first-order lag of the quasi-static one.
    /// Only the harness (`examples/in_memory.rs`, `lookalike-spec "damping β"`) records it.
    #[cfg_attr(test, allow(dead_code))]
    Damping(f64),
}

struct Session {
    rec: Recording,
}

fn session(effect: Effect, oblique: bool) -> Session {
    session_at(effect, oblique, &LOCATIONS)
}

fn session_at(effect: Effect, oblique: bool, xy: &[(f64, f64)]) -> Session {
    session_with(&[effect], oblique, xy, 8)
}

/// The four probe locations of [`session`].
const LOCATIONS: [(f64, f64); 4] = [
    (0.012, 0.012),
    (0.028, 0.012),
    (0.012, 0.028),
    (0.028, 0.028),
];

/// A session with every effect of `effects` in the data (at most one history-dependent truth:
/// creep, plasticity, support springs or anisotropy; any force-channel, friction, gravity and
/// stiffness effects besides), marker noise seeded with `seed`.
fn session_with(effects: &[Effect], oblique: bool, xy: &[(f64, f64)], seed: u64) -> Session {
    session_planned(effects, oblique, xy, seed, None)
}

/// [`session_with`] recorded under `protocol` (the library's re-planned probe program of the
/// standard one, `softcap_diagnose::protocols::Protocol::apply`, applied to the true force).
fn session_planned(
    effects: &[Effect],
    oblique: bool,
    xy: &[(f64, f64)],
    seed: u64,
    protocol: Option<Protocol>,
) -> Session {
    let stiffer = effects.iter().find_map(|e| match e {
        Effect::Stiffer(s) => Some(*s),
        _ => None,
    });
    let mut truth_sim = simulator(20e3 * stiffer.unwrap_or(1.0));
    let locs: Vec<Vector3<f64>> = xy
        .iter()
        .map(|&(x, y)| Vector3::new(x, y, SIZE[2]))
        .collect();
    let axis = if oblique {
        Vector3::new(0.35, 0.0, -1.0).normalize()
    } else {
        -Vector3::z()
    };
    // frames: 2 rest, then the four locations
    let mut t = Vec::new();
    let mut tip = Vec::new();
    let mut f_true = Vec::new();
    let mut loc_of = Vec::new();
    for _ in 0..2 {
        t.push(t.len() as f64 * DT);
        tip.push(locs[0] + Vector3::z() * 0.005);
        f_true.push(Vector3::zeros());
        loc_of.push(None);
    }
    for (l, c) in locs.iter().enumerate() {
        for &p in &PROFILE {
            t.push(t.len() as f64 * DT);
            let depth = 0.002 * p;
            let travel = if oblique {
                Vector3::x() * 0.8 * depth
            } else {
                Vector3::zeros()
            };
            tip.push(if p > 0.0 {
                c - Vector3::z() * depth + travel
            } else {
                c + Vector3::z() * 0.003
            });
            f_true.push(axis * (PEAK_N * p));
            loc_of.push(Some(l));
        }
    }
    let mut axes = vec![axis; t.len()];
    if let Some(protocol) = protocol {
        let program: Vec<Frame> = (0..t.len())
            .map(|k| Frame {
                frame: k as u64,
                time_s: t[k],
                tip_m: tip[k],
                axis,
                force_n: f_true[k],
                markers_m: vec![None; markers().len()],
            })
            .collect();
        let rec = recording(program);
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        let planned = protocol.apply(&rec, &seg);
        t = planned.frames.iter().map(|f| f.time_s).collect();
        tip = planned.frames.iter().map(|f| f.tip_m).collect();
        f_true = planned.frames.iter().map(|f| f.force_n).collect();
        axes = planned.frames.iter().map(|f| f.axis).collect();
    }
    let n = t.len();
    // measured force
    let mut f_meas = f_true.clone();
    for e in effects {
        f_meas = match *e {
            Effect::SensorLag(tau) => low_pass(&t, &f_meas, tau),
            Effect::ClockOffset(d) => (0..n)
                .map(|k| softcap_diagnose::signal::sample(&t, &f_meas, t[k] - d))
                .collect(),
            _ => f_meas,
        };
    }
    // force that deforms the object
    let mut f_obj = f_true.clone();
    let mut body = Vector3::zeros();
    for e in effects {
        match *e {
            Effect::Friction(mu) => {
                for k in 0..n {
                    f_obj[k] += Vector3::x() * (mu * f_true[k].norm());
                }
            }
            Effect::Gravity(rho) => body = Vector3::new(0.0, 0.0, -9.81 * rho),
            _ => {}
        }
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 5e-6).unwrap();
    let rest_truth = truth_sim
        .simulate(&SimLoad::default(), false)
        .unwrap()
        .markers_m;
    // History-dependent truths: the extended FEM models (Prony creep, J2 plasticity, support
    // springs) over the whole sequence.
    let ext = effects.iter().find_map(|e| match *e {
        Effect::Creep { g, tau_s } => Some(Extension::Viscoelastic { g, tau_s }),
        Effect::Plastic {
            yield_pa,
            hardening_pa,
        } => Some(Extension::Plastic {
            yield_stress_pa: yield_pa,
            hardening_pa,
        }),
        Effect::SupportSlip(k) => Some(Extension::SupportSprings {
            stiffness_n_per_m: k,
        }),
        Effect::Anisotropic(ratio) => Some(Extension::Anisotropic {
            fibre: Vector3::new(1.0, 0.0, 1.0).normalize(),
            ratio,
        }),
        Effect::Damping(beta_s) => Some(Extension::Dynamic {
            density_kg_m3: 1e-3,
            alpha_per_s: 0.0,
            beta_s,
            lame_ratio_factor: 1.0,
        }),
        _ => None,
    });
    let loads: Vec<SimLoad> = (0..n)
        .map(|k| SimLoad {
            probe: (f_obj[k].norm() > 0.0).then_some(ProbeLoad {
                tip_m: tip[k],
                axis: axes[k],
                force_n: f_obj[k],
            }),
            body_force_n_m3: body,
        })
        .collect();
    let sequence = ext.map(|e| {
        let frames: Vec<SequenceFrame> = (0..n)
            .map(|k| SequenceFrame {
                time_s: t[k],
                load: loads[k],
            })
            .collect();
        truth_sim.simulate_sequence(&e, &frames).unwrap()
    });
    let _ = rest_truth;
    let mut frames = Vec::with_capacity(n);
    for k in 0..n {
        let x = match &sequence {
            Some(seq) => seq[k].clone(),
            None => truth_sim.simulate(&loads[k], false).unwrap().markers_m,
        };
        let markers_m = x
            .iter()
            .map(|p| Some(p + Vector3::from_fn(|_, _| noise.sample(&mut rng))))
            .collect();
        frames.push(Frame {
            frame: k as u64,
            time_s: t[k],
            tip_m: tip[k],
            axis: axes[k],
            force_n: f_meas[k],
            markers_m,
        });
    }
    Session {
        rec: recording(frames),
    }
}

/// The block's recording of `frames`.
fn recording(frames: Vec<Frame>) -> Recording {
    let mesh = mesh();
    let rest = markers();
    Recording {
        marker_ids: (0..rest.len()).map(|i| format!("m{i}")).collect(),
        normals: surface_normals(&mesh, &rest),
        rest_markers_m: rest,
        gravity_m_s2: Vector3::new(0.0, 0.0, -9.81),
        support: Some(SupportPlane {
            normal: Vector3::z(),
            offset_m: 0.0,
            tolerance_m: 1e-6,
        }),
        tip_radius_m: 0.002,
        frames,
    }
}

fn run(effect: Effect, oblique: bool, expect: &str) {
    let s = session(effect, oblique);
    let mut sim = simulator(20e3);
    let run = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default()).unwrap();
    let d = &run.diagnosis;
    if let Some(dir) = std::env::var_os("SOFTCAP_IN_MEMORY_JSON").map(std::path::PathBuf::from) {
        // the whole diagnosis of the case, to compare runs (`SOFTCAP_IN_MEMORY_JSON=DIR`)
        std::fs::create_dir_all(&dir).unwrap();
        let name = std::thread::current()
            .name()
            .unwrap_or("case")
            .replace("::", "-");
        softcap_diagnose::write_json(&dir.join(format!("{name}.json")), d).unwrap();
    }
    for r in &d.ranked {
        eprintln!(
            "{:>16} score {:+.3} before {:.3e} after {:.3e} params {:?}",
            r.hypothesis, r.score, r.heldout_rmse_before_m, r.heldout_rmse_after_m, r.params
        );
    }
    eprintln!("signatures {:?}", run.signatures);
    eprintln!("located top {:?}", &d.located[..3.min(d.located.len())]);
    assert_eq!(d.verdict, expect);
    let top = &d.ranked[0];
    assert_eq!(top.hypothesis, expect);
    if expect != "none" {
        assert!(
            top.heldout_rmse_after_m * 3.0 <= top.heldout_rmse_before_m,
            "held-out {} → {}",
            top.heldout_rmse_before_m,
            top.heldout_rmse_after_m
        );
    }
    assert_eq!(d.ranked.len(), 10, "every catalog name and none are ranked");
    let names: std::collections::BTreeSet<&str> =
        d.ranked.iter().map(|r| r.hypothesis.as_str()).collect();
    assert_eq!(names.len(), 10);
}

/// Diagnoses a session with `effects` and asserts that exactly the effects `expect` are named
/// (in any order), each with the joint model's held-out error on its cells below the effects
/// without it and below the effect alone, and the verdict among them.
fn run_pair(effects: &[Effect], oblique: bool, expect: [&str; 2]) {
    let s = session_with(effects, oblique, &LOCATIONS, 8);
    let mut sim = simulator(20e3);
    let run = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default()).unwrap();
    let d = &run.diagnosis;
    for e in &d.effects {
        eprintln!(
            "{:>16} conf {:.3} before {:.4} without {:.4} alone {:.4} joint {:.4} mm gains {:?} {:?}",
            e.hypothesis,
            e.confidence,
            1e3 * e.heldout_rmse_before_m,
            1e3 * e.heldout_rmse_without_m,
            1e3 * e.heldout_rmse_single_m,
            1e3 * e.heldout_rmse_after_m,
            e.fold_gains,
            e.params
        );
    }
    for r in d.ranked.iter().take(5) {
        eprintln!(
            "{:>16} score {:+.3} before {:.3e} after {:.3e}",
            r.hypothesis, r.score, r.heldout_rmse_before_m, r.heldout_rmse_after_m
        );
    }
    let mut named: Vec<&str> = d.effects.iter().map(|e| e.hypothesis.as_str()).collect();
    named.sort();
    let mut want = expect.to_vec();
    want.sort();
    assert_eq!(named, want, "verdict {}", d.verdict);
    assert_eq!(d.verdict, d.effects[0].hypothesis);
    let second = &d.effects[1];
    assert!(second.heldout_rmse_after_m < second.heldout_rmse_without_m);
    assert!(second.heldout_rmse_after_m < second.heldout_rmse_single_m);
}

#[test]
fn support_slip_and_sensor_lag_are_both_named() {
    run_pair(
        &[Effect::SupportSlip(500.0), Effect::SensorLag(0.12)],
        true,
        ["support-slip", "sensor-lag"],
    );
}

#[test]
fn anisotropy_and_gravity_are_both_named() {
    run_pair(
        &[Effect::Anisotropic(5.0), Effect::Gravity(1000.0)],
        false,
        ["anisotropy", "gravity-preload"],
    );
}

/// A pair whose second effect has fold gains as large as the first's (inconclusive while the
/// look-alike check ran before forward selection): tangential support springs and a 0.1 s clock
/// offset on the oblique path.
#[test]
fn support_slip_and_clock_offset_are_both_named() {
    run_pair(
        &[Effect::SupportSlip(500.0), Effect::ClockOffset(0.1)],
        true,
        ["support-slip", "clock-offset"],
    );
}

/// The fourth pair: Coulomb probe friction μ 0.5 on the oblique path and a 0.1 s clock offset
/// (the frictional rigid-tip replays of its confirmation are most of its cost: with the three
/// look-alike tests below, 78 CPU-s together in the test profile).
#[test]
fn probe_friction_and_clock_offset_are_both_named() {
    run_pair(
        &[Effect::Friction(0.5), Effect::ClockOffset(0.1)],
        true,
        ["probe-friction", "clock-offset"],
    );
}

/// One look-alike chain of issue 37: the truth `a` recorded under the standard protocol (noise
/// seed 100), its diagnosis; when that names a next experiment, `a` re-recorded under it (seed
/// 101) and the other candidate's truth `b` recorded under it too (seed 102), each diagnosed.
struct LookalikeChain {
    first: softcap_diagnose::Diagnosis,
    next: Option<(
        Protocol,
        softcap_diagnose::Diagnosis,
        softcap_diagnose::Diagnosis,
    )>,
}

/// Which of the block's markers the cameras see.
#[derive(Clone, Copy, PartialEq)]
enum View {
    /// All 33: the top grid, the side markers at mid-height and those on the support.
    All,
    /// Only the 25 on the top surface (a camera above the block); the side markers unobserved
    /// in every frame.
    Top,
}

impl View {
    /// `rec` as this view observes it.
    fn observe(self, mut rec: Recording) -> Recording {
        if self == View::Top {
            let hidden: Vec<bool> = rec
                .rest_markers_m
                .iter()
                .map(|m| m.z < SIZE[2] - 1e-9)
                .collect();
            for f in &mut rec.frames {
                for (m, x) in f.markers_m.iter_mut().enumerate() {
                    if hidden[m] {
                        *x = None;
                    }
                }
            }
        }
        rec
    }
}

fn lookalike_chain(
    a: &[Effect],
    b: &[Effect],
    oblique: bool,
    xy: &[(f64, f64)],
    view: View,
) -> LookalikeChain {
    let mut sim = simulator(20e3);
    let settings = DiagnoseSettings::default();
    let rec = view.observe(session_with(a, oblique, xy, 100).rec);
    let first = diagnose(&rec, &mut sim, &settings).unwrap().diagnosis;
    let next = first.next_experiment.as_ref().map(|n| {
        let protocol = Protocol::ALL
            .into_iter()
            .find(|p| p.name() == n.protocol)
            .unwrap();
        let mut again = |truth: &[Effect], seed: u64| {
            let s = session_planned(truth, oblique, xy, seed, Some(protocol));
            diagnose(&view.observe(s.rec), &mut sim, &settings)
                .unwrap()
                .diagnosis
        };
        (protocol, again(a, 101), again(b, 102))
    });
    LookalikeChain { first, next }
}

/// The plastic truth of the look-alike pairs: J2, σ_y 2 kPa, H 1 kPa.
const LOOKALIKE_PLASTIC: Effect = Effect::Plastic {
    yield_pa: 2000.0,
    hardening_pa: 1000.0,
};

/// A Prony branch g, τ whose instantaneous modulus is the model's: G∞ = 20 kPa / (1 + g).
fn slow_creep(g: f64, tau_s: f64) -> Vec<Effect> {
    vec![Effect::Stiffer(1.0 / (1.0 + g)), Effect::Creep { g, tau_s }]
}

/// Issue 37's first look-alike pair decided by re-recording: slow creep g 1, τ 5 s (recovery
/// time τ(1 + g) = 10 s over gaps of ≈ 0.85 s: the released set persists 0.91 over them, as a
/// permanent one would) against J2 plasticity. Under the standard protocol neither outexplains
/// the other beyond the fold-to-fold spread: `inconclusive` with both as candidates, and the
/// next experiment is `longer-holds` (the creep keeps creeping under the tripled holds, a
/// plastic set does not), predicted to separate them more than the recorded protocol does.
/// Re-recorded under it, the creep truth is named `viscoelasticity` and the plastic truth
/// `plasticity`. With `plasticity::PERMANENT_PERSISTENCE` at 0.9 the first protocol named
/// the creep `plasticity`. ≈ 54 CPU-s (three diagnoses with Prony re-simulations; ≈ 220 before
/// plasticity's rigid-tip points were ranked on the fit mesh bisected once):
/// `cargo test --workspace --test diagnose_tests -- in_memory::slow_creep_and_plasticity_decided_by_longer_holds`.
#[test]
fn slow_creep_and_plasticity_decided_by_longer_holds() {
    let chain = lookalike_chain(
        &slow_creep(1.0, 5.0),
        &[LOOKALIKE_PLASTIC],
        false,
        &LOCATIONS,
        View::All,
    );
    let d = &chain.first;
    eprintln!("first protocol: {}", d.verdict);
    print_ranked(d);
    if let Some((p, creep, plastic)) = &chain.next {
        for (what, r) in [("creep truth", creep), ("plastic truth", plastic)] {
            eprintln!("{what} re-recorded under {}: {}", p.name(), r.verdict);
            print_ranked(r);
        }
    }
    let persistence = d.ranked[0].evidence.signatures.released_set_persistence;
    assert!(
        persistence.is_some_and(|p| (0.9..1.0).contains(&p)),
        "{persistence:?}"
    );
    assert_decided_by_re_recording(
        &chain,
        ["plasticity", "viscoelasticity"],
        "longer-holds",
        2.0,
        ["viscoelasticity", "plasticity"],
    );
}

/// A look-alike chain decided by re-recording: the first protocol `inconclusive` with
/// `candidates` (sorted), `protocol` suggested with a predicted difference above `min_ratio` ×
/// the recorded one, and the truths A and B re-recorded under it named `verdicts`.
fn assert_decided_by_re_recording(
    chain: &LookalikeChain,
    candidates: [&str; 2],
    protocol: &str,
    min_ratio: f64,
    verdicts: [&str; 2],
) {
    let d = &chain.first;
    assert_eq!(d.verdict, "inconclusive", "{:?}", d.effects);
    let mut cands: Vec<&str> = d.candidates.iter().map(|c| c.hypothesis.as_str()).collect();
    cands.sort();
    assert_eq!(cands, candidates);
    let next = d.next_experiment.as_ref().unwrap();
    assert_eq!(next.protocol, protocol);
    assert!(
        next.predicted_difference_m > min_ratio * next.recorded_difference_m,
        "{next:?}"
    );
    let (planned, a, b) = chain.next.as_ref().unwrap();
    assert_eq!(planned.name(), protocol);
    assert_eq!(a.verdict, verdicts[0], "{:?}", a.candidates);
    assert_eq!(b.verdict, verdicts[1], "{:?}", b.candidates);
}

/// Issue 37's second look-alike pair decided by re-recording: a first-order sensor lag τ 12 ms
/// against a clock offset δ 12 ms, on 50 ms frames. A lag that short has finished growing its
/// delay within the ramp's first tenth, so both read the same samples (hold drift 0.048, delays
/// 6.5 / 8.2 ms against 6.6 / 8.2 ms): the screens' first-order terms τ ḟ and δ ḟ are one field,
/// the delay growth (1.7 ± 0.8 ms) is within two standard errors of both a shift's and a lag's
/// (3.0 ms each, measured as the data are): `inconclusive` with both. The planner simulates each
/// under its confirmation's force model (the inverse FSR chain, the shifted force): the ramps
/// twice as fast, sampled at 25 ms, separate them most. Re-recorded so, the lag's delay grows
/// (1.8 ± 0.4 ms; a shift's 0.9, a lag's 2.0) and it is named `sensor-lag`; the offset's does
/// not (−0.8 ± 0.45 ms) and it is named `clock-offset`. Before (main 5cbccc21) the first
/// protocol named both `sensor-lag`. ≈ 25 CPU-s:
/// `cargo test --workspace --test diagnose_tests -- in_memory::sensor_lag_and_clock_offset_decided_by_faster_ramps`.
#[test]
fn sensor_lag_and_clock_offset_decided_by_faster_ramps() {
    let chain = lookalike_chain(
        &[Effect::SensorLag(0.012)],
        &[Effect::ClockOffset(0.012)],
        false,
        &LOCATIONS,
        View::All,
    );
    print_ranked(&chain.first);
    if let Some((_, lag, offset)) = &chain.next {
        print_ranked(lag);
        print_ranked(offset);
    }
    assert_decided_by_re_recording(
        &chain,
        ["clock-offset", "sensor-lag"],
        "faster-ramps",
        1.5,
        ["sensor-lag", "clock-offset"],
    );
}

/// Support slip seen by a camera above the block only ([`View::Top`]: no marker on or near the
/// support observed): tangential support springs 700 N/m on the oblique path (noise seed 100, the
/// standard protocol of the look-alike chains). The whole block's translation along the push
/// still moves every top marker beyond the contact radius (`far_field_push`), so support slip
/// keeps its signature without the attached markers and is named, not its look-alike probe
/// friction (whose tip traction drags the markers around the contact only): the top view does
/// not make the two look alike. ≈ 8 CPU-s.
#[test]
fn support_slip_seen_from_above_is_named() {
    let rec =
        View::Top.observe(session_with(&[Effect::SupportSlip(700.0)], true, &LOCATIONS, 100).rec);
    let mut sim = simulator(20e3);
    let d = diagnose(&rec, &mut sim, &DiagnoseSettings::default())
        .unwrap()
        .diagnosis;
    print_ranked(&d);
    let s = &d.ranked[0].evidence.signatures;
    assert_eq!(s.attached_motion_m, 0.0, "no support marker is observed");
    assert!(s.far_field_push_m > 3.0 * s.three_sigma_m(), "{s:?}");
    assert_eq!(d.verdict, "support-slip", "{:?}", d.candidates);
    first_effect_three_fold(&d);
}

/// Support springs of 1500 N/m, the calibration's middle strength (noise seed 101): stiffer than
/// the block's own shear stiffness, so the base slips more under the load than away from it and
/// the screen's rigid translation does not qualify. The far-field push (> 3σ) sends support-slip
/// to re-simulation after the screen's candidates, and its springs grid reaches the stiffness whose
/// slip is the signature's 3σ (`support_slip::stiffness_grid`): named, k within √2 of the truth.
/// Before both (main 73544ae1) the verdict was `unexplained`. ≈ 14 CPU-s.
#[test]
fn stiff_support_springs_are_named() {
    let s = session_with(&[Effect::SupportSlip(1500.0)], true, &LOCATIONS, 101);
    let mut sim = simulator(20e3);
    let d = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default())
        .unwrap()
        .diagnosis;
    print_ranked(&d);
    assert_eq!(d.verdict, "support-slip", "{:?}", d.unexplained);
    let e = first_effect_three_fold(&d);
    let k = e.params["support_tangential_stiffness_n_per_m"];
    assert!(
        (1500.0 / 2f64.sqrt()..=1500.0 * 2f64.sqrt()).contains(&k),
        "k {k} N/m"
    );
}

/// A set above 3σ whose persistence over the gaps between releases is `p`, with standard error
/// `se`.
fn persisting(p: f64, se: f64) -> softcap_diagnose::Signatures {
    softcap_diagnose::Signatures {
        noise_sigma_m: 5e-6,
        released_set_m: 8e-5,
        released_set_persistence: Some(p),
        released_set_persistence_se: Some(se),
        ..Default::default()
    }
}

/// Plasticity's signature (`plasticity::PERMANENT_PERSISTENCE`, `PERSISTENCE_Z`): a creep
/// recovering at zero load with the retardation time τ' leaves e^{−Δt/τ'} of its set after a gap
/// Δt, below 1 however long τ' is: the creep g 1, τ 5 s of
/// [`slow_creep_and_plasticity_decided_by_longer_holds`] (τ' = τ(1 + g) = 10 s) over its 0.85 s
/// gaps persists 0.92 in theory and measures 0.913 ± 0.036 there, 2.4 standard errors below 1:
/// no support; a set within two standard errors of 1 (the calibration's weak plastic set, seed
/// 100: 0.988 ± 0.044) is supported, as is one that does not decay (the suites' plastic sets
/// measure 1.03–1.13); one recovering within a gap is contradicted, as is a set at the noise.
#[test]
fn only_a_released_set_that_does_not_decay_supports_plasticity() {
    use softcap_diagnose::Hypothesis;
    use softcap_diagnose::hypotheses::plasticity::Plasticity;
    let creep = (-0.85f64 / (5.0 * (1.0 + 1.0))).exp();
    assert!((0.9..1.0).contains(&creep), "{creep}");
    assert_eq!(Plasticity.signature_support(&persisting(creep, 0.036)), 0.0);
    assert_eq!(Plasticity.signature_support(&persisting(0.913, 0.036)), 0.0);
    assert_eq!(Plasticity.signature_support(&persisting(0.988, 0.044)), 1.0);
    assert_eq!(Plasticity.signature_support(&persisting(0.913, 0.05)), 1.0);
    // without a standard error the comparison is exact
    assert_eq!(Plasticity.signature_support(&persisting(0.999, 0.0)), 0.0);
    for p in [1.0, 1.03, 1.13] {
        assert_eq!(
            Plasticity.signature_support(&persisting(p, 0.01)),
            1.0,
            "{p}"
        );
    }
    assert_eq!(Plasticity.signature_support(&persisting(0.3, 0.01)), -1.0);
    let at_noise = softcap_diagnose::Signatures {
        released_set_m: 1e-5,
        ..persisting(1.1, 0.01)
    };
    assert_eq!(Plasticity.signature_support(&at_noise), -1.0);
    let single_release = softcap_diagnose::Signatures {
        released_set_persistence: None,
        released_set_persistence_se: None,
        ..persisting(1.0, 0.01)
    };
    assert_eq!(Plasticity.signature_support(&single_release), 1.0);
}

/// Slow creep against plasticity (issue 37's look-alike pair): a Prony branch g 1, τ 2 s whose
/// instantaneous modulus is the model's leaves a set after each release that persists over the
/// gaps between releases (persistence 0.77), as a plastic set does. The creep screen keeps each
/// location's creep under its markers and the persisting-but-recovering set no longer ranks
/// plasticity first: the creep is named, not plasticity (the reverse truth:
/// [`plastic_set_is_named`]). ≈ 70 CPU-s: the Prony re-simulations.
#[test]
fn slow_creep_is_not_named_plasticity() {
    let s = session_with(
        &[Effect::Stiffer(0.5), Effect::Creep { g: 1.0, tau_s: 2.0 }],
        false,
        &LOCATIONS,
        100,
    );
    let mut sim = simulator(20e3);
    let d = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default())
        .unwrap()
        .diagnosis;
    let persistence = d.ranked[0].evidence.signatures.released_set_persistence;
    assert!(
        persistence.is_some_and(|p| (0.5..0.9).contains(&p)),
        "{persistence:?}"
    );
    assert_eq!(d.verdict, "viscoelasticity", "{:?}", d.candidates);
    let top = &d.ranked[0];
    assert!(top.heldout_rmse_after_m * 3.0 <= top.heldout_rmse_before_m);
    // the plastic set was a qualifying alternative
    let plastic = d
        .ranked
        .iter()
        .find(|r| r.hypothesis == "plasticity")
        .unwrap();
    assert!(plastic.score >= 0.3, "{}", plastic.score);
}

#[test]
fn clean_control_is_none() {
    run(Effect::Clean, false, "none");
}

#[test]
fn oblique_clean_control_is_none() {
    run(Effect::Clean, true, "none");
}

#[test]
fn stiffer_material_control_is_none() {
    run(Effect::Stiffer(1.15), false, "none");
}

/// The clean session with marker m0 (a corner of the top grid, far from every probe location)
/// moved 0.45 mm sideways for 2 s in the middle of the recording — one marker on a spurious blob
/// beside it, the shape of a capture mislabel — diagnosed with `settings`.
fn relabeled_marker(settings: &DiagnoseSettings) -> (softcap_diagnose::Diagnosis, usize, usize) {
    let mut s = session(Effect::Clean, false);
    let nt = s.rec.frames.len();
    let (a, b) = (nt / 2 - 20, nt / 2 + 20);
    assert!(s.rec.frames[b].time_s - s.rec.frames[a].time_s >= 1.95);
    for f in &mut s.rec.frames[a..b] {
        f.markers_m[0] = f.markers_m[0].map(|p| p + Vector3::new(3.2e-4, 3.2e-4, 0.0));
    }
    let mut sim = simulator(20e3);
    let run = diagnose(&s.rec, &mut sim, settings).unwrap();
    (run.diagnosis, a, b)
}

/// The relabeled marker is flagged (exactly its 2 s) and left out: the verdict and held-out error
/// are the clean control's.
#[test]
fn relabeled_marker_is_flagged_and_left_out() {
    let (d, a, b) = relabeled_marker(&DiagnoseSettings::default());
    assert_eq!(d.outliers.len(), 1, "{:?}", d.outliers);
    let o = &d.outliers[0];
    assert_eq!((o.marker.as_str(), o.frames), ("m0", [a, b - 1]));
    assert!((o.step_m - 4.5e-4).abs() < 5e-5, "step {}", o.step_m);
    assert_eq!(d.verdict, "none");
    assert_message_matches(&d);
    let none = d.ranked.iter().find(|r| r.hypothesis == "none").unwrap();
    assert!(
        none.heldout_rmse_before_m < 0.012e-3,
        "{}",
        none.heldout_rmse_before_m
    );
}

/// With the outlier check off the mismatch stays in: far above the noise, explained by no catalog
/// entry — `unexplained`, naming the marker.
#[test]
fn relabeled_marker_left_in_is_unexplained() {
    let mut settings = DiagnoseSettings::default();
    settings.outliers.enabled = false;
    let (d, _, _) = relabeled_marker(&settings);
    assert!(d.outliers.is_empty());
    for r in &d.ranked {
        eprintln!(
            "{:>16} before {:.3e} after {:.3e} {:?}",
            r.hypothesis, r.heldout_rmse_before_m, r.heldout_rmse_after_m, r.evidence.baseline
        );
    }
    assert_eq!(d.verdict, "unexplained", "{:?}", d.unexplained);
    let u = d.unexplained.as_ref().unwrap();
    eprintln!("{u:?}");
    assert!(u.heldout_rmse_m >= 5.0 * u.noise_floor_m);
    assert!(u.best_explained_rmse_m >= 5.0 * u.noise_floor_m);
    assert_eq!(u.markers[0].0, "m0", "{u:?}");
    assert!(u.markers[0].1 > 1e-4, "{u:?}");
    assert_message_matches(&d);
}

/// `/diagnose/diagnosis` (the protobuf message, through an encode/decode round trip) carries the
/// same verdict, `unexplained` location and outlier runs as the JSON document.
fn assert_message_matches(d: &softcap_diagnose::Diagnosis) {
    use softcap_mcap::prost::Message;
    let bytes = softcap_diagnose::output::diagnosis_message(d).encode_to_vec();
    let m = softcap_mcap::proto::Diagnosis::decode(bytes.as_slice()).unwrap();
    assert_eq!(m.verdict, d.verdict);
    match (&m.unexplained, &d.unexplained) {
        (Some(p), Some(u)) => {
            assert_eq!(p.cell, u.cell);
            assert_eq!(p.location, u.location.map(|l| l as u32));
            assert_eq!(
                (
                    p.heldout_rmse_m,
                    p.best_explained_rmse_m,
                    p.noise_floor_m,
                    p.cell_rmse_m
                ),
                (
                    u.heldout_rmse_m,
                    u.best_explained_rmse_m,
                    u.noise_floor_m,
                    u.cell_rmse_m
                )
            );
            let markers: Vec<(String, f64)> = p
                .markers
                .iter()
                .map(|kv| match kv.value {
                    Some(softcap_mcap::proto::key_value::Value::Number(v)) => (kv.key.clone(), v),
                    ref other => panic!("marker {}: {other:?}", kv.key),
                })
                .collect();
            assert_eq!(markers, u.markers);
        }
        (None, None) => {}
        (p, u) => panic!("message {p:?} vs JSON {u:?}"),
    }
    assert_eq!(m.outliers.len(), d.outliers.len());
    for (p, o) in m.outliers.iter().zip(&d.outliers) {
        assert_eq!(
            (
                p.marker.as_str(),
                p.marker_index as usize,
                p.observations as usize
            ),
            (o.marker.as_str(), o.marker_index, o.observations)
        );
        assert_eq!([p.first_frame as usize, p.last_frame as usize], o.frames);
        assert_eq!([p.first_time_s, p.last_time_s], o.time_s);
        assert_eq!(p.step_m, o.step_m);
    }
}

#[test]
fn sensor_lag_is_named() {
    run(Effect::SensorLag(0.12), false, "sensor-lag");
}

#[test]
fn clock_offset_is_named() {
    run(Effect::ClockOffset(0.1), false, "clock-offset");
}

#[test]
fn viscoelastic_creep_is_named() {
    run(
        Effect::Creep { g: 0.8, tau_s: 0.2 },
        false,
        "viscoelasticity",
    );
}

#[test]
fn gravity_preload_is_named() {
    run(Effect::Gravity(1000.0), false, "gravity-preload");
}

/// Gravity's sag is no plastic set (issue 37's search for a second look-alike pair): the sag is
/// a displacement at rest like a permanent set, but it is there in the rest frames before the
/// first press, and the released-set signature subtracts each marker's rest residual, so the sag
/// leaves no released set and plasticity's signature contradicts it (support −1). ρ 200 kg/m³
/// sags the block below the rest signature's 3σ, ρ 1000 above; both are `gravity-preload`
/// (noise seed 100 of the look-alike chains). Measured: released set 9.0 µm (3σ 15.1 µm) at
/// ρ 200, 0.0149 → 0.0086 mm with ρ 198.
#[test]
fn gravity_sag_is_no_plastic_set() {
    for rho in [200.0, 1000.0] {
        let s = session_with(&[Effect::Gravity(rho)], false, &LOCATIONS, 100);
        let mut sim = simulator(20e3);
        let d = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default())
            .unwrap()
            .diagnosis;
        print_ranked(&d);
        let sig = &d.ranked[0].evidence.signatures;
        assert!(
            sig.released_set_m <= sig.three_sigma_m(),
            "ρ {rho}: released set {} m, 3σ {} m",
            sig.released_set_m,
            sig.three_sigma_m()
        );
        let plastic = d
            .ranked
            .iter()
            .find(|r| r.hypothesis == "plasticity")
            .and_then(|r| r.evidence.screened.as_ref())
            .map(|s| s.signature_support);
        assert_eq!(plastic, Some(-1.0), "ρ {rho}");
        assert_eq!(d.verdict, "gravity-preload", "ρ {rho}: {:?}", d.candidates);
    }
}

#[test]
fn probe_friction_is_named() {
    run(Effect::Friction(0.5), true, "probe-friction");
}

#[test]
fn support_slip_is_named() {
    run(Effect::SupportSlip(500.0), true, "support-slip");
}

#[test]
fn plastic_set_is_named() {
    run(
        Effect::Plastic {
            yield_pa: 2000.0,
            hardening_pa: 1000.0,
        },
        false,
        "plasticity",
    );
}

/// Times ten simulations and one diagnosis (part `timing` of the example).
#[cfg(not(test))]
fn timing_probe() {
    let mut sim = simulator(20e3);
    let t0 = std::time::Instant::now();
    let load = SimLoad {
        probe: Some(ProbeLoad {
            tip_m: Vector3::new(0.012, 0.012, 0.019),
            axis: -Vector3::z(),
            force_n: -Vector3::z() * 0.25,
        }),
        body_force_n_m3: Vector3::zeros(),
    };
    for _ in 0..10 {
        sim.simulate(&load, true).unwrap();
    }
    eprintln!("10 sims {:?}", t0.elapsed());
    let s = session(Effect::SensorLag(0.12), false);
    let t0 = std::time::Instant::now();
    let run = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default()).unwrap();
    eprintln!("diagnose {:?} {}", t0.elapsed(), run.diagnosis.verdict);
}

fn pv(p: &Vector3<f64>) -> softcap_mcap::proto::Vec3 {
    softcap_mcap::proto::Vec3 {
        x: p.x,
        y: p.y,
        z: p.z,
    }
}

/// Writes the session as a capture.mcap and the default model as a material.mcap.
fn write_inputs(
    rec: &Recording,
    dir: &std::path::Path,
) -> (std::path::PathBuf, std::path::PathBuf) {
    use softcap_mcap::{Provenance, Writer, proto, topics};
    let cap = dir.join("capture.mcap");
    let mut w = Writer::create(&cap, &Provenance::new("capture", "test")).unwrap();
    let session = proto::SessionInfo {
        name: "in-memory".into(),
        kind: "probe".into(),
        marker_ids: rec.marker_ids.clone(),
        object_markers: rec.num_markers() as u32,
        rest_positions_m: rec.rest_markers_m.iter().map(pv).collect(),
        gravity_m_s2: Some(pv(&rec.gravity_m_s2)),
        support: rec.support.map(|s| proto::SupportPlane {
            normal: Some(pv(&s.normal)),
            offset_m: s.offset_m,
            tolerance_m: s.tolerance_m,
        }),
        tip_shape: "disk".into(),
        tip_radius_m: rec.tip_radius_m,
        shaft_direction: "handle-to-tip".into(),
        metres_per_unit: 1.0,
        ..Default::default()
    };
    w.write_static(&topics::SESSION, &session).unwrap();
    for f in &rec.frames {
        let t_ns = (f.time_s * 1e9).round() as u64;
        let markers = f
            .markers_m
            .iter()
            .enumerate()
            .filter_map(|(i, p)| {
                p.map(|p| proto::Marker {
                    id: i as u32,
                    position_m: Some(pv(&p)),
                    visible: true,
                    views: 3,
                    ..Default::default()
                })
            })
            .collect();
        w.write(
            &topics::MARKERS,
            t_ns,
            &proto::MarkerFrame {
                frame: f.frame,
                t_camera_s: f.time_s,
                markers,
            },
        )
        .unwrap();
        w.write(
            &topics::PROBE,
            t_ns,
            &proto::ProbeSample {
                frame: f.frame,
                t_camera_s: f.time_s,
                tip_m: Some(pv(&f.tip_m)),
                axis: Some(pv(&f.axis)),
                force_n: Some(pv(&f.force_n)),
                voltage_v: 0.0,
            },
        )
        .unwrap();
    }
    w.finish().unwrap();

    let mat = dir.join("material.mcap");
    let m = mesh();
    let p = LinearParams::from_young_poisson(20e3, 0.45).unwrap();
    let mut w = Writer::create(&mat, &Provenance::new("tissue fit", "test")).unwrap();
    w.write_static(
        &topics::VOLUME_MESH,
        &proto::TetMesh {
            name: "volume".into(),
            positions_m: m.vertices.iter().flat_map(|v| [v.x, v.y, v.z]).collect(),
            tets: m.tets.iter().flat_map(|t| t.map(|i| i as u32)).collect(),
            ..Default::default()
        },
    )
    .unwrap();
    w.write(
        &topics::ELEMENT_MATERIAL,
        0,
        &proto::ElementMaterial {
            lambda_pa: vec![p.lambda; m.tets.len()],
            alpha_pa: vec![p.alpha; m.tets.len()],
            ..Default::default()
        },
    )
    .unwrap();
    w.finish().unwrap();
    (cap, mat)
}

#[test]
fn stage_run_writes_json_report_and_mcap_and_bad_input_exits_2() {
    let s = session(Effect::ClockOffset(0.1), false);
    let dir = tempfile::tempdir().unwrap();
    let (cap, mat) = write_inputs(&s.rec, dir.path());
    let cfg = softcap_diagnose::RunConfig {
        capture: cap.clone(),
        material: mat.clone(),
        output: dir.path().join("diagnosis.mcap"),
        json: Some(dir.path().join("diagnosis.json")),
        report: Some(dir.path().join("report")),
        settings: Default::default(),
        arguments: vec!["softcap-diagnose".into()],
        progress: false,
    };
    let d = softcap_diagnose::run(&cfg).unwrap();
    assert_eq!(d.verdict, "clock-offset");

    // JSON: the issue-8 schema and the named effects with their confidence (issue 37)
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("diagnosis.json")).unwrap())
            .unwrap();
    let keys =
        |v: &serde_json::Value| -> Vec<String> { v.as_object().unwrap().keys().cloned().collect() };
    assert_eq!(
        keys(&j),
        ["confidence", "effects", "located", "ranked", "verdict"]
    );
    assert_eq!(j["verdict"], "clock-offset");
    assert_eq!(j["effects"][0]["hypothesis"], "clock-offset");
    assert_eq!(
        keys(&j["effects"][0]),
        [
            "confidence",
            "fold_gains",
            "heldout_rmse_after_m",
            "heldout_rmse_before_m",
            "heldout_rmse_single_m",
            "heldout_rmse_without_m",
            "hypothesis",
            "params",
            "scored_cells"
        ]
    );
    let c = j["confidence"].as_f64().unwrap();
    assert!((0.9..=1.0).contains(&c), "confidence {c}");
    assert_eq!(
        keys(&j["ranked"][0]),
        [
            "evidence",
            "heldout_rmse_after_m",
            "heldout_rmse_before_m",
            "hypothesis",
            "params",
            "score"
        ]
    );
    assert_eq!(
        keys(&j["located"][0]),
        ["component", "phase", "region", "rmse_m"]
    );
    let offset = j["ranked"][0]["params"]["offset_s"].as_f64().unwrap();
    assert!((offset - 0.1).abs() <= 0.0126, "offset {offset}");

    // report
    let report = std::fs::read_to_string(dir.path().join("report/report.md")).unwrap();
    assert!(report.contains("**Verdict: `clock-offset`**"));
    assert!(report.contains("## Named effects"));
    for f in ["residual_map.png", "residual_time.png", "loops.png"] {
        let bytes = std::fs::read(dir.path().join("report").join(f)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{f}");
        assert!(report.contains(f));
    }
    let leftovers: Vec<_> = std::fs::read_dir(dir.path().join("report"))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n.to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");

    // diagnosis.mcap round trip
    let r = softcap_mcap::Recording::open(dir.path().join("diagnosis.mcap")).unwrap();
    let dm = r.read_static(&softcap_mcap::topics::DIAGNOSIS).unwrap();
    assert_eq!(dm.verdict, "clock-offset");
    assert_eq!(dm.ranked.len(), 10);
    let em = r
        .read_static(&softcap_mcap::topics::EXTENDED_MODEL)
        .unwrap();
    assert_eq!(em.hypothesis, "clock-offset");
    assert!(
        em.params
            .iter()
            .any(|p| p.key == "offset_s" && p.unit == "s")
    );
    let ext = r.read(&softcap_mcap::topics::EXTENDED_MARKERS).unwrap();
    assert_eq!(ext.len(), s.rec.frames.len());

    // bad input: exit code 2, nothing written
    let exe = env!("CARGO_BIN_EXE_softcap-diagnose");
    let out = dir.path().join("bad.mcap");
    let corrupt = dir.path().join("corrupt.mcap");
    let bytes = std::fs::read(&cap).unwrap();
    std::fs::write(&corrupt, &bytes[..bytes.len() / 2]).unwrap();
    for (c, m) in [(&corrupt, &mat), (&cap, &dir.path().join("missing.mcap"))] {
        let st = std::process::Command::new(exe)
            .arg(c)
            .arg(m)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap();
        assert_eq!(
            st.status.code(),
            Some(2),
            "{}",
            String::from_utf8_lossy(&st.stderr)
        );
        assert!(!out.exists());
        let err = String::from_utf8_lossy(&st.stderr);
        assert!(err.contains(".mcap"), "{err}");
    }
}

/// Regenerates the example report in docs/diagnose/ (part `docs-report` of the example).
#[cfg(not(test))]
fn write_docs_report() {
    let s = session(Effect::Creep { g: 0.8, tau_s: 0.2 }, false);
    let mut sim = simulator(20e3);
    let run = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default()).unwrap();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/diagnose");
    softcap_diagnose::write_report(&dir, &s.rec, &run).unwrap();
    softcap_diagnose::write_json(&dir.join("diagnosis.json"), &run.diagnosis).unwrap();
}

/// Timing of the full catalog on a 10-location session (part `ten-locations` of the example).
#[cfg(not(test))]
fn full_catalog_on_ten_locations_timing() {
    let xy: Vec<(f64, f64)> = [0.008, 0.016, 0.024, 0.032]
        .iter()
        .flat_map(|&x| [0.010, 0.022, 0.032].map(|y| (x, y)))
        .take(10)
        .collect();
    let s = session_at(Effect::SensorLag(0.12), false, &xy);
    let mut sim = simulator(20e3);
    let t0 = std::time::Instant::now();
    let run = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default()).unwrap();
    eprintln!(
        "10 locations, {} frames: {:?}, verdict {}, locations found {}",
        s.rec.frames.len(),
        t0.elapsed(),
        run.diagnosis.verdict,
        run.segmentation.num_folds()
    );
    assert_eq!(run.segmentation.num_folds(), 10);
    assert_eq!(run.diagnosis.verdict, "sensor-lag");
}

/// Regression guard of the strain-space default model (bickel2009 eq. 8, §3.4): the simulator
/// solves the basis to convergence at every load (the plain parameter iteration of
/// `StrainSpaceMaterial::model` stopped at MaxIterations on the suite's clean control), the
/// markers do not depend on the order the loads come in (the material is elastic; each solve
/// continues from the previous equilibrium only to start its iterations), the frame-by-frame
/// sequence of `Extension::Elastic` gives the same markers, and the strain dependence is live
/// (the markers differ from the zero-strain parameters' linear response).
#[test]
fn strain_space_default_model_does_not_depend_on_the_frame_order() {
    use softcap_probing::{StrainBasisSettings, StrainSample, StrainSpaceMaterial};
    let p = LinearParams::from_young_poisson(20e3, 0.45).unwrap();
    // λ and α double between zero strain and ε_zz = −0.05 in every tet (a stiffening tissue)
    let stiffening: Vec<StrainSample> = [(0.0, 1.0), (-0.05, 2.0)]
        .into_iter()
        .map(|(eps_zz, scale)| StrainSample {
            strain: [0.0, 0.0, eps_zz, 0.0, 0.0, 0.0],
            params: LinearParams {
                lambda: scale * p.lambda,
                alpha: scale * p.alpha,
            },
        })
        .collect();
    let samples = vec![stiffening; mesh().tets.len()];
    let material = std::sync::Arc::new(
        StrainSpaceMaterial::fit(&samples, &StrainBasisSettings::default())
            .unwrap()
            .0,
    );
    let load = |x: f64, y: f64, f: f64| SimLoad {
        probe: Some(ProbeLoad {
            tip_m: Vector3::new(x, y, SIZE[2]),
            axis: -Vector3::z(),
            force_n: Vector3::new(0.0, 0.0, -f),
        }),
        body_force_n_m3: Vector3::zeros(),
    };
    let loads = [
        load(0.02, 0.02, 0.25),
        load(0.02, 0.02, 0.5),
        load(0.02, 0.02, 0.75),
        load(0.02, 0.02, 1.0),
        load(0.012, 0.028, 1.0),
        SimLoad::default(),
    ];
    let run = |order: &[usize]| -> Vec<Vec<Vector3<f64>>> {
        let mut sim = simulator(20e3).with_strain_space(material.clone()).unwrap();
        let mut out = vec![Vec::new(); loads.len()];
        for &k in order {
            let o = sim.simulate(&loads[k], true).unwrap();
            assert!(o.force_response.is_some() || loads[k].probe.is_none());
            out[k] = o.markers_m;
        }
        out
    };
    let forward = run(&[0, 1, 2, 3, 4, 5]);
    let backward = run(&[5, 4, 3, 2, 1, 0]);
    let frames: Vec<SequenceFrame> = loads
        .iter()
        .enumerate()
        .map(|(k, l)| SequenceFrame {
            time_s: DT * k as f64,
            load: *l,
        })
        .collect();
    let sequence = simulator(20e3)
        .with_strain_space(material.clone())
        .unwrap()
        .simulate_sequence(&Extension::Elastic, &frames)
        .unwrap();
    let mut linear = simulator(20e3);
    let max_diff = |a: &[Vector3<f64>], b: &[Vector3<f64>]| {
        a.iter()
            .zip(b)
            .map(|(u, v)| (u - v).norm())
            .fold(0.0, f64::max)
    };
    // 100 × the displacement tolerance (10⁻⁸ of the 0.06 m bounding-box diagonal): the relaxed
    // parameter iteration converges linearly and stops within a few tolerances of the fixed point
    for k in 0..loads.len() {
        let order = max_diff(&forward[k], &backward[k]);
        let seq = max_diff(&forward[k], &sequence[k]);
        eprintln!("load {k}: order {order:.2e} m, sequence {seq:.2e} m");
        assert!(
            order <= 6e-8,
            "load {k}: frame order moves markers {order} m"
        );
        assert!(seq <= 6e-8, "load {k}: sequence vs frames {seq} m");
    }
    let lin = linear.simulate(&loads[3], false).unwrap().markers_m;
    let stiffening = max_diff(&forward[3], &lin);
    eprintln!("basis vs zero-strain linear response at 1 N: {stiffening:.3e} m");
    assert!(
        stiffening > 1e-5,
        "strain dependence inactive: {stiffening} m from the linear response"
    );
}

/// The harnesses of `examples/in_memory.rs` (not tests: they time or regenerate docs figures).
#[cfg(not(test))]
pub(crate) fn harness(part: Option<&str>) -> Result<(), String> {
    match part {
        Some("timing") => timing_probe(),
        Some("ten-locations") => full_catalog_on_ten_locations_timing(),
        Some("docs-report") => write_docs_report(),
        Some("effect-size") => effect_sizes(std::env::args().nth(2).as_deref().unwrap_or("")),
        Some("calibration") => match std::env::args().nth(2) {
            None => calibration()?,
            Some(filter) => calibration_sessions(&filter, std::env::args().nth(3).as_deref())?,
        },
        Some("pairs") => pairs_table(std::env::args().nth(2).as_deref()),
        Some("next-experiment") => next_experiment_table(std::env::args().nth(2).as_deref()),
        Some("lookalike") => lookalike_table(std::env::args().nth(2).as_deref()),
        Some("lookalike-spec") => {
            let args: Vec<String> = std::env::args().skip(2).collect();
            lookalike_spec(&args)?
        }
        other => {
            return Err(format!(
                "part {other:?}: one of timing, ten-locations, docs-report, calibration, effect-size, pairs, next-experiment, lookalike, lookalike-spec"
            ));
        }
    }
    Ok(())
}

/// The calibration sessions: per effect, three strengths (barely above the noise, middle,
/// strong) and whether the session needs the oblique probe.
#[cfg(not(test))]
fn calibration_effects() -> Vec<(&'static str, bool, [Effect; 3])> {
    let creep = |g: f64| Effect::Creep { g, tau_s: 0.2 };
    vec![
        (
            "sensor-lag",
            false,
            [0.02, 0.05, 0.12].map(Effect::SensorLag),
        ),
        (
            "clock-offset",
            false,
            [0.01, 0.03, 0.1].map(Effect::ClockOffset),
        ),
        ("viscoelasticity", false, [0.1, 0.3, 0.8].map(creep)),
        (
            "gravity-preload",
            false,
            [100.0, 300.0, 1000.0].map(Effect::Gravity),
        ),
        (
            "support-slip",
            true,
            [5000.0, 1500.0, 500.0].map(Effect::SupportSlip),
        ),
        (
            "anisotropy",
            false,
            [1.5, 2.5, 5.0].map(Effect::Anisotropic),
        ),
        // the two with rigid-tip replays (tens of CPU-s per session) last; plasticity's σ_y by
        // the effect size of the other seven at each level (`effect-size "plasticity strengths"`)
        (
            "plasticity",
            false,
            [2200.0, 2000.0, 1750.0].map(plastic_hardening_1kpa),
        ),
        (
            "probe-friction",
            true,
            [0.05, 0.15, 0.5].map(Effect::Friction),
        ),
    ]
}

/// Strength label of calibration column `i`.
#[cfg(not(test))]
fn strength_label(e: &Effect) -> String {
    match *e {
        Effect::SensorLag(t) => format!("τ {t} s"),
        Effect::ClockOffset(d) => format!("δ {d} s"),
        Effect::Creep { g, .. } => format!("g {g}"),
        Effect::Gravity(r) => format!("ρ {r} kg/m³"),
        Effect::Friction(m) => format!("μ {m}"),
        Effect::SupportSlip(k) => format!("k {k} N/m"),
        Effect::Plastic { yield_pa, .. } => format!("σy {} kPa", yield_pa / 1e3),
        Effect::Anisotropic(r) => format!("ratio {r}"),
        _ => String::new(),
    }
}

/// False alarms on 20 seeded clean sessions (alternately straight and oblique probe) and
/// detection against strength (8 effects × 3 strengths, each with its effect size against the
/// default model, [`EffectSize`]): a table on stdout, the CSV and the plot under
/// `SOFTCAP_CALIBRATION_OUT` (default `target/calibration`).
#[cfg(not(test))]
fn calibration() -> Result<(), String> {
    use std::fmt::Write as _;
    let out = std::env::var_os("SOFTCAP_CALIBRATION_OUT")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| "target/calibration".into());
    std::fs::create_dir_all(&out).map_err(|e| e.to_string())?;
    let mut csv =
        String::from("kind,effect,strength,seed,effect_size_um,verdict,effects,confidence,named\n");
    let diagnose_one = |effects: &[Effect], oblique: bool, seed: u64| {
        let s = session_with(effects, oblique, &LOCATIONS, seed);
        let mut sim = simulator(20e3);
        diagnose(&s.rec, &mut sim, &DiagnoseSettings::default()).map(|r| r.diagnosis)
    };
    let mut alarms = 0;
    let clean_n = 20;
    for seed in 1..=clean_n {
        let oblique = seed % 2 == 0;
        let d = diagnose_one(&[Effect::Clean], oblique, seed).map_err(|e| e.to_string())?;
        let alarm = d.verdict != "none";
        alarms += alarm as usize;
        let named: Vec<&str> = d.effects.iter().map(|e| e.hypothesis.as_str()).collect();
        eprintln!("clean seed {seed}: {} ({:.3})", d.verdict, d.confidence);
        let _ = writeln!(
            csv,
            "clean,none,0,{seed},0.0,{},{},{:.4},{}",
            d.verdict,
            named.join("+"),
            d.confidence,
            !alarm
        );
    }
    let mut rows = Vec::new();
    for (name, oblique, strengths) in calibration_effects() {
        let mut hit = [false; 3];
        let mut labels = strengths.map(|e| strength_label(&e));
        for (i, e) in strengths.iter().enumerate() {
            let seed = 100 + i as u64;
            let size_um = 1e6 * EffectSize::of(*e, oblique, seed).model_rms_m;
            labels[i] = format!("{} ({size_um:.1} µm)", labels[i]);
            let d = diagnose_one(&[*e], oblique, seed).map_err(|e| e.to_string())?;
            let named: Vec<&str> = d.effects.iter().map(|e| e.hypothesis.as_str()).collect();
            hit[i] = named.contains(&name);
            eprintln!(
                "{name} {} (effect size {size_um:.1} µm): {} {:?} ({:.3})",
                strength_label(e),
                d.verdict,
                named,
                d.confidence
            );
            let _ = writeln!(
                csv,
                "effect,{name},{},{seed},{size_um:.1},{},{},{:.4},{}",
                strength_label(e),
                d.verdict,
                named.join("+"),
                d.confidence,
                hit[i]
            );
        }
        rows.push((name, labels, hit));
    }
    std::fs::write(out.join("calibration.csv"), &csv).map_err(|e| e.to_string())?;
    println!(
        "false alarms: {alarms} / {clean_n} clean sessions ({:.0} %)\n",
        100.0 * alarms as f64 / clean_n as f64
    );
    println!("| effect | weak | middle | strong |\n|---|---|---|---|");
    for (name, labels, hit) in &rows {
        let cell = |i: usize| format!("{} {}", labels[i], if hit[i] { "✓" } else { "✗" });
        println!("| {name} | {} | {} | {} |", cell(0), cell(1), cell(2));
    }
    let rate = |i: usize| rows.iter().filter(|r| r.2[i]).count() as f64 / rows.len() as f64;
    println!(
        "| detection rate | {:.0} % | {:.0} % | {:.0} % |",
        100.0 * rate(0),
        100.0 * rate(1),
        100.0 * rate(2)
    );
    let png = out.join("calibration.png");
    let rates = [rate(0), rate(1), rate(2)];
    let false_alarm = alarms as f64 / clean_n as f64;
    softcap_figure::draw_png(&png, (800, 500), |root| {
        calibration_plot(root, &rows, rates, false_alarm).map_err(|e| e.into())
    })
    .map_err(|e| e.to_string())?;
    eprintln!(
        "wrote {} and {}",
        out.join("calibration.csv").display(),
        png.display()
    );
    Ok(())
}

/// The calibration's effect sessions whose "effect strength" label contains `filter` (e.g.
/// `"support-slip k 1500"`), diagnosed alone with their ranked rows on stderr and a line each on
/// stdout: with the table's noise seed (100 + strength column), or with `seed` (another draw of
/// the same truth).
#[cfg(not(test))]
fn calibration_sessions(filter: &str, seed: Option<&str>) -> Result<(), String> {
    let seed: Option<u64> = seed
        .map(|s| s.parse().map_err(|_| format!("seed {s:?}: not an integer")))
        .transpose()?;
    for (name, oblique, strengths) in calibration_effects() {
        for (i, e) in strengths.iter().enumerate() {
            let label = format!("{name} {}", strength_label(e));
            if !label.contains(filter) {
                continue;
            }
            let seed = seed.unwrap_or(100 + i as u64);
            let t0 = std::time::Instant::now();
            let s = session_with(&[*e], oblique, &LOCATIONS, seed);
            let mut sim = simulator(20e3);
            let d = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default())
                .map_err(|e| e.to_string())?
                .diagnosis;
            eprintln!("{label}, seed {seed}:");
            print_ranked(&d);
            let named: Vec<&str> = d.effects.iter().map(|e| e.hypothesis.as_str()).collect();
            println!(
                "| {label} | {seed} | `{}` | {} | {:.2} | {:.0} s |",
                d.verdict,
                named.join(", "),
                d.confidence,
                t0.elapsed().as_secs_f64()
            );
        }
    }
    Ok(())
}

/// How far each calibration effect whose label contains `filter` lifts the data above the noise
/// ([`EffectSize`]); with the filter `yield onset`, J2 plasticity (hardening 1 kPa) at σ_y
/// 2–4 kPa instead: where the 0.25 N probe starts to yield the 648-tet block; with the filter
/// `plasticity strengths`, the rule that sets plasticity's three calibration strengths
/// ([`plasticity_strengths`]).
#[cfg(not(test))]
fn effect_sizes(filter: &str) {
    if filter == "plasticity strengths" {
        plasticity_strengths();
        return;
    }
    println!("{}", EffectSize::HEADER);
    if filter == "yield onset" {
        for yield_pa in [2000.0, 2500.0, 3000.0, 3500.0, 4000.0] {
            let e = plastic_hardening_1kpa(yield_pa);
            let size = EffectSize::of(e, false, 101);
            println!(
                "{}",
                size.row(&format!("plasticity {}", strength_label(&e)))
            );
        }
        return;
    }
    for (name, oblique, strengths) in calibration_effects() {
        for (i, e) in strengths.iter().enumerate() {
            let label = format!("{name} {}", strength_label(e));
            if label.contains(filter) {
                println!(
                    "{}",
                    EffectSize::of(*e, oblique, 100 + i as u64).row(&label)
                );
            }
        }
    }
}

/// J2 plasticity with the calibration's hardening modulus, 1 kPa.
#[cfg(not(test))]
fn plastic_hardening_1kpa(yield_pa: f64) -> Effect {
    Effect::Plastic {
        yield_pa,
        hardening_pa: 1000.0,
    }
}

/// The rule for plasticity's calibration strengths: at each level (weak, middle, strong; noise
/// seed 100, 101, 102) the median over the seven other effects of the effect size the default
/// model sees ([`EffectSize::model_rms_m`]), and the yield stress σ_y of the grid (hardening
/// 1 kPa, the 0.25 N probe) whose session's effect size is closest to it (absolute difference).
/// The grid is swept once at seed 101: a marker-only effect's size does not depend on the noise
/// draw (the same draws cancel). One table row per level on stdout, the sweep on stderr.
#[cfg(not(test))]
fn plasticity_strengths() {
    let grid = [
        500.0, 750.0, 1000.0, 1250.0, 1500.0, 1750.0, 2000.0, 2100.0, 2200.0, 2300.0, 2400.0,
        2500.0,
    ];
    let sweep: Vec<(f64, f64)> = grid
        .iter()
        .map(|&y| {
            let size = EffectSize::of(plastic_hardening_1kpa(y), false, 101);
            eprintln!("{}", size.row(&format!("plasticity σy {} kPa", y / 1e3)));
            (y, size.model_rms_m)
        })
        .collect();
    println!(
        "| level (seed) | effect size of the seven others, µm (× √3σ) | median | σ_y whose size is closest (its size) |"
    );
    println!("|---|---|---|---|");
    for (i, level) in ["weak", "middle", "strong"].iter().enumerate() {
        let seed = 100 + i as u64;
        let mut others: Vec<(&str, f64)> = calibration_effects()
            .into_iter()
            .filter(|(name, ..)| *name != "plasticity")
            .map(|(name, oblique, strengths)| {
                (
                    name,
                    EffectSize::of(strengths[i], oblique, seed).model_rms_m,
                )
            })
            .collect();
        others.sort_by(|a, b| a.1.total_cmp(&b.1));
        let median = others[others.len() / 2].1;
        let (y, size) = sweep
            .iter()
            .min_by(|a, b| (a.1 - median).abs().total_cmp(&(b.1 - median).abs()))
            .copied()
            .expect("a non-empty grid");
        let um = |x: f64| format!("{:.1} ({:.2})", 1e6 * x, x / noise_rms_m());
        let listed: Vec<String> = others
            .iter()
            .map(|(name, x)| format!("{name} {:.1}", 1e6 * x))
            .collect();
        println!(
            "| {level} ({seed}) | {} | {} | σy {} kPa ({}) |",
            listed.join(", "),
            um(median),
            y / 1e3,
            um(size)
        );
    }
}

/// The noise RMS of a marker position, √3σ (σ = 5 µm per axis), m.
#[cfg(not(test))]
fn noise_rms_m() -> f64 {
    3f64.sqrt() * 5e-6
}

/// How far a calibration session lies from the clean session of the same probe path and noise
/// seed (the same noise draws, so the difference is the effect alone), over the location frames:
/// the marker difference (all markers, and the released frames within the contact radius of the
/// probed point), the measured force's difference, and the difference of the residuals against
/// the default model each one's measured force drives (the effect as the diagnosis sees it: the
/// marker difference for effects on the object, the model's response to the force difference for
/// effects on the force channel).
#[cfg(not(test))]
struct EffectSize {
    /// RMS and largest marker difference, m.
    markers_m: (f64, f64),
    /// RMS and largest marker difference on released frames near the probed point, m.
    released_m: (f64, f64),
    /// RMS difference of the measured force over all frames, N.
    force_rms_n: f64,
    /// RMS difference of the residuals against the default model, m.
    model_rms_m: f64,
    /// Largest such difference, m.
    model_max_m: f64,
}

#[cfg(not(test))]
impl EffectSize {
    const HEADER: &str = "| session | markers RMS / max, µm (× √3σ) | released near the probe RMS / max, µm | force RMS, mN | against the default model RMS / max, µm (× √3σ) |\n|---|---|---|---|---|";

    fn of(effect: Effect, oblique: bool, seed: u64) -> EffectSize {
        let a = session_with(&[effect], oblique, &LOCATIONS, seed).rec;
        let b = session_with(&[Effect::Clean], oblique, &LOCATIONS, seed).rec;
        let baseline = |rec: &Recording| {
            let seg = Segmentation::new(rec, &SegmentSettings::default());
            let mut sim = simulator(20e3);
            let progress = indicatif::ProgressBar::hidden();
            softcap_diagnose::prepare(rec, &seg, &mut sim, &DiagnoseSettings::default(), &progress)
                .expect("the default model reaches equilibrium")
                .baseline_m
        };
        let (pa, pb) = (baseline(&a), baseline(&b));
        let seg = Segmentation::new(&b, &SegmentSettings::default());
        let radius = softcap_diagnose::cells::contact_radius_m(&b);
        let acc = |x: &mut (f64, usize, f64), d: f64| *x = (x.0 + d * d, x.1 + 1, x.2.max(d));
        let (mut all, mut rel, mut model) = ((0.0, 0, 0.0), (0.0, 0, 0.0), (0.0, 0, 0.0));
        let mut force = 0.0;
        for (k, (fa, fb)) in a.frames.iter().zip(&b.frames).enumerate() {
            force += (fa.force_n - fb.force_n).norm_squared();
            let Some(l) = seg.fold_of_frame[k] else {
                continue;
            };
            for (m, (x, y)) in fa.markers_m.iter().zip(&fb.markers_m).enumerate() {
                let (Some(x), Some(y)) = (x, y) else { continue };
                acc(&mut all, (x - y).norm());
                acc(&mut model, ((x - pa[k][m]) - (y - pb[k][m])).norm());
                let near = (seg.locations[l].contact_tip_m - b.rest_markers_m[m]).norm() <= radius;
                if seg.phases[k] == softcap_diagnose::Phase::Released && near {
                    acc(&mut rel, (x - y).norm());
                }
            }
        }
        let rms = |x: (f64, usize, f64)| (x.0 / x.1.max(1) as f64).sqrt();
        EffectSize {
            markers_m: (rms(all), all.2),
            released_m: (rms(rel), rel.2),
            force_rms_n: (force / a.frames.len() as f64).sqrt(),
            model_rms_m: rms(model),
            model_max_m: model.2,
        }
    }

    fn row(&self, label: &str) -> String {
        let (n, um) = (noise_rms_m(), 1e6);
        format!(
            "| {label} | {:.1} / {:.1} ({:.2} / {:.2}) | {:.1} / {:.1} | {:.2} | {:.1} / {:.1} ({:.2} / {:.2}) |",
            um * self.markers_m.0,
            um * self.markers_m.1,
            self.markers_m.0 / n,
            self.markers_m.1 / n,
            um * self.released_m.0,
            um * self.released_m.1,
            1e3 * self.force_rms_n,
            um * self.model_rms_m,
            um * self.model_max_m,
            self.model_rms_m / n,
            self.model_max_m / n
        )
    }
}

/// Detection per effect and the rate against strength, with the false-alarm rate as a line.
#[cfg(not(test))]
fn calibration_plot(
    root: &plotters::drawing::DrawingArea<
        plotters::prelude::BitMapBackend<'_>,
        plotters::coord::Shift,
    >,
    rows: &[(&str, [String; 3], [bool; 3])],
    rates: [f64; 3],
    false_alarm: f64,
) -> Result<(), String> {
    use plotters::prelude::*;
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let mut chart = ChartBuilder::on(root)
        .caption(
            "in-memory rig: detection against effect strength",
            (softcap_figure::FONT_FAMILY, 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(-0.3f64..2.3f64, -0.05f64..1.05f64)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_labels(3)
        .x_label_formatter(&|x| ["weak", "middle", "strong"][(x.round() as usize).min(2)].into())
        .y_desc("fraction named")
        .draw()
        .map_err(|e| e.to_string())?;
    for (j, (name, _, hit)) in rows.iter().enumerate() {
        let c = Palette99::pick(j).to_rgba();
        let dx = (j as f64 - rows.len() as f64 / 2.0) * 0.02;
        chart
            .draw_series((0..3).map(|i| {
                Circle::new(
                    (i as f64 + dx, if hit[i] { 1.0 } else { 0.0 }),
                    5,
                    c.filled(),
                )
            }))
            .map_err(|e| e.to_string())?
            .label(*name)
            .legend(move |(x, y)| Circle::new((x, y), 5, c.filled()));
    }
    chart
        .draw_series(LineSeries::new(
            (0..3).map(|i| (i as f64, rates[i])),
            BLACK.stroke_width(3),
        ))
        .map_err(|e| e.to_string())?
        .label("detection rate")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(3)));
    chart
        .draw_series(LineSeries::new(
            [(-0.3, false_alarm), (2.3, false_alarm)],
            RED.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?
        .label("false-alarm rate (clean)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(2)));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(|e| e.to_string())?;
    Ok(())
}

/// The two-effect sessions (those whose name contains `filter`): the named effects and the joint
/// model against each one alone.
#[cfg(not(test))]
fn pairs_table(filter: Option<&str>) {
    let plastic = Effect::Plastic {
        yield_pa: 2000.0,
        hardening_pa: 1000.0,
    };
    let cases: [(&str, &[Effect], bool); 10] = [
        (
            "creep + clock offset",
            &[
                Effect::Creep { g: 0.8, tau_s: 0.2 },
                Effect::ClockOffset(0.1),
            ],
            false,
        ),
        (
            "support springs + sensor lag",
            &[Effect::SupportSlip(500.0), Effect::SensorLag(0.12)],
            true,
        ),
        (
            "plasticity + probe friction",
            &[plastic, Effect::Friction(0.5)],
            true,
        ),
        (
            "anisotropy + gravity",
            &[Effect::Anisotropic(5.0), Effect::Gravity(1000.0)],
            false,
        ),
        (
            "gravity + sensor lag",
            &[Effect::Gravity(1000.0), Effect::SensorLag(0.12)],
            false,
        ),
        (
            "gravity + clock offset",
            &[Effect::Gravity(1000.0), Effect::ClockOffset(0.1)],
            false,
        ),
        (
            "probe friction + clock offset",
            &[Effect::Friction(0.5), Effect::ClockOffset(0.1)],
            true,
        ),
        (
            "support springs + clock offset",
            &[Effect::SupportSlip(500.0), Effect::ClockOffset(0.1)],
            true,
        ),
        (
            "anisotropy + sensor lag",
            &[Effect::Anisotropic(5.0), Effect::SensorLag(0.12)],
            false,
        ),
        (
            "creep + sensor lag",
            &[
                Effect::Creep { g: 0.8, tau_s: 0.2 },
                Effect::SensorLag(0.12),
            ],
            false,
        ),
    ];
    println!(
        "| session | verdict | effects (confidence) | second effect's cells: default / first alone / second alone / joint, mm |"
    );
    println!("|---|---|---|---|");
    for (name, effects, oblique) in cases {
        if filter.is_some_and(|f| !name.contains(f)) {
            continue;
        }
        let s = session_with(effects, oblique, &LOCATIONS, 8);
        let mut sim = simulator(20e3);
        let t0 = std::time::Instant::now();
        let d = match diagnose(&s.rec, &mut sim, &DiagnoseSettings::default()) {
            Ok(r) => r.diagnosis,
            Err(e) => {
                println!("| {name} | error: {e} | | |");
                continue;
            }
        };
        eprintln!("{name}:");
        print_ranked(&d);
        let named: Vec<String> = d
            .effects
            .iter()
            .map(|e| format!("{} ({:.2})", e.hypothesis, e.confidence))
            .collect();
        let cells = d.effects.get(1).map_or("–".to_string(), |e| {
            format!(
                "{:.4} / {:.4} / {:.4} / {:.4}",
                1e3 * e.heldout_rmse_before_m,
                1e3 * e.heldout_rmse_without_m,
                1e3 * e.heldout_rmse_single_m,
                1e3 * e.heldout_rmse_after_m
            )
        });
        println!(
            "| {name} | `{}` | {} | {cells} |",
            d.verdict,
            named.join(", ")
        );
        eprintln!("{name}: {:?}", t0.elapsed());
    }
}

/// The first named effect, asserted to lower its held-out error at least 3×.
fn first_effect_three_fold(d: &softcap_diagnose::Diagnosis) -> &softcap_diagnose::NamedEffect {
    let e = &d.effects[0];
    assert!(
        3.0 * e.heldout_rmse_after_m <= e.heldout_rmse_before_m,
        "held-out {} → {}",
        e.heldout_rmse_before_m,
        e.heldout_rmse_after_m
    );
    e
}

/// The top of the ranked table, the named effects and the candidates on stderr.
fn print_ranked(d: &softcap_diagnose::Diagnosis) {
    if let Some(s) = d.ranked.first().map(|r| &r.evidence.signatures) {
        eprintln!(
            "  signatures drift {:.4} tip creep {:.4} ± {:?} delay10 {:.4} delay50 {:.4} growth se {:?} shift/lag growth {:.4}/{:.4} set {:.2e} persist {:?} ± {:?} drag {:.2e} attached {:.2e} far {:.2e} 3σ {:.2e}",
            s.hold_force_drift,
            s.hold_tip_creep,
            s.hold_tip_creep_se,
            s.force_delay_10_s,
            s.force_delay_50_s,
            s.force_delay_growth_se_s,
            s.force_delay_growth_shift_s,
            s.force_delay_growth_lag_s,
            s.released_set_m,
            s.released_set_persistence,
            s.released_set_persistence_se,
            s.contact_drag_m,
            s.attached_motion_m,
            s.far_field_push_m,
            s.three_sigma_m()
        );
    }
    for r in d.ranked.iter().take(7) {
        let sup = r.evidence.screened.as_ref().map(|s| {
            (
                s.signature_support,
                s.qualifies,
                (1e3 * s.heldout_rmse_linearised_m * 1e4).round() / 1e4,
            )
        });
        eprintln!(
            "  {:>16} score {:+.3} before {:.4} after {:.4} mm support/qualifies/screen mm {sup:?} {:?} {:?}",
            r.hypothesis,
            r.score,
            1e3 * r.heldout_rmse_before_m,
            1e3 * r.heldout_rmse_after_m,
            r.evidence.confirmation_failed,
            r.params
        );
    }
    for e in &d.effects {
        eprintln!(
            "  effect {} conf {:.3} before/without/single/after {:.4}/{:.4}/{:.4}/{:.4} mm gains {:?} {:?}",
            e.hypothesis,
            e.confidence,
            1e3 * e.heldout_rmse_before_m,
            1e3 * e.heldout_rmse_without_m,
            1e3 * e.heldout_rmse_single_m,
            1e3 * e.heldout_rmse_after_m,
            e.fold_gains,
            e.params
        );
    }
    for c in &d.candidates {
        eprintln!(
            "  candidate {} conf {:.3} after {:.4} mm gains {:?}",
            c.hypothesis,
            c.confidence,
            1e3 * c.heldout_rmse_after_m,
            c.fold_gains
        );
    }
    if let Some(n) = &d.next_experiment {
        eprintln!("  next {n:?}");
    }
}

/// Look-alike sessions (those whose name contains `filter`): diagnosed under the standard
/// protocol; when `inconclusive`, re-recorded under the suggested protocol (same truth, same noise
/// seed) and diagnosed again.
#[cfg(not(test))]
fn next_experiment_table(filter: Option<&str>) {
    let cases: Vec<(&str, &[&str], Vec<Effect>, bool)> = vec![
        (
            "sensor lag τ 0.03 s",
            &["sensor-lag"],
            vec![Effect::SensorLag(0.03)],
            false,
        ),
        (
            "sensor lag τ 0.05 s",
            &["sensor-lag"],
            vec![Effect::SensorLag(0.05)],
            false,
        ),
        (
            "clock offset 0.02 s",
            &["clock-offset"],
            vec![Effect::ClockOffset(0.02)],
            false,
        ),
        (
            "clock offset 0.03 s",
            &["clock-offset"],
            vec![Effect::ClockOffset(0.03)],
            false,
        ),
        (
            "creep g 0.3",
            &["viscoelasticity"],
            vec![Effect::Creep { g: 0.3, tau_s: 0.2 }],
            false,
        ),
        (
            "creep g 0.3, τ 1 s",
            &["viscoelasticity"],
            vec![Effect::Creep { g: 0.3, tau_s: 1.0 }],
            false,
        ),
        (
            "gravity ρ 300",
            &["gravity-preload"],
            vec![Effect::Gravity(300.0)],
            false,
        ),
        (
            "support springs 1500 N/m",
            &["support-slip"],
            vec![Effect::SupportSlip(1500.0)],
            true,
        ),
        (
            "clock offset 0.015 s",
            &["clock-offset"],
            vec![Effect::ClockOffset(0.015)],
            false,
        ),
        (
            "sensor lag τ 0.02 s",
            &["sensor-lag"],
            vec![Effect::SensorLag(0.02)],
            false,
        ),
        (
            "creep g 0.8, τ 1.5 s",
            &["viscoelasticity"],
            vec![Effect::Creep { g: 0.8, tau_s: 1.5 }],
            false,
        ),
        (
            "creep g 1.5, τ 3 s",
            &["viscoelasticity"],
            vec![Effect::Creep { g: 1.5, tau_s: 3.0 }],
            false,
        ),
        (
            "sensor lag τ 0.01 s",
            &["sensor-lag"],
            vec![Effect::SensorLag(0.01)],
            false,
        ),
        (
            "sensor lag τ 0.015 s",
            &["sensor-lag"],
            vec![Effect::SensorLag(0.015)],
            false,
        ),
        (
            "clock offset 0.01 s",
            &["clock-offset"],
            vec![Effect::ClockOffset(0.01)],
            false,
        ),
        (
            "creep g 0.5, τ 0.05 s",
            &["viscoelasticity"],
            vec![Effect::Creep {
                g: 0.5,
                tau_s: 0.05,
            }],
            false,
        ),
        (
            "creep g 0.3, τ 0.1 s",
            &["viscoelasticity"],
            vec![Effect::Creep { g: 0.3, tau_s: 0.1 }],
            false,
        ),
        (
            "creep g 1, τ 0.05 s",
            &["viscoelasticity"],
            vec![Effect::Creep {
                g: 1.0,
                tau_s: 0.05,
            }],
            false,
        ),
        (
            "support springs 700 N/m",
            &["support-slip"],
            vec![Effect::SupportSlip(700.0)],
            true,
        ),
        (
            "support springs 1000 N/m",
            &["support-slip"],
            vec![Effect::SupportSlip(1000.0)],
            true,
        ),
        (
            "friction μ 0.1",
            &["probe-friction"],
            vec![Effect::Friction(0.1)],
            true,
        ),
        (
            "gravity ρ 1000 + clock offset 0.1 s",
            &["gravity-preload", "clock-offset"],
            vec![Effect::Gravity(1000.0), Effect::ClockOffset(0.1)],
            false,
        ),
        (
            "support springs 500 N/m + clock offset 0.1 s",
            &["support-slip", "clock-offset"],
            vec![Effect::SupportSlip(500.0), Effect::ClockOffset(0.1)],
            true,
        ),
    ];
    println!(
        "| session (truth) | first protocol: verdict, candidates | next experiment (predicted difference, mm) | re-recorded: verdict |"
    );
    println!("|---|---|---|---|");
    for (name, truth, effects, oblique) in cases {
        if filter.is_some_and(|f| !name.contains(f)) {
            continue;
        }
        let s = session_with(&effects, oblique, &LOCATIONS, 100);
        let mut sim = simulator(20e3);
        let Ok(run) = diagnose(&s.rec, &mut sim, &DiagnoseSettings::default()) else {
            println!("| {name} | error | | |");
            continue;
        };
        let d = run.diagnosis;
        eprintln!("{name}:");
        print_ranked(&d);
        let cands: Vec<&str> = d.candidates.iter().map(|c| c.hypothesis.as_str()).collect();
        eprintln!("{name}: {} {:?} {:?}", d.verdict, cands, d.next_experiment);
        let Some(next) = d.next_experiment else {
            println!(
                "| {name} ({truth:?}) | `{}` {:?} | – | – |",
                d.verdict, cands
            );
            continue;
        };
        let protocol = Protocol::ALL
            .into_iter()
            .find(|p| p.name() == next.protocol)
            .unwrap_or(Protocol::LongerHolds);
        let s2 = session_planned(&effects, oblique, &LOCATIONS, 100, Some(protocol));
        let (verdict2, decided) = match diagnose(&s2.rec, &mut sim, &DiagnoseSettings::default()) {
            Ok(r) => {
                eprintln!("{name}, re-recorded under {}:", next.protocol);
                print_ranked(&r.diagnosis);
                let mut named: Vec<&str> = r
                    .diagnosis
                    .effects
                    .iter()
                    .map(|e| e.hypothesis.as_str())
                    .collect();
                named.sort();
                let mut want = truth.to_vec();
                want.sort();
                let v = format!("{} {named:?}", r.diagnosis.verdict);
                (v, named == want)
            }
            Err(e) => (format!("error: {e}"), false),
        };
        println!(
            "| {name} ({truth:?}) | `{}`: {} | `{}` ({:.4} vs {:.4} recorded) | `{verdict2}` {} |",
            d.verdict,
            cands.join(", "),
            next.protocol,
            1e3 * next.predicted_difference_m,
            1e3 * next.recorded_difference_m,
            if decided { "✓" } else { "✗" }
        );
    }
}

/// The look-alike pairs of issue 37 (those whose name contains `filter`): the first truth under
/// the standard protocol, and when `inconclusive` both truths re-recorded under the suggested
/// protocol ([`lookalike_chain`]).
#[cfg(not(test))]
fn lookalike_table(filter: Option<&str>) {
    let plastic = LOOKALIKE_PLASTIC;
    let cases: Vec<(&str, Vec<Effect>, Vec<Effect>, bool, View)> = vec![
        (
            "slow creep g 1, τ 2 s / plasticity",
            slow_creep(1.0, 2.0),
            vec![plastic],
            false,
            View::All,
        ),
        (
            "slow creep g 0.5, τ 4 s / plasticity",
            slow_creep(0.5, 4.0),
            vec![plastic],
            false,
            View::All,
        ),
        (
            "slow creep g 0.3, τ 4 s / plasticity",
            slow_creep(0.3, 4.0),
            vec![plastic],
            false,
            View::All,
        ),
        (
            "slow creep g 1, τ 5 s / plasticity",
            slow_creep(1.0, 5.0),
            vec![plastic],
            false,
            View::All,
        ),
        (
            "slow creep g 2, τ 10 s / plasticity",
            slow_creep(2.0, 10.0),
            vec![plastic],
            false,
            View::All,
        ),
        (
            "support springs 700 N/m / friction μ 0.2",
            vec![Effect::SupportSlip(700.0)],
            vec![Effect::Friction(0.2)],
            true,
            View::All,
        ),
        (
            "friction μ 0.2 / support springs 700 N/m",
            vec![Effect::Friction(0.2)],
            vec![Effect::SupportSlip(700.0)],
            true,
            View::All,
        ),
        (
            "top view: friction μ 0.1 / support springs 700 N/m",
            vec![Effect::Friction(0.1)],
            vec![Effect::SupportSlip(700.0)],
            true,
            View::Top,
        ),
        (
            "top view: friction μ 0.2 / support springs 700 N/m",
            vec![Effect::Friction(0.2)],
            vec![Effect::SupportSlip(700.0)],
            true,
            View::Top,
        ),
        (
            "top view: support springs 700 N/m / friction μ 0.2",
            vec![Effect::SupportSlip(700.0)],
            vec![Effect::Friction(0.2)],
            true,
            View::Top,
        ),
        (
            "top view: support springs 1500 N/m / friction μ 0.1",
            vec![Effect::SupportSlip(1500.0)],
            vec![Effect::Friction(0.1)],
            true,
            View::Top,
        ),
        (
            "top view: friction μ 0.05 / support springs 1500 N/m",
            vec![Effect::Friction(0.05)],
            vec![Effect::SupportSlip(1500.0)],
            true,
            View::Top,
        ),
        (
            "top view: friction μ 0.07 / support springs 1000 N/m",
            vec![Effect::Friction(0.07)],
            vec![Effect::SupportSlip(1000.0)],
            true,
            View::Top,
        ),
        (
            "top view: support springs 1000 N/m / friction μ 0.1",
            vec![Effect::SupportSlip(1000.0)],
            vec![Effect::Friction(0.1)],
            true,
            View::Top,
        ),
        (
            "anisotropy 2.5 / friction μ 0.2",
            vec![Effect::Anisotropic(2.5)],
            vec![Effect::Friction(0.2)],
            true,
            View::All,
        ),
        (
            "anisotropy 5 / friction μ 0.2",
            vec![Effect::Anisotropic(5.0)],
            vec![Effect::Friction(0.2)],
            true,
            View::All,
        ),
        (
            "top view: support springs 2500 N/m / friction μ 0.05",
            vec![Effect::SupportSlip(2500.0)],
            vec![Effect::Friction(0.05)],
            true,
            View::Top,
        ),
    ];
    for (name, a, b, oblique, view) in cases {
        if filter.is_some_and(|f| !name.contains(f)) {
            continue;
        }
        let t0 = std::time::Instant::now();
        let chain = lookalike_chain(&a, &b, oblique, &LOCATIONS, view);
        report_chain(name, &chain, t0.elapsed().as_secs_f64());
    }
}

/// One look-alike chain: its diagnoses' ranked rows, the candidates and every protocol's
/// predicted difference on stderr; its table row on stdout.
#[cfg(not(test))]
fn report_chain(name: &str, chain: &LookalikeChain, secs: f64) {
    let d = &chain.first;
    let cands: Vec<&str> = d.candidates.iter().map(|c| c.hypothesis.as_str()).collect();
    eprintln!("{name}, first protocol: {} {cands:?}", d.verdict);
    print_ranked(d);
    for c in &d.candidates {
        eprintln!(
            "  candidate {} after {:.4} mm confidence {:.3} fold gains {:?} {:?}",
            c.hypothesis,
            1e3 * c.heldout_rmse_after_m,
            c.confidence,
            c.fold_gains,
            c.params
        );
    }
    let next = d.next_experiment.as_ref();
    if let Some(n) = next {
        let each: Vec<(&str, f64)> = n
            .protocols
            .iter()
            .map(|p| (p.protocol.as_str(), 1e3 * p.predicted_difference_m))
            .collect();
        eprintln!("  predicted differences, mm: {each:?}");
    }
    match (&chain.next, next) {
        (Some((p, again, reverse)), Some(n)) => {
            for (what, r) in [("same truth", again), ("other truth", reverse)] {
                eprintln!(
                    "{name}, {what} re-recorded under {}: {}",
                    p.name(),
                    r.verdict
                );
                print_ranked(r);
            }
            println!(
                "| {name} | `{}` {cands:?} | `{}` ({:.4} mm vs {:.4} recorded) | `{}` / `{}` | {secs:.0} s |",
                d.verdict,
                p.name(),
                1e3 * n.predicted_difference_m,
                1e3 * n.recorded_difference_m,
                again.verdict,
                reverse.verdict,
            );
        }
        _ => println!(
            "| {name} | `{}` {cands:?} | – | – | {secs:.0} s |",
            d.verdict
        ),
    }
}

/// Truths from a spec, `;`-separated effects, each a name and its numbers: `lag τ`, `offset δ`,
/// `creep g τ`, `slow-creep g τ` ([`slow_creep`]), `gravity ρ`, `friction μ`, `springs k`,
/// `plastic σ_y H` (Pa), `anisotropy ratio`, `stiffer s`.
#[cfg(not(test))]
fn parse_effects(spec: &str) -> Result<Vec<Effect>, String> {
    let mut out = Vec::new();
    for part in spec.split(';').map(str::trim).filter(|p| !p.is_empty()) {
        let mut words = part.split_whitespace();
        let name = words.next().unwrap_or_default();
        let x: Vec<f64> = words
            .map(|w| {
                w.parse()
                    .map_err(|_| format!("{part:?}: {w:?} is not a number"))
            })
            .collect::<Result<_, _>>()?;
        let effects = match (name, x.as_slice()) {
            ("lag", &[tau]) => vec![Effect::SensorLag(tau)],
            ("offset", &[delta]) => vec![Effect::ClockOffset(delta)],
            ("creep", &[g, tau_s]) => vec![Effect::Creep { g, tau_s }],
            ("slow-creep", &[g, tau_s]) => slow_creep(g, tau_s),
            ("gravity", &[rho]) => vec![Effect::Gravity(rho)],
            ("friction", &[mu]) => vec![Effect::Friction(mu)],
            ("springs", &[k]) => vec![Effect::SupportSlip(k)],
            ("plastic", &[yield_pa, hardening_pa]) => vec![Effect::Plastic {
                yield_pa,
                hardening_pa,
            }],
            ("anisotropy", &[ratio]) => vec![Effect::Anisotropic(ratio)],
            ("stiffer", &[scale]) => vec![Effect::Stiffer(scale)],
            ("damping", &[beta_s]) => vec![Effect::Damping(beta_s)],
            _ => {
                return Err(format!(
                    "{part:?}: one of lag τ, offset δ, creep g τ, slow-creep g τ, gravity ρ, \
                     friction μ, springs k, plastic σ_y H, anisotropy ratio, stiffer s, damping β"
                ));
            }
        };
        out.extend(effects);
    }
    Ok(out)
}

/// One look-alike chain from specs ([`parse_effects`]): `lookalike-spec A B [oblique] [top]`.
#[cfg(not(test))]
fn lookalike_spec(args: &[String]) -> Result<(), String> {
    let [a, b, flags @ ..] = args else {
        return Err("lookalike-spec A B [oblique] [top]".into());
    };
    if let Some(f) = flags
        .iter()
        .find(|f| !["oblique", "top"].contains(&f.as_str()))
    {
        return Err(format!("flag {f:?}: one of oblique, top"));
    }
    let oblique = flags.iter().any(|f| f == "oblique");
    let view = match flags.iter().any(|f| f == "top") {
        true => View::Top,
        false => View::All,
    };
    let (ea, eb) = (parse_effects(a)?, parse_effects(b)?);
    let t0 = std::time::Instant::now();
    let chain = lookalike_chain(&ea, &eb, oblique, &LOCATIONS, view);
    report_chain(&format!("{a} / {b}"), &chain, t0.elapsed().as_secs_f64());
    Ok(())
}
