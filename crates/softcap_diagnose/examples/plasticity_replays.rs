//! Where the plasticity confirmation's rigid-tip replays stand against the recording: J2 replays
//! (`Extension::Plastic` / `PlasticPoisson`, the hypothesis's rigid-tip grid or given points) and
//! force-driven J2 sequences on chosen meshes, each scored on the hypothesis's cells
//! (released frames, markers near a touched location) as the confirmation scores it: the RMS to
//! the measured markers over every scored cell, and the sums per location fold (a = Σ u·u,
//! b = Σ u·v, c = Σ v·v, n; u the candidate's displacement from the unloaded model's markers,
//! v the measured one) from which `confirm`'s leave-one-location-out choice is recomputed offline.
//!
//! ```sh
//! cargo run --profile test -p softcap_diagnose --example plasticity_replays -- \
//!     capture.mcap material.mcap MESH [MESH ...] [-- POINT ...]
//! ```
//! MESH: `fit`, `bisN` (bisected to N × the tets, `ProbeSimulator::bisected`), `ref8` (1 → 8),
//! `local:F:S` (refined inside the touched balls scaled by S to a longest edge of F × the fit
//! mesh's longest, `FemProbeSimulator::refined_near`), `localmm:L:S` (the same to a longest edge
//! of L mm); `A+B` applies B to A's result (`ref8+localmm:1:0.6`); `quad`: the rigid-tip J2
//! replays on the 10-node tets of the mesh so far (`FemProbeSimulator::quadratic`, small-strain
//! kinematics; markers by the 10-node shape functions in their linear-mesh tets; the last step).
//! POINT: `r:SY:H:NU` a rigid-tip replay
//! (σ_y and H as fractions of the peak contact pressure, NU a Poisson ratio or `fit`),
//! `f:SY:H` a force-driven sequence, `none` (the meshes only); default: the hypothesis's eight
//! rigid-tip points.

use softcap_diagnose::hypotheses::Hypothesis;
use softcap_diagnose::hypotheses::plasticity::Plasticity;
use softcap_diagnose::nalgebra::Vector3;
use softcap_diagnose::{
    Extension, FemProbeSimulator, FemSimSettings, MaterialSource, Recording, SegmentSettings,
    Segmentation, contact_sequence, pose_sequence, read_material_from, recording_from_capture,
};
use softcap_fem::TipShape;
use softcap_mcap::capture::CaptureData;

/// CPU seconds of this process (user + system, every thread).
fn cpu_s() -> f64 {
    softcap_app::process::cpu_seconds().unwrap_or(f64::NAN)
}

