//! Where the default model's floor comes from (docs/diagnose.md, "Session 11 (lead)"): a suite
//! session's recording against several models of it, each model's residual RMS on the probed
//! markers per phase and on the contact frames' markers near / away from the tip (2.5 tip radii,
//! the anisotropy / support-slip cells). A measuring harness, not a check: nothing asserted beyond
//! the chain running.
//!
//! `cargo run --release -p softcap_e2e --example diagnose_floor`, with
//! - `FLOOR_CASE=NAME` (a suite scenario, default `clean`) or `FLOOR_TOML=PATH` (any scenario, e.g.
//!   a copy of clean.toml with another `fit_cells`);
//! - `FLOOR_MATERIAL=E_PA,NU` a homogeneous material instead of the tissue fit's;
//! - `FLOOR_LOAD=consistent | flat-punch | hertz` the footprint-consistent loads of a uniform,
//!   a rigid flat punch's (Sneddon) or a rigid sphere's (Hertz) pressure instead of the default
//!   (`softcap_probing::FootprintLoad`; default: the load material.mcap was fitted under,
//!   which this does not refit);
//! - `FLOOR_LEVELS=N` 1 → 8 refinements of the template for the refined models (default 1);
//! - `FLOOR_WHICH` a subset of `abcd` (a: force BC, b: rigid-tip replay, c / d: the same on the
//!   refined template; default all);
//! - `FLOOR_PRONY=G,TAU_S` every model extended by one Prony branch
//!   (`Extension::Viscoelastic`: the viscoelasticity oracle with the truth's g, τ);
//! - `FLOOR_SCALE=1` also prints each model with the compliance scale d = Σu·v / Σu·u fitted on
//!   every observation (the material's overall stiffness refit, in-sample);
//! - `FLOOR_FRAMES=1` also prints, per frame of a location: its phase, the measured force, the
//!   force's share across the probe axis, the measured and simulated mean displacement along the
//!   axis, the residual RMS (all components, and along the axis) — over the markers within 2.5
//!   tip radii of the location's axis — and the measured tip (docs/diagnose.md, session 12);
//! - `FLOOR_TRUTH=DIR/truth/markers.csv` also scores the synthetic truth's own marker tracks
//!   (the capture's error: `softcap synth` the same scenario to DIR first);
//! - `FLOOR_MU=0.5,0.8,...` instead of the above, the frictional rigid-tip replay
//!   (`Extension::ProbeFriction`) at each μ on the refined template (`FLOOR_LOCAL=F[:S]`: locally,
//!   as `SOFTCAP_SUITE_REFINE=local:F:S`, also for the refined models c / d), each location's RMS on the probe-friction effect cells
//!   (`spatial::effect_mask`) at compliance 1, split by phase and normal / tangential component
//!   (docs/diagnose.md, "Session 12 (fric)"); `FLOOR_FRAMES=1` adds per contact frame the scored
//!   markers' mean measured and simulated displacement along the location's tangential travel;
//! - `FLOOR_QUAD=K` the frictional replay's contact at quadrature points, K² sub-triangles of
//!   3 points per boundary triangle (`softcap_fem::ContactDiscretisation::Quadrature`; 0: at the
//!   nodes, the default; docs/diagnose.md session 14 (fric));
//! - `FLOOR_PENALTY=P` the rigid-tip replays' contact penalty factor (`FemSimSettings::
//!   rigid_tip_contact`, a multiple of a contact node's mean diagonal stiffness; default 10⁴, the
//!   diagnosis' rigid tip; the suite's probe-friction truth uses 100) — for the frictional replay
//!   of `FLOOR_MU` and the rigid-tip models b / d alike (docs/diagnose.md session 14 (fric2));
//! - `FLOOR_SLIP=F` the frictional replay's regularization slip as a fraction of the surface node
//!   spacing near the tips (`FemSimSettings::friction_slip_fraction`, default 0.1; 0 = the law's
//!   10 µm; docs/diagnose.md session 15 (lead));
//! - `FLOOR_TRACTION=MU,C` adds the Coulomb return-mapping traction (`friction::traction_history`,
//!   μ, tangential stiffness C × the indentation stiffness) to every measured force (force BC only);
//!   every model also prints its "contact near" RMS per location;
//! - `FLOOR_EXT=ti:FX,FY,FZ,RATIO,NU_T,NU_A` simulates the transversely isotropic extension
//!   (`Extension::TransverselyIsotropic` over the model's E) instead of the elastic default — the
//!   anisotropy oracle with the truth's fibre and ratio (instead of `FLOOR_PRONY`);
//! - `FLOOR_EXT=dyn:RHO,ALPHA,BETA[,LAME]` the dynamic replay (`Extension::Dynamic`: density
//!   kg/m³, Rayleigh α 1/s, β s, Lamé ratio factor, default 1) instead — the inertia-damping oracle with the truth's values;
//! - `FLOOR_LAT=C,DX,DY,DZ` adds a lateral traction C‖f‖ along (DX, DY, DZ) to every measured
//!   force (force BC only: the reaction an axial force sensor does not see);
//! - `FLOOR_TRUTH_TIP=DIR/truth/probe.csv` replays the rigid tip at the synthetic truth's tip
//!   positions instead of the captured ones;
//! - `FLOOR_FORCE=DIR/truth/probe.csv` drives the force-BC models with the synthetic truth's probe
//!   force instead of the measured one (a force-channel effect — sensor-lag, clock-offset —
//!   undone exactly: the best any model of the sensor can reach);
//! - `SOFTCAP_SUITE_CACHE=DIR` reuses synth / capture / tissue fit (tests/common).
//!
//! Always printed: the hold fit (`temporal::hold_relaxation`, the Prony grids' centre).

