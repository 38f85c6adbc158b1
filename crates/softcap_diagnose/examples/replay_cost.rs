//! What one rigid-tip J2 replay of the plasticity confirmation costs on a recorded session, and
//! how far a faster replay's markers move from the reference: the replay `confirm` runs
//! (`Extension::Plastic`, σ_y = 0.3 and H = 0.2 of the peak contact pressure) on the fit mesh
//! refined 1 → 8, at the session's measured poses, once per refactorization policy
//! (`FemSimSettings::replay_refactorization`: `every`, `step`, `stale`), with the contact active set
//! frozen after N equilibrium iterations instead of 12 (`freezeN`,
//! `EquilibriumSettings::contact_freeze_after`, `FemSimSettings::friction_contact_freeze_after`), with the mesh refined only inside the touched
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
        // "freezeN": the contact active set frozen after N equilibrium iterations (default 12;
        // the frictional replay's `FemSimSettings::friction_contact_freeze_after` too), the rest
        // as `step` (the replays' default policy)
        if let Some(n) = policy
            .strip_prefix("freeze")
            .and_then(|n| n.parse::<usize>().ok())
        {
            settings.equilibrium.contact_freeze_after = n;
            settings.friction_contact_freeze_after = n;
        }
        // "fricmaxN": the frictional replay's solves capped at N iterations (default 150,
        // `FemSimSettings::friction_max_iterations`), the rest as `step`
        if let Some(n) = policy
            .strip_prefix("fricmax")
            .and_then(|n| n.parse::<usize>().ok())
        {
            settings.friction_max_iterations = n;
        }
        settings.replay_refactorization = match policy {
            "stale" => Refactorization::WhenStale,
            "step" => Refactorization::EveryStep,
            p if p.starts_with("fricmax") || p.starts_with("freeze") => Refactorization::EveryStep,
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
        // "nearK": refined only inside the touched balls with K × their radius, to a longest edge
        // there of REPLAY_NEAR_EDGE (default ½) × the surface spacing near the tips
        // (`surface_spacing_near`: the uniform 1 → 8 refinement's spacing there)
        let near = policy
            .strip_prefix("near")
            .and_then(|k| k.parse::<f64>().ok());
        let fine = if policy == "coarse" {
            sim
        } else if let Some(k) = near {
            let r = softcap_diagnose::cells::contact_radius_m(&rec);
            let balls: Vec<_> = softcap_diagnose::cells::touched_balls(&rec, &seg)
                .into_iter()
                .map(|b| softcap_mesh::RefineBall {
                    radius_m: k * b.radius_m,
                    ..b
                })
                .collect();
            let tips: Vec<_> = frames
                .iter()
                .filter_map(|f| f.load.probe.map(|p| p.tip_m))
                .collect();
            let h = softcap_diagnose::sim::surface_spacing_near(
                &material.mesh,
                cap.session.tip_radius_m,
                &tips,
            )
            .ok_or("no surface")?;
            let frac: f64 = std::env::var("REPLAY_NEAR_EDGE")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(0.5);
            println!(
                "{policy}: balls {} of radius {:.2} mm, surface spacing near the tips {:.2} mm, longest edge {:.2} mm, target edge {:.2} mm",
                balls.len(),
                k * r * 1e3,
                h * 1e3,
                sim.longest_edge_m() * 1e3,
                frac * h * 1e3
            );
            sim.refined_near(&balls, frac * h, 200_000)?
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
        // RMS marker difference to the first policy on probe-friction's effect cells (contact
        // frames, markers under the tip: `contact_cells`) and on every marker of those frames
        let cells = softcap_diagnose::cells::contact_cells(&rec, &seg, true);
        let rms = |under: bool| {
            reference.as_ref().map_or(0.0, |r| {
                let (mut s, mut n) = (0.0, 0usize);
                for (k, (a, b)) in r.iter().zip(&x).enumerate() {
                    for (m, (p, q)) in a.iter().zip(b).enumerate() {
                        let in_contact =
                            seg.fold_of_frame[k].is_some() && seg.phases[k].in_contact();
                        if (under && cells[k][m]) || (!under && in_contact) {
                            s += (p - q).norm_squared();
                            n += 1;
                        }
                    }
                }
                (s / n.max(1) as f64).sqrt()
            })
        };
        println!(
            "{policy:>6}: rms marker difference to the first on the effect cells {:.4} mm, on every marker of the contact frames {:.4} mm",
            rms(true) * 1e3,
            rms(false) * 1e3
        );
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