type Field = Vec<Vec<Vector3<f64>>>;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 4 {
        return Err(
            "usage: plasticity_replays capture.mcap material.mcap MESH [MESH ...] [-- POINT ...]"
                .into(),
        );
    }
    let cap = CaptureData::read(&a[1])?;
    let material = read_material_from(a[2].as_ref(), MaterialSource::Homogeneous)?;
    let rec: Recording = recording_from_capture(&cap, &material.mesh)?;
    let split = a.iter().position(|s| s == "--").unwrap_or(a.len());
    let meshes: Vec<&str> = a[3..split].iter().map(String::as_str).collect();
    let mut points: Vec<String> = a.iter().skip(split + 1).cloned().collect();
    if points.is_empty() {
        for nu in ["fit", "0.45"] {
            for sy in ["0.3", "0.4"] {
                for hh in ["0.2", "0.5"] {
                    points.push(format!("r:{sy}:{hh}:{nu}"));
                }
            }
        }
    }
    let support = rec.support.ok_or("no support plane")?;
    let fixed = support.nodes(&material.mesh);
    let seg = Segmentation::new(&rec, &SegmentSettings::default());
    let cells = Plasticity
        .effect_cells(&rec, &seg)
        .ok_or("no effect cells")?;
    let r_tip = rec.tip_radius_m.max(1e-4);
    let pressure_pa = seg.peak_force_n() / (std::f64::consts::PI * r_tip * r_tip);
    let mut settings = FemSimSettings::default();
    if let Some(load) = material.footprint_load {
        settings.patch.load = load;
    }
    let tip = match cap.session.tip_shape.as_str() {
        "sphere" => TipShape::Sphere {
            radius_m: cap.session.tip_radius_m,
        },
        _ => TipShape::Disk {
            radius_m: cap.session.tip_radius_m,
            thickness_m: cap.session.tip_radius_m,
        },
    };
    let build = || -> Result<FemProbeSimulator, Box<dyn std::error::Error>> {
        Ok(FemProbeSimulator::new(
            &material.mesh,
            material.model.clone(),
            &fixed,
            &rec.rest_markers_m,
            settings.clone(),
        )?
        .with_support_plane(&support.normal, support.offset_m)
        .with_rigid_tip(tip.clone()))
    };
    let base = build()?;
    let rest = base.rest_markers_m();
    let (e_fit, nu_fit) = material
        .model
        .params()
        .first()
        .ok_or("no material")?
        .to_young_poisson()?;
    let nf = seg.num_folds();
    println!(
        "pressure {pressure_pa:.0} Pa, fit E {e_fit:.0} Pa nu {nu_fit:.4}, {} tets, longest edge {:.2} mm, {nf} folds, {} scored cells",
        material.mesh.tets.len(),
        base.longest_edge_m() * 1e3,
        cells.mask.iter().flatten().filter(|&&b| b).count()
    );
    // per fold bucket (nf: no fold) sums a, b, c, n over the scored cells
    let sums = |x: &Field| {
        let mut s = vec![[0.0f64; 4]; nf + 1];
        for (k, f) in rec.frames.iter().enumerate() {
            let Some(l) = seg.fold_of_frame[k] else {
                continue;
            };
            for (m, y) in f.markers_m.iter().enumerate() {
                let Some(y) = y else { continue };
                if !cells.mask[k][m] {
                    continue;
                }
                let (u, v) = (x[k][m] - rest[m], y - rest[m]);
                s[l][0] += u.norm_squared();
                s[l][1] += u.dot(&v);
                s[l][2] += v.norm_squared();
                s[l][3] += 1.0;
            }
        }
        s
    };
    for l in &seg.locations {
        let deepest = l
            .contact_frames
            .iter()
            .map(|&k| rec.frames[k].tip_m)
            .min_by(|a, b| a.z.total_cmp(&b.z))
            .unwrap_or(l.peak_tip_m);
        println!(
            "location {}: peak tip {:.3?} mm, deepest tip {:.3?} mm, {} contact frames",
            l.index,
            (l.peak_tip_m * 1e3).as_slice(),
            (deepest * 1e3).as_slice(),
            l.contact_frames.len()
        );
    }
    for spec in meshes {
        let (c0, t0) = (cpu_s(), std::time::Instant::now());
        // `+` chains refinements, each applied to the previous one's result
        let mut sim = build()?;
        for step in spec.split('+') {
            sim = if step == "quad" {
                sim.quadratic()?
            } else if step == "fit" {
                sim
            } else if step == "ref8" {
                sim.refined()?
            } else if let Some(n) = step.strip_prefix("bis") {
                sim.bisected(n.parse()?)?
            } else if let Some(rest) = step
                .strip_prefix("local:")
                .or_else(|| step.strip_prefix("localmm:"))
            {
                let v: Vec<f64> = rest.split(':').map(str::parse).collect::<Result<_, _>>()?;
                let balls: Vec<_> = softcap_diagnose::cells::touched_balls(&rec, &seg)
                    .into_iter()
                    .map(|b| softcap_mesh::RefineBall {
                        radius_m: b.radius_m * v[1],
                        ..b
                    })
                    .collect();
                let edge_m = if step.starts_with("localmm:") {
                    v[0] * 1e-3
                } else {
                    v[0] * base.longest_edge_m()
                };
                sim.refined_near(&balls, edge_m, 400_000)?
            } else {
                return Err(format!("unknown mesh {step}").into());
            };
        }
        let tips: Vec<Vector3<f64>> = seg.locations.iter().map(|l| l.peak_tip_m).collect();
        println!(
            "MESH {spec}: {} tets, {} nodes, surface spacing near the tips {:.2} mm, built in {:.1} CPU-s",
            sim.model().params().len(),
            sim.setup().mesh.vertices.len(),
            softcap_diagnose::sim::surface_spacing_near(&sim.setup().mesh, r_tip, &tips)
                .unwrap_or(f64::NAN)
                * 1e3,
            cpu_s() - c0
        );
        for pt in points.iter().filter(|p| *p != "none") {
            let f: Vec<&str> = pt.split(':').collect();
            let (sy, hh) = (f[1].parse::<f64>()?, f[2].parse::<f64>()?);
            let (yield_stress_pa, hardening_pa) = (sy * pressure_pa, hh * pressure_pa);
            let (c1, t1) = (cpu_s(), std::time::Instant::now());
            let x = if f[0] == "r" {
                let ext = match f.get(3).copied() {
                    None | Some("fit") => Extension::Plastic {
                        yield_stress_pa,
                        hardening_pa,
                    },
                    Some(nu) => Extension::PlasticPoisson {
                        yield_stress_pa,
                        hardening_pa,
                        poisson: nu.parse()?,
                    },
                };
                sim.simulate_sequence_rigid_tip(&ext, &pose_sequence(&rec))?
                    .ok_or("no rigid tip")?
            } else {
                let ext = Extension::Plastic {
                    yield_stress_pa,
                    hardening_pa,
                };
                let forces: Vec<Vector3<f64>> = rec.frames.iter().map(|f| f.force_n).collect();
                sim.simulate_sequence(&ext, &contact_sequence(&rec, &seg, &forces))?
            };
            let s = sums(&x);
            let t: [f64; 4] = s.iter().fold([0.0; 4], |acc, q| {
                [acc[0] + q[0], acc[1] + q[1], acc[2] + q[2], acc[3] + q[3]]
            });
            let rms = |d: f64| ((t[2] - 2.0 * d * t[1] + d * d * t[0]).max(0.0) / t[3]).sqrt();
            let d_best = if t[0] > 0.0 { t[1] / t[0] } else { 1.0 };
            println!(
                "CAND {spec} {pt} rms_d1 {:.4} mm, d* {d_best:.3} rms_d* {:.4} mm, {:.1} CPU-s {:.1} s | {}",
                rms(1.0) * 1e3,
                rms(d_best) * 1e3,
                cpu_s() - c1,
                t1.elapsed().as_secs_f64(),
                s.iter()
                    .map(|q| format!("{:.6e},{:.6e},{:.6e},{}", q[0], q[1], q[2], q[3]))
                    .collect::<Vec<_>>()
                    .join(";")
            );
        }
        println!(
            "MESH {spec} done: {:.1} CPU-s, {:.1} s wall",
            cpu_s() - c0,
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