#[path = "../tests/common/mod.rs"]
mod common;

use softcap_diagnose::nalgebra::Vector3;
use softcap_diagnose::{
    Extension, FemProbeSimulator, FemSimSettings, Hypothesis, MaterialSource, Phase, Region,
    SegmentSettings, Segmentation, SequenceFrame, contact_sequence, pose_sequence,
    read_material_from, recording_from_capture, residuals,
};
use softcap_fem::{CorotationalModel, LinearParams, TipShape};
use softcap_mcap::capture::CaptureData;
use softcap_synth::Scenario;
use std::time::Instant;

fn main() {
    let env = |k: &str| std::env::var(k).ok();
    let name = env("FLOOR_CASE").unwrap_or_else(|| "clean".into());
    let path = env("FLOOR_TOML")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| common::suite_dir().join(format!("{name}.toml")));
    let scenario = Scenario::load(&path).unwrap();
    let inputs = common::prepare_inputs(&scenario);
    let cap = CaptureData::read(&inputs.capture).unwrap();
    let material = read_material_from(&inputs.material, MaterialSource::Homogeneous).unwrap();
    let rec = recording_from_capture(&cap, &material.mesh).unwrap();
    let support = rec.support.expect("a support plane");
    let fixed = support.nodes(&material.mesh);
    let mut settings = FemSimSettings::default();
    // The load the material was fitted under (material.mcap), as the diagnosis replays it.
    if let Some(load) = material.footprint_load {
        settings.patch.load = load;
    }
    if let Some(load) = env("FLOOR_LOAD") {
        settings.patch.load =
            softcap_probing::FootprintLoad::from_name(&load).unwrap_or_else(|| {
                panic!("FLOOR_LOAD={load}: lumped | consistent | flat-punch | hertz")
            });
    }
    if let Some(k) = env("FLOOR_QUAD") {
        settings.friction_contact = match k.parse::<usize>().expect("FLOOR_QUAD=K") {
            0 => softcap_fem::ContactDiscretisation::Nodes,
            k => softcap_fem::ContactDiscretisation::Quadrature { subdivisions: k },
        };
    }
    if let Some(p) = env("FLOOR_PENALTY") {
        settings.rigid_tip_contact.penalty_factor = p.parse().expect("FLOOR_PENALTY=P");
    }
    if let Some(e) = env("FLOOR_SLIP") {
        settings.friction_slip_fraction = e.parse().expect("FLOOR_SLIP=FRACTION");
    }
    if let Some(l) = env("FLOOR_LOCAL") {
        let (f, s) = l.split_once(':').unwrap_or((&l, "1"));
        settings.refinement.local = true;
        settings.refinement.edge_fraction = f.parse().unwrap();
        settings.refinement.radius_scale = s.parse().unwrap();
    }
    let mut model = material.model.clone();
    println!(
        "FLOOR {} tets, tissue fit (E, nu) = {:?} under {:?} loads, replayed under {}; rigid tip: penalty factor {:e}, friction contact {:?}",
        material.mesh.tets.len(),
        model.params()[0].to_young_poisson(),
        material.footprint_load,
        settings.patch.load.name(),
        settings.rigid_tip_contact.penalty_factor,
        settings.friction_contact
    );
    if let Some(v) = env("FLOOR_MATERIAL") {
        let (e, nu) = v.split_once(',').expect("FLOOR_MATERIAL=E_PA,NU");
        let p = LinearParams::from_young_poisson(e.parse().unwrap(), nu.parse().unwrap()).unwrap();
        model = CorotationalModel::homogeneous(&material.mesh, p).unwrap();
    }
    let r = cap.session.tip_radius_m;
    let tip = match cap.session.tip_shape.as_str() {
        "sphere" => TipShape::Sphere { radius_m: r },
        _ => TipShape::Disk {
            radius_m: r,
            thickness_m: r,
        },
    };
    let sim = FemProbeSimulator::new(&material.mesh, model, &fixed, &rec.rest_markers_m, settings)
        .unwrap()
        .with_support_plane(&support.normal, support.offset_m)
        .with_rigid_tip(tip);
    let seg = Segmentation::new(&rec, &SegmentSettings::default());
    // the held force's standard-linear-solid fit (position control: it measures G(t) directly)
    println!(
        "FLOOR hold relaxation (g, tau_s) = {:?}",
        softcap_diagnose::hypotheses::viscoelasticity::hold_relaxation(&rec, &seg)
    );
    // Force BC: the measured force on the contact frames; rigid tip: every frame's measured pose
    // (the diagnosis' own sequences).
    // FLOOR_LAT=C,DX,DY,DZ: a lateral traction C·‖f‖ along the unit (DX, DY, DZ) added to every
    // frame's measured force (what an axial force sensor does not see).
    let lateral = env("FLOOR_LAT").map(|v| {
        let v: Vec<f64> = v.split(',').map(|x| x.parse().unwrap()).collect();
        v[0] * Vector3::new(v[1], v[2], v[3]).normalize()
    });
    let mut forces: Vec<Vector3<f64>> = rec
        .frames
        .iter()
        .map(|f| f.force_n + lateral.map_or(Vector3::zeros(), |l| l * f.force_n.norm()))
        .collect();
    // FLOOR_TRACTION=MU,C: the Coulomb return-mapping traction of `friction::traction_history`
    // (μ, tangential stiffness C × the indentation stiffness K) added to every measured force
    // (force BC only: the force-driven probe-friction model of the confirmation grid).
    if let Some(v) = env("FLOOR_TRACTION") {
        let (mu, c) = v.split_once(',').expect("FLOOR_TRACTION=MU,C");
        let k_ind = softcap_diagnose::friction::indentation_stiffness_n_per_m(&seg);
        let t = softcap_diagnose::friction::traction_history(
            &rec,
            &seg,
            &forces,
            mu.parse().unwrap(),
            c.parse::<f64>().unwrap() * k_ind,
        );
        for (f, t) in forces.iter_mut().zip(&t) {
            *f += t;
        }
        println!("FLOOR traction mu {mu}, k_t {c} x K = {k_ind:.1} N/m");
    }
    // FLOOR_TRUTH_TIP=DIR/truth/probe.csv: the rigid-tip replays at the synthetic truth's tip
    // positions instead of the captured ones (separates the capture's pose error from the model).
    let mut replayed = rec.clone();
    if let Some(path) = env("FLOOR_TRUTH_TIP") {
        let text = std::fs::read_to_string(path).unwrap();
        for line in text.lines().skip(1) {
            let v: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
            if let Some(f) = replayed.frames.iter_mut().find(|f| f.frame == v[0] as u64) {
                f.tip_m = Vector3::new(v[5], v[6], v[7]) * 1e-3;
            }
        }
    }
    if let Some(path) = env("FLOOR_FORCE") {
        let text = std::fs::read_to_string(path).unwrap();
        let mut replaced = 0;
        for line in text.lines().skip(1) {
            let v: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
            if let Some(k) = rec.frames.iter().position(|f| f.frame == v[0] as u64) {
                forces[k] = Vector3::new(v[2], v[3], v[4]);
                replaced += 1;
            }
        }
        println!("FLOOR force: the truth's probe force on {replaced} frames");
    }
    let frames = |every_pose: bool| -> Vec<SequenceFrame> {
        if every_pose {
            pose_sequence(&replayed)
        } else {
            contact_sequence(&rec, &seg, &forces)
        }
    };
    let rest = sim.rest_markers_m();
    let report_one = |label: &str, x: &[Vec<Vector3<f64>>]| {
        let res = residuals(&rec, x);
        let rms = |keep: &dyn Fn(usize, usize) -> bool| {
            1e3 * softcap_diagnose::residual::rms_where_m(&res, keep).unwrap_or(0.0)
        };
        let probed = |p: Phase| rms(&|k, m| seg.phases[k] == p && seg.regions[m] == Region::Probed);
        let near = |k: usize, m: usize| {
            (rec.rest_markers_m[m] - rec.frames[k].tip_m).norm() <= 2.5 * rec.tip_radius_m
        };
        let contact = |k: usize| seg.phases[k].in_contact();
        println!(
            "FLOOR {name} {label}: probed loading {:.4} hold {:.4} unloading {:.4} released {:.4} (loading+hold+released {:.4}) | contact near {:.4} away {:.4} mm",
            probed(Phase::Loading),
            probed(Phase::Hold),
            probed(Phase::Unloading),
            probed(Phase::Released),
            rms(&|k, m| {
                matches!(
                    seg.phases[k],
                    Phase::Loading | Phase::Hold | Phase::Released
                ) && seg.fold_of_frame[k].is_some()
                    && seg.regions[m] == Region::Probed
            }),
            rms(&|k, m| contact(k) && near(k, m)),
            rms(&|k, m| contact(k) && !near(k, m)),
        );
        let per: Vec<String> = (0..seg.locations.len())
            .map(|l| {
                format!(
                    "{:.4}",
                    rms(&|k, m| contact(k) && near(k, m) && seg.fold_of_frame[k] == Some(l))
                )
            })
            .collect();
        println!(
            "FLOOR {name} {label}: contact near per location {}",
            per.join(" ")
        );
    };
    let scale = env("FLOOR_SCALE").is_some();
    // (with FLOOR_MU, FLOOR_FRAMES is the friction profile's per-frame table instead)
    let per_frame = env("FLOOR_FRAMES").is_some() && env("FLOOR_MU").is_none();
    let frame_table = |label: &str, x: &[Vec<Vector3<f64>>]| {
        println!(
            "FRAMES {label}: k t_s phase force_n lateral_force_fraction measured_mm simulated_mm rms_mm axial_rms_mm (markers near the location, along the probe axis)"
        );
        for (k, f) in rec.frames.iter().enumerate() {
            let Some(l) = seg.fold_of_frame[k] else {
                continue;
            };
            let loc = &seg.locations[l];
            let (mut dm, mut ds, mut e, mut ea, mut n) = (0.0, 0.0, 0.0, 0.0, 0usize);
            for (m, y) in f.markers_m.iter().enumerate() {
                let lateral = (rest[m] - loc.peak_tip_m).cross(&loc.axis).norm();
                if let Some(y) = y
                    && lateral <= 2.5 * rec.tip_radius_m
                {
                    dm += (y - rest[m]).dot(&loc.axis);
                    ds += (x[k][m] - rest[m]).dot(&loc.axis);
                    e += (y - x[k][m]).norm_squared();
                    ea += (y - x[k][m]).dot(&loc.axis).powi(2);
                    n += 1;
                }
            }
            let n = n.max(1) as f64;
            println!(
                "FRAMES {k:3} {:.3} {:9} {:.4} {:.3} {:+.4} {:+.4} {:.4} {:.4} tip_mm {:.3} {:.3} {:.3}",
                f.time_s,
                seg.phases[k].name(),
                f.force_n.norm(),
                f.force_n.cross(&f.axis).norm() / f.force_n.norm().max(1e-12),
                1e3 * dm / n,
                1e3 * ds / n,
                1e3 * (e / n).sqrt(),
                1e3 * (ea / n).sqrt(),
                1e3 * f.tip_m.x,
                1e3 * f.tip_m.y,
                1e3 * f.tip_m.z
            );
        }
    };
    let report = |label: &str, x: &[Vec<Vector3<f64>>]| {
        report_one(label, x);
        if per_frame {
            frame_table(label, x);
        }
        if !scale {
            return;
        }
        // d = Σ u·v / Σ u·u over every observation (u simulated, v measured, from rest)
        let (mut uu, mut uv) = (0.0, 0.0);
        for (f, row) in rec.frames.iter().zip(x) {
            for ((y, xm), r) in f.markers_m.iter().zip(row).zip(&rest) {
                if let Some(y) = y {
                    uu += (xm - r).norm_squared();
                    uv += (xm - r).dot(&(y - r));
                }
            }
        }
        let d = if uu > 0.0 { uv / uu } else { 1.0 };
        let scaled: Vec<Vec<Vector3<f64>>> = x
            .iter()
            .map(|row| {
                row.iter()
                    .zip(&rest)
                    .map(|(xm, r)| r + (xm - r) * d)
                    .collect()
            })
            .collect();
        report_one(&format!("{label}, compliance x{d:.3}"), &scaled);
    };
    if let Some(path) = env("FLOOR_TRUTH") {
        let text = std::fs::read_to_string(path).unwrap();
        let mut truth = vec![sim.rest_markers_m(); rec.frames.len()];
        for line in text.lines().skip(1) {
            let v: Vec<&str> = line.split(',').collect();
            let frame: u64 = v[0].parse().unwrap();
            let k = rec.frames.iter().position(|f| f.frame == frame);
            let m = rec.marker_ids.iter().position(|id| id == v[1]);
            if let (Some(k), Some(m)) = (k, m) {
                let c = |i: usize| v[i].parse::<f64>().unwrap() * 1e-3;
                truth[k][m] = Vector3::new(c(2), c(3), c(4));
            }
        }
        report("synthetic truth's markers", &truth);
    }
    report(
        "rest markers (no model)",
        &vec![sim.rest_markers_m(); rec.frames.len()],
    );
    if let Some(list) = env("FLOOR_MU") {
        friction_profile(&rec, &seg, &sim, &list);
        return;
    }
    let which = env("FLOOR_WHICH").unwrap_or_else(|| "abcd".into());
    let prony = env("FLOOR_PRONY").map_or(Extension::Elastic, |v| {
        let (g, tau) = v.split_once(',').expect("FLOOR_PRONY=G,TAU_S");
        Extension::Viscoelastic {
            g: g.parse().unwrap(),
            tau_s: tau.parse().unwrap(),
        }
    });
    let force_ext = match env("FLOOR_EXT") {
        None => prony,
        Some(v) if v.starts_with("dyn:") => {
            let v: Vec<f64> = v[4..].split(',').map(|x| x.parse().unwrap()).collect();
            Extension::Dynamic {
                density_kg_m3: v[0],
                alpha_per_s: v[1],
                beta_s: v[2],
                lame_ratio_factor: v.get(3).copied().unwrap_or(1.0),
            }
        }
        Some(v) => {
            let v: Vec<f64> = v
                .strip_prefix("ti:")
                .expect("FLOOR_EXT=ti:FX,FY,FZ,RATIO,NU_T,NU_A")
                .split(',')
                .map(|x| x.parse().unwrap())
                .collect();
            Extension::TransverselyIsotropic {
                fibre: Vector3::new(v[0], v[1], v[2]).normalize(),
                ratio: v[3],
                nu_transverse: v[4],
                nu_fibre: v[5],
            }
        }
    };
    let run = |label: &str, s: &FemProbeSimulator, rigid: bool| {
        let t = Instant::now();
        let x = if rigid {
            s.simulate_sequence_rigid_tip(&force_ext, &frames(true))
                .unwrap()
                .expect("a rigid tip")
        } else {
            s.simulate_sequence(&force_ext, &frames(false)).unwrap()
        };
        let label = format!("{label} {force_ext:?}");
        report(&format!("{label} ({:.1} s)", t.elapsed().as_secs_f64()), &x);
    };
    if which.contains('a') {
        run("template, force BC", &sim, false);
    }
    if which.contains('b') {
        run("template, rigid-tip replay", &sim, true);
    }
    if which.contains('c') || which.contains('d') {
        let levels: usize = env("FLOOR_LEVELS").map_or(1, |v| v.parse().unwrap());
        let r = &sim.settings().refinement;
        let mut fine = if r.local {
            // FLOOR_LOCAL: inside the touched balls only, as the diagnosis' refined replays
            let balls: Vec<_> = softcap_diagnose::cells::touched_balls(&rec, &seg)
                .into_iter()
                .map(|b| softcap_mesh::RefineBall {
                    radius_m: b.radius_m * r.radius_scale,
                    ..b
                })
                .collect();
            sim.refined_near(&balls, r.edge_fraction * sim.longest_edge_m(), r.max_tets)
                .unwrap()
        } else {
            sim.refined().unwrap()
        };
        for _ in 1..levels {
            fine = fine.refined().unwrap();
        }
        println!("FLOOR refined mesh: {} tets", fine.setup().mesh.tets.len());
        if which.contains('c') {
            run(&format!("refined x{levels}, force BC"), &fine, false);
        }
        if which.contains('d') {
            run(&format!("refined x{levels}, rigid-tip replay"), &fine, true);
        }
    }
}

