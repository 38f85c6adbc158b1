//! What one rigid-tip J2 replay of the plasticity confirmation costs on a recorded session, and
//! how far a faster replay's markers move from the reference: the replay `confirm` runs
//! (`Extension::Plastic`, σ_y = 0.3 and H = 0.2 of the peak contact pressure) on the fit mesh
//! refined 1 → 8, at the session's measured poses, once per refactorization policy
//! (`FemSimSettings::replay_refactorization`: `every`, `step`, `stale`), with the contact active set
//! frozen after N equilibrium iterations instead of 12 (`freezeN`,
//! `EquilibriumSettings::contact_freeze_after`), with the mesh refined only inside the touched
//! balls (`local`) or on the fit mesh itself (`coarse`), with CPU seconds and the largest marker difference to the first policy.
//! With `REPLAY_MU=μ` in the environment, the frictional replay of `probe-friction` at μ instead.
//!
//! ```sh
//! cargo run --profile test -p softcap_diagnose --example replay_cost -- \
//!     capture.mcap material.mcap [frames] [every|step|stale|freezeN|local|coarse ...]
//! ```

use softcap_diagnose::{
    Extension, FemProbeSimulator, FemSimSettings, MaterialSource, Phase, Recording,
    SegmentSettings, Segmentation, pose_sequence, read_material_from, recording_from_capture,
};
use softcap_fem::{Refactorization, TipShape};
use softcap_mcap::capture::CaptureData;

/// CPU seconds of this process (user + system, every thread), from /proc/self/stat.
fn cpu_s() -> f64 {
    softcap_app::process::cpu_seconds().unwrap_or(f64::NAN)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    run(std::env::args().collect())
}

/// `main` under the test harness (`cargo test --profile test -p softcap_e2e -p softcap_diagnose
/// --example replay_cost --no-run` builds it with the test build's dependencies):
/// `REPLAY_COST_ARGS="capture.mcap material.mcap [frames] [policies]" replay_cost-HASH --ignored`.
#[test]
#[ignore = "a measuring aid: needs REPLAY_COST_ARGS"]
fn replay_cost_from_env() {
    let args = std::env::var("REPLAY_COST_ARGS").expect("REPLAY_COST_ARGS");
    let a = std::iter::once("replay_cost".to_string())
        .chain(args.split_whitespace().map(String::from))
        .collect();
    run(a).unwrap();
}

fn run(a: Vec<String>) -> Result<(), Box<dyn std::error::Error>> {
    if a.len() < 3 {
        return Err(
            "usage: replay_cost capture.mcap material.mcap [frames] [every|step|stale|freezeN|local|coarse ...]".into(),
        );
    }
    let cap = CaptureData::read(&a[1])?;
    let material = read_material_from(a[2].as_ref(), MaterialSource::Homogeneous)?;
    let mut rec: Recording = recording_from_capture(&cap, &material.mesh)?;
    if let Some(n) = a.get(3).and_then(|v| v.parse::<usize>().ok()) {
        rec.frames.truncate(n.max(2));
    }
    let policies: Vec<&str> = a.iter().skip(4).map(String::as_str).collect();
    let policies = if policies.is_empty() {
        vec!["every", "stale"]
    } else {
        policies
    };
    let support = rec.support.ok_or("no support plane")?;
    let fixed = support.nodes(&material.mesh);
    let seg = Segmentation::new(&rec, &SegmentSettings::default());
    let r_tip = rec.tip_radius_m.max(1e-4);
    let pressure_pa = seg.peak_force_n() / (std::f64::consts::PI * r_tip * r_tip);
    let ext = Extension::Plastic {
        yield_stress_pa: 0.3 * pressure_pa,
        hardening_pa: 0.2 * pressure_pa,
    };
    // REPLAY_MU=μ: the frictional replay of `probe-friction` (`Extension::ProbeFriction`, on the
    // fit mesh refined as `friction_refinement` asks on top of the policy's mesh) instead
    let ext = match std::env::var("REPLAY_MU") {
        Ok(mu) => Extension::ProbeFriction { mu: mu.parse()? },
        Err(_) => ext,
    };
    let frames = pose_sequence(&rec);
    let mut reference: Option<Vec<Vec<softcap_diagnose::nalgebra::Vector3<f64>>>> = None;
    for policy in policies {
        let mut settings = FemSimSettings::default();
        if let Some(load) = material.footprint_load {
            settings.patch.load = load;
        }
        // "freezeN": the contact active set frozen after N equilibrium iterations (default 12)
        if let Some(n) = policy
            .strip_prefix("freeze")
            .and_then(|n| n.parse::<usize>().ok())
        {
            settings.equilibrium.contact_freeze_after = n;
        }
        settings.replay_refactorization = match policy {
            "stale" => Refactorization::WhenStale,
            "step" => Refactorization::EveryStep,
            _ => Refactorization::EveryIteration,
        };
        let sim = FemProbeSimulator::new(
            &material.mesh,
            material.model.clone(),
            &fixed,
            &rec.rest_markers_m,
            settings,
        )?
        .with_support_plane(&support.normal, support.offset_m)
        .with_rigid_tip(TipShape::Disk {
            radius_m: cap.session.tip_radius_m,
            thickness_m: cap.session.tip_radius_m,
        });
        // "local": refined only inside the touched balls (`RefinementSettings::local`), as
        // `ProbeSimulator::refined` does with that setting
        let fine = if policy == "coarse" {
            sim
        } else if policy == "local" {
            let balls = softcap_diagnose::cells::touched_balls(&rec, &seg);
            let edge = 0.5 * sim.longest_edge_m();
            sim.refined_near(&balls, edge, 200_000)?
        } else {
            sim.refined()?
        };
        let (c0, t0) = (cpu_s(), std::time::Instant::now());
        let x = fine
            .simulate_sequence_rigid_tip(&ext, &frames)?
            .ok_or("no rigid tip")?;
        let (cpu, wall) = (cpu_s() - c0, t0.elapsed().as_secs_f64());
        // the largest marker difference over every frame, and over the released frames (where
        // the plasticity hypothesis scores a permanent set)
        let diff = |released_only: bool| {
            reference.as_ref().map_or(0.0, |r| {
                r.iter()
                    .zip(&x)
                    .enumerate()
                    .filter(|(k, _)| !released_only || seg.phases[*k] == Phase::Released)
                    .flat_map(|(_, (a, b))| a.iter().zip(b).map(|(p, q)| (p - q).norm()))
                    .fold(0.0, f64::max)
            })
        };
        println!(
            "{policy:>6}: {} frames, {} tets, {cpu:.1} CPU-s, {wall:.1} s wall, max marker difference to the first {:.3e} mm (released frames {:.3e} mm)",
            frames.len(),
            fine.model().params().len(),
            diff(false) * 1e3,
            diff(true) * 1e3
        );
        reference.get_or_insert(x);
    }
    Ok(())
}
