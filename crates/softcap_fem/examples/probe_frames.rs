//! Interactive probe loop of the criterion bench (1,800-tet block, disk probe, +0.1 mm per frame
//! from the previous equilibrium) with per-frame wall time and process CPU time (all threads, from
//! /proc/self/task/*/schedstat), so that frame cost can be read on a loaded machine.
//! `cargo run --release -p softcap_fem --example probe_frames -- [frames] [every|stale] [predict]`

use softcap_fem::nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use softcap_fem::*;
use std::time::Instant;

fn cpu_ns() -> u64 {
    let mut total = 0;
    if let Ok(dir) = std::fs::read_dir("/proc/self/task") {
        for t in dir.flatten() {
            if let Ok(s) = std::fs::read_to_string(t.path().join("schedstat")) {
                total += s
                    .split_whitespace()
                    .next()
                    .and_then(|v| v.parse::<u64>().ok())
                    .unwrap_or(0);
            }
        }
    }
    total
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let frames: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(400);
    let policy = match args.get(2).map(String::as_str) {
        Some("every") => Refactorization::EveryIteration,
        _ => Refactorization::WhenStale,
    };
    // "predict": start each frame from x + (x − x_previous) (linear extrapolation of the motion).
    let predict = args.get(3).map(String::as_str) == Some("predict");
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.1, 0.1, 0.03], [10, 10, 3]);
    let mut model = CorotationalModel::homogeneous(
        &mesh,
        LinearParams::from_young_poisson(5.0e4, 0.4).expect("valid"),
    )
    .expect("valid mesh");
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.z.abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    let top: Vec<usize> = (0..mesh.vertices.len())
        .filter(|&i| (mesh.vertices[i].z - 0.03).abs() < 1e-12)
        .collect();
    let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    let probe = Probe::new(
        TipShape::Disk {
            radius_m: 0.015,
            thickness_m: 0.01,
        },
        Isometry3::from_parts(Translation3::new(0.05, 0.05, 0.03), down),
    )
    .expect("valid probe");
    let settings = EquilibriumSettings {
        residual_tol_rel: 1e-6,
        displacement_tol_rel: 1e-7,
        refactorization: policy,
        ..Default::default()
    };
    let mut solver = StaticSolver::with_bc(&model, &bc).expect("solver");
    let mut x = mesh.vertices.clone();
    let f = vec![Vector3::zeros(); x.len()];
    let mut depth = 0.0;
    let mut previous = x.clone();
    let (mut iters, mut walls) = (0usize, Vec::new());
    let t0 = Instant::now();
    let c0 = cpu_ns();
    for _ in 0..frames {
        let reset = depth > 0.004;
        depth = if reset { 0.0 } else { depth + 1e-4 };
        if predict {
            let current = x.clone();
            if !reset {
                for (xi, (c, p)) in x.iter_mut().zip(current.iter().zip(&previous)) {
                    *xi = c + (c - p);
                }
            }
            previous = current;
        }
        let contact = ContactProblem {
            probe: probe.advanced(depth),
            candidate_nodes: top.clone(),
            settings: ContactSettings::default(),
        };
        let t = Instant::now();
        let rep = solver.solve(&mut model, &mut x, &f, Some(&contact), &settings);
        walls.push(t.elapsed().as_secs_f64());
        assert!(rep.converged(), "{rep:?}");
        iters += rep.iterations;
    }
    let wall = t0.elapsed().as_secs_f64();
    let cpu = (cpu_ns() - c0) as f64 * 1e-9;
    walls.sort_by(f64::total_cmp);
    println!(
        "{policy:?}: {frames} frames, {:.2} iterations/frame; wall mean {:.3} ms, median {:.3} ms; CPU (all threads) {:.3} ms/frame",
        iters as f64 / frames as f64,
        1e3 * wall / frames as f64,
        1e3 * walls[frames / 2],
        1e3 * cpu / frames as f64
    );
}