/// The frictional replay's per-location error on the probe-friction effect cells for every μ of
/// `list` (`FLOOR_MU`), compliance 1.
fn friction_profile(
    rec: &softcap_diagnose::Recording,
    seg: &Segmentation,
    sim: &FemProbeSimulator,
    list: &str,
) {
    use softcap_diagnose::ProbeSimulator;
    let mus: Vec<f64> = list.split(',').map(|v| v.parse().unwrap()).collect();
    let balls = softcap_diagnose::cells::touched_balls(rec, seg);
    let mut fine = ProbeSimulator::refined(sim, &balls).unwrap().unwrap();
    let mask = softcap_diagnose::hypotheses::probe_friction::ProbeFriction
        .effect_cells(rec, seg)
        .unwrap()
        .mask;
    let exts: Vec<Extension> = mus
        .iter()
        .map(|&mu| Extension::ProbeFriction { mu })
        .collect();
    let frames = pose_sequence(rec);
    // the regularization slip of the replay on the uniformly refined mesh (the default)
    let tips: Vec<Vector3<f64>> = frames
        .iter()
        .filter_map(|f| f.load.probe.map(|p| p.tip_m))
        .collect();
    if let Ok(red) = sim.refined() {
        let mesh = &red.setup().mesh;
        let r = rec.tip_radius_m;
        println!(
            "MU surface spacing near the tips on the refined mesh h = {:.3} mm, slip distance {:.3} mm (fraction {})",
            1e3 * softcap_diagnose::sim::surface_spacing_near(mesh, r, &tips).unwrap_or(0.0),
            1e3 * softcap_diagnose::sim::friction_slip_distance_m(
                mesh,
                r,
                &tips,
                sim.settings().friction_slip_fraction
            ),
            sim.settings().friction_slip_fraction
        );
    }
    let t = Instant::now();
    let out = fine.simulate_sequences_rigid_tip(&exts, &frames);
    println!(
        "MU {} replays {:.1} s",
        mus.len(),
        t.elapsed().as_secs_f64()
    );
    let nl = seg.locations.len();
    for (mu, x) in mus.iter().zip(out) {
        let Ok(Some(x)) = x else {
            println!("MU {mu:.4} failed: {:?}", x.err());
            continue;
        };
        let res = residuals(rec, &x);
        let (mut s, mut n) = (vec![0.0; nl + 1], vec![0usize; nl + 1]);
        for (k, row) in res.iter().enumerate() {
            let Some(l) = seg.fold_of_frame[k] else {
                continue;
            };
            for (m, r) in row.iter().enumerate() {
                if let Some(r) = r
                    && mask[k][m]
                {
                    for i in [l, nl] {
                        s[i] += r.norm_squared();
                        n[i] += 1;
                    }
                }
            }
        }
        let rms: Vec<String> = (0..=nl)
            .map(|i| format!("{:.4}", 1e3 * (s[i] / n[i].max(1) as f64).sqrt()))
            .collect();
        let counts: Vec<String> = n.iter().map(|c| c.to_string()).collect();
        println!(
            "MU {mu:.4} per location / all (mm): {} (cells {})",
            rms.join(" "),
            counts.join(" ")
        );
        // the same cells split by phase and by component (surface normal = +z on the top face)
        let split = |keep: &dyn Fn(usize) -> bool, comp: usize| {
            let (mut s, mut n) = (0.0, 0usize);
            for (k, row) in res.iter().enumerate() {
                if seg.fold_of_frame[k].is_none() || !keep(k) {
                    continue;
                }
                for (m, r) in row.iter().enumerate() {
                    if let Some(r) = r
                        && mask[k][m]
                    {
                        s += match comp {
                            0 => r.norm_squared(),
                            1 => r.z * r.z,
                            _ => r.x * r.x + r.y * r.y,
                        };
                        n += 1;
                    }
                }
            }
            1e3 * (s / n.max(1) as f64).sqrt()
        };
        // per contact frame: the measured and simulated displacement of the scored markers along
        // the location's tangential travel (mean), and the residual RMS
        if std::env::var_os("FLOOR_FRAMES").is_some() {
            let sim_disp = |k: usize, m: usize| x[k][m] - rec.rest_markers_m[m];
            for (k, fr) in rec.frames.iter().enumerate() {
                let Some(l) = seg.fold_of_frame[k] else {
                    continue;
                };
                let loc = &seg.locations[l];
                let mut d = loc.peak_tip_m - loc.contact_tip_m;
                d.z = 0.0;
                let s_hat = d.normalize();
                let (mut meas, mut simd, mut rr, mut n) = (0.0, 0.0, 0.0, 0usize);
                for m in 0..rec.num_markers() {
                    if let Some(p) = fr.markers_m[m]
                        && mask[k][m]
                    {
                        meas += (p - rec.rest_markers_m[m]).dot(&s_hat);
                        simd += sim_disp(k, m).dot(&s_hat);
                        rr += (p - x[k][m]).norm_squared();
                        n += 1;
                    }
                }
                if n == 0 {
                    continue;
                }
                let nf = n as f64;
                println!(
                    "MU {mu:.4} frame {k} loc {l} {:?} depth {:.3} along travel measured {:.4} simulated {:.4} rms {:.4} (n {n})",
                    seg.phases[k],
                    1e3 * (fr.tip_m - loc.contact_tip_m).z,
                    1e3 * meas / nf,
                    1e3 * simd / nf,
                    1e3 * (rr / nf).sqrt()
                );
            }
        }
        for (name, ph) in [
            ("loading", Phase::Loading),
            ("hold", Phase::Hold),
            ("unloading", Phase::Unloading),
        ] {
            let keep = |k: usize| seg.phases[k] == ph;
            println!(
                "MU {mu:.4} {name}: total {:.4} normal {:.4} tangential {:.4}",
                split(&keep, 0),
                split(&keep, 1),
                split(&keep, 2)
            );
        }
    }
}
