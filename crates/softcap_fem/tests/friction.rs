//! Regularized Coulomb friction: the law (slide at μ f_n, stick stiffness 2μf_n/ε, Jacobian vs
//! FD) and a probe pressed on a block and dragged sideways: the tangential force on the probe
//! matches a bonded probe while sticking, stays ≤ μN on the way, and equals μN when sliding.

use crate::common;
use softcap_fem::nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use softcap_fem::*;

#[test]
fn regularized_coulomb_law_and_jacobian() {
    let p = FrictionParams {
        mu: 0.4,
        slip_distance_m: 1e-3,
    };
    let nu = Vector3::new(0.0, 0.0, 1.0);
    let proj = Matrix3::identity() - nu * nu.transpose();
    let fnn = 10.0;
    // Sliding: |f| = μ f_n exactly, opposite to the slip.
    let d = Vector3::new(3e-3, -4e-3, 0.0);
    let (f, _) = regularized_coulomb(&p, fnn, &d, &proj);
    assert!((f.norm() - 4.0).abs() < 1e-12 && f.dot(&d) < 0.0);
    // Sticking at tiny slip: f ≈ −(2μ f_n/ε) δ.
    let d = Vector3::new(1e-9, 2e-9, 0.0);
    let (f, k) = regularized_coulomb(&p, fnn, &d, &proj);
    assert!((f + d * (2.0 * 0.4 * 10.0 / 1e-3)).norm() < 1e-5 * f.norm());
    assert!((k - proj * 8000.0).norm() < 1e-5 * 8000.0);
    // −∂f/∂δ against central differences inside the regularized zone.
    for d in [
        Vector3::new(3e-4, -2e-4, 0.0),
        Vector3::new(-7e-4, 5e-4, 0.0),
    ] {
        let (_, k) = regularized_coulomb(&p, fnn, &d, &proj);
        let h = 1e-9;
        for j in 0..2 {
            let mut e = Vector3::zeros();
            e[j] = h;
            let fd = -(regularized_coulomb(&p, fnn, &(d + e), &proj).0
                - regularized_coulomb(&p, fnn, &(d - e), &proj).0)
                / (2.0 * h);
            let an = k.column(j).into_owned();
            assert!((fd - an).norm() < 1e-5 * an.norm(), "{fd} vs {an}");
        }
    }
    assert!(
        FrictionParams {
            mu: -0.1,
            slip_distance_m: 1e-3
        }
        .validate()
        .is_err()
    );
}

struct Rig {
    mesh: softcap_mesh::TetMesh,
    model: CorotationalModel,
    bc: DirichletBc,
    top: Vec<usize>,
}

fn rig() -> Rig {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 0.5], [4, 4, 2]);
    let model = CorotationalModel::homogeneous(
        &mesh,
        LinearParams::from_young_poisson(1.0e4, 0.3).unwrap(),
    )
    .unwrap();
    let (bc, top) = common::block_supports(&mesh, 0.0, 0.5, false);
    Rig {
        mesh,
        model,
        bc,
        top,
    }
}

/// Disk probe pointing down (−z) with its face at height 0.5 − depth, centred at (0.5 + s, 0.5).
fn pose(depth: f64, s: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.5 + s, 0.5, 0.5 - depth),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    )
}

/// The disk probe (radius 0.3, thickness 0.1) at the top surface with friction μ, ε = 1e-5.
fn disk_contact(rig: &Rig, mu: f64) -> FrictionalContact {
    let probe = Probe::new(
        TipShape::Disk {
            radius_m: 0.3,
            thickness_m: 0.1,
        },
        pose(0.0, 0.0),
    )
    .unwrap();
    let contact = ContactProblem {
        probe,
        candidate_nodes: rig.top.clone(),
        settings: ContactSettings::default(),
    };
    FrictionalContact::new(
        contact,
        FrictionParams {
            mu,
            slip_distance_m: 1e-5,
        },
    )
    .unwrap()
}

/// Indents by `depth` then drags by `shifts`; returns (x after indentation, per-shift reports).
fn drag(
    rig: &mut Rig,
    mu: f64,
    depth: f64,
    shifts: &[f64],
) -> (Vec<Vector3<f64>>, Vec<(FrictionReport, Vec<Vector3<f64>>)>) {
    let mut fc = disk_contact(rig, mu);
    let mut solver = NodalSolver::new(&rig.model, &rig.bc.dofs()).unwrap();
    let mut x = rig.mesh.vertices.clone();
    let zero = vec![Vector3::zeros(); x.len()];
    let settings = EquilibriumSettings::newton();
    for k in 1..=4 {
        fc.set_pose(pose(depth * k as f64 / 4.0, 0.0));
        let rep = solver.solve(&mut rig.model, &mut x, &zero, &mut [&mut fc], &settings);
        assert!(rep.converged(), "indent {k}: {rep:?}");
        fc.commit(&x);
    }
    let indented = x.clone();
    let mut out = Vec::new();
    for (k, &s) in shifts.iter().enumerate() {
        fc.set_pose(pose(depth, s));
        let rep = solver.solve(&mut rig.model, &mut x, &zero, &mut [&mut fc], &settings);
        assert!(rep.converged(), "shift {k} = {s}: {rep:?}");
        fc.commit(&x);
        out.push((fc.report(&x), x.clone()));
    }
    (indented, out)
}

#[test]
fn dragged_probe_sticks_like_a_bonded_probe_below_mu_n() {
    let mut r = rig();
    let s = 2e-3;
    let (indented, reps) = drag(&mut r, 5.0, 0.01, &[0.0, 0.5 * s, s]);
    let (rep, _) = &reps[2];
    assert_eq!(rep.patch_nodes.len(), 5, "{:?}", rep.patch_nodes);
    assert_eq!(rep.sticking_nodes, 5, "{rep:?}");
    let ft = rep.probe_tangential_force_n;
    assert!(ft.x < 0.0 && ft.x.abs() < 5.0 * rep.normal_force_n);
    // The indentation leaves a small tangential pre-load (the structured mesh's diagonals are not
    // mirror-symmetric); the drag adds to it.
    let f0 = reps[0].0.probe_tangential_force_n;
    // Bonded reference: the patch nodes carried rigidly by s from the indented state.
    let mut bc = r.bc.clone();
    for &n in &rep.patch_nodes {
        bc.fix_node(n, indented[n] + Vector3::new(s, 0.0, 0.0));
    }
    let mut solver = StaticSolver::with_bc(&r.model, &bc).unwrap();
    let mut xb = indented.clone();
    bc.apply(&mut xb);
    let zero = vec![Vector3::zeros(); xb.len()];
    let rb = solver.solve(
        &mut r.model,
        &mut xb,
        &zero,
        None,
        &EquilibriumSettings::newton(),
    );
    assert!(rb.converged());
    let f_int = r.model.internal_forces(&xb);
    let bonded_x: f64 = rep.patch_nodes.iter().map(|&n| f_int[n].x).sum();
    // Force on the body from the bonded probe = internal force at the patch; on the probe: −.
    let rel = (ft.x + bonded_x).abs() / bonded_x.abs();
    eprintln!(
        "friction stick: F_t on probe {:.4} N, bonded {:.4} N (rel {rel:.2e}), N = {:.3} N",
        ft.x, -bonded_x, rep.normal_force_n
    );
    assert!(
        rel < 1e-3,
        "stick {} N vs bonded {} N (rel {rel})",
        -ft.x,
        bonded_x
    );
    // Stick is linear in the drag: F(s) − F(0) = 2 (F(s/2) − F(0)) (rel. 1e-3).
    let half = reps[1].0.probe_tangential_force_n - f0;
    let full = ft - f0;
    assert!(
        (full - half * 2.0).norm() < 1e-3 * full.norm(),
        "{full} vs 2 × {half}"
    );
}

#[test]
fn dragged_probe_slides_at_mu_n() {
    let mut r = rig();
    let mu = 0.3;
    let shifts: Vec<f64> = (1..=8).map(|k| 0.0025 * k as f64).collect();
    let (_, reps) = drag(&mut r, mu, 0.01, &shifts);
    let mut prev = 0.0;
    for (rep, _) in &reps {
        let ft = rep.probe_tangential_force_n;
        // Never above the Coulomb cone; nondecreasing as the drag grows.
        assert!(ft.norm() <= mu * rep.normal_force_n * (1.0 + 1e-9));
        assert!(ft.norm() >= prev * (1.0 - 1e-3));
        prev = ft.norm();
    }
    let (rep, _) = reps.last().unwrap();
    assert_eq!(rep.sliding_nodes, rep.patch_nodes.len(), "{rep:?}");
    let ft = rep.probe_tangential_force_n;
    let ratio = ft.norm() / rep.normal_force_n;
    eprintln!(
        "friction slide: F_t on probe {ft:?} N, N = {:.4} N, |F_t|/N = {ratio:.8} (μ = {mu})",
        rep.normal_force_n
    );
    assert!((ratio - mu).abs() < 1e-5 * mu, "F_t/N = {ratio}");
    // Mostly against the drag (the slip direction tilts by ~1° on the asymmetric mesh).
    assert!(ft.x < 0.0 && ft.y.abs() < 0.05 * ft.norm(), "{ft} {rep:?}");
}

#[test]
fn frictionless_limit_matches_the_static_contact_solver() {
    // μ = 0: the nodal solver with FrictionalContact reproduces StaticSolver's penalty contact.
    let mut r = rig();
    let (_, reps) = drag(&mut r, 0.0, 0.01, &[0.0]);
    let (rep, x_nodal) = &reps[0];
    assert!(rep.friction_force_n.norm() == 0.0);
    let probe = Probe::new(
        TipShape::Disk {
            radius_m: 0.3,
            thickness_m: 0.1,
        },
        pose(0.01, 0.0),
    )
    .unwrap();
    let contact = ContactProblem {
        probe,
        candidate_nodes: r.top.clone(),
        settings: ContactSettings::default(),
    };
    let mut solver = StaticSolver::with_bc(&r.model, &r.bc).unwrap();
    let mut x = r.mesh.vertices.clone();
    let zero = vec![Vector3::zeros(); x.len()];
    let mut last = None;
    for k in 1..=4 {
        let mut c = contact.clone();
        c.probe.world_from_probe = pose(0.01 * k as f64 / 4.0, 0.0);
        let rep = solver.solve(
            &mut r.model,
            &mut x,
            &zero,
            Some(&c),
            &EquilibriumSettings::newton(),
        );
        assert!(rep.converged());
        last = Some(rep);
    }
    let srep = last.unwrap();
    let worst = x
        .iter()
        .zip(x_nodal)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).norm()));
    assert!(worst < 1e-9, "max position difference {worst} m");
    assert!(
        (srep.contact.axial_force_n - rep.normal_force_n).abs() < 1e-6 * rep.normal_force_n,
        "{} vs {}",
        srep.contact.axial_force_n,
        rep.normal_force_n
    );
}

#[test]
fn lagged_normal_forces_settle_and_the_drag_slides_at_mu_n() {
    // The same drag with f_n held per solve and re-lagged (`solve_lagged`, the iterations the
    // synthetic truth and the diagnose replay use): the lag settles within its tolerance at every
    // step, the probe is moved by `move_probe` (stuck nodes carried with it), and the sliding
    // patch carries μ × the settled normal force.
    let mut r = rig();
    let mu = 0.3;
    let mut fc = disk_contact(&r, mu);
    fc.normal_force_lag = NormalForceLag::Solve;
    let mut solver = NodalSolver::new(&r.model, &r.bc.dofs()).unwrap();
    let mut x = r.mesh.vertices.clone();
    let zero = vec![Vector3::zeros(); x.len()];
    let settings = EquilibriumSettings::newton();
    let lag = LaggedIterations::default();
    let mut path: Vec<(f64, f64)> = (1..=4).map(|k| (0.01 * k as f64 / 4.0, 0.0)).collect();
    path.extend((1..=8).map(|k| (0.01, 0.0025 * k as f64)));
    let mut last = None;
    for (k, &(depth, s)) in path.iter().enumerate() {
        let before = fc.anchors_world();
        let x_before = x.clone();
        fc.move_probe(&mut x, pose(depth, s));
        // the predictor: every anchored node moved with the probe increment, nothing else
        let (dz, dx) = if k == 0 {
            (0.0, 0.0)
        } else {
            (-(depth - path[k - 1].0), s - path[k - 1].1)
        };
        for (n, _) in &before {
            let moved = x[*n] - x_before[*n];
            assert!(
                (moved - Vector3::new(dx, 0.0, dz)).norm() < 1e-12,
                "{moved}"
            );
        }
        let out = solve_lagged(
            &mut solver,
            &mut r.model,
            &mut x,
            &zero,
            Some(&mut fc),
            &mut [],
            &settings,
            &lag,
        );
        assert!(out.equilibrium.converged(), "step {k}: {out:?}");
        assert!(out.lag_mismatch <= lag.tolerance, "step {k}: {out:?}");
        fc.commit(&x);
        last = Some(fc.report(&x));
    }
    let rep = last.unwrap();
    assert_eq!(rep.sliding_nodes, rep.patch_nodes.len(), "{rep:?}");
    let ratio = rep.probe_tangential_force_n.norm() / rep.normal_force_n;
    // the friction bound uses the lagged f_n, within the lag tolerance of the settled one
    assert!(
        (ratio - mu).abs() < 2.0 * lag.tolerance * mu,
        "F_t/N = {ratio}"
    );
    assert!(rep.probe_tangential_force_n.x < 0.0);
    // without a contact term it is one plain nodal solve (unloading back to rest)
    let mut x = r.mesh.vertices.clone();
    let out = solve_lagged(
        &mut solver,
        &mut r.model,
        &mut x,
        &zero,
        None,
        &mut [],
        &settings,
        &lag,
    );
    assert!(out.equilibrium.converged() && out.lag_mismatch == 0.0);
}

/// The lagged drag of `lagged_normal_forces_settle_and_the_drag_slides_at_mu_n` under
/// `refactorization`: per step the positions, the last solve's iterations and the lag mismatch.
fn lagged_drag(refactorization: Refactorization) -> Vec<(Vec<Vector3<f64>>, usize, f64)> {
    let mut r = rig();
    let mut fc = disk_contact(&r, 0.3);
    fc.normal_force_lag = NormalForceLag::Solve;
    let mut solver = NodalSolver::new(&r.model, &r.bc.dofs()).unwrap();
    let mut x = r.mesh.vertices.clone();
    let zero = vec![Vector3::zeros(); x.len()];
    let settings = EquilibriumSettings {
        refactorization,
        ..EquilibriumSettings::newton()
    };
    let mut path: Vec<(f64, f64)> = (1..=4).map(|k| (0.01 * k as f64 / 4.0, 0.0)).collect();
    path.extend((1..=8).map(|k| (0.01, 0.0025 * k as f64)));
    let mut out = Vec::new();
    for (k, &(depth, s)) in path.iter().enumerate() {
        fc.move_probe(&mut x, pose(depth, s));
        let lagged = solve_lagged(
            &mut solver,
            &mut r.model,
            &mut x,
            &zero,
            Some(&mut fc),
            &mut [],
            &settings,
            &LaggedIterations::default(),
        );
        assert!(lagged.equilibrium.converged(), "step {k}: {lagged:?}");
        fc.commit(&x);
        out.push((
            x.clone(),
            lagged.equilibrium.iterations,
            lagged.lag_mismatch,
        ));
    }
    out
}

#[test]
fn every_step_takes_the_lagged_drag_of_every_iteration() {
    // `Refactorization::EveryStep` in `NodalSolver`: the converged iterate is tested with its
    // forces alone instead of a fresh assembly and factorization; the iterates are those of
    // `EveryIteration`, so every step's equilibrium is the same to the displacement tolerance
    // (1e-8 of the 1.1 m block's diagonal; 2x for the one iterate the alternative residual bound
    // may stop earlier) and takes as many iterations or one fewer.
    let every = lagged_drag(Refactorization::EveryIteration);
    let step = lagged_drag(Refactorization::EveryStep);
    let tol_x = EquilibriumSettings::newton().displacement_tol_rel * 1.5;
    for (k, (a, b)) in every.iter().zip(&step).enumerate() {
        let d =
            a.0.iter()
                .zip(&b.0)
                .map(|(p, q)| (p - q).norm())
                .fold(0.0, f64::max);
        assert!(d <= 2.0 * tol_x, "step {k}: {d:e} m");
        assert!(
            b.1 <= a.1 && b.1 + 1 >= a.1,
            "step {k}: {} vs {} iterations",
            b.1,
            a.1
        );
        assert!((a.2 - b.2).abs() < 1e-4, "step {k}: lag {} vs {}", a.2, b.2);
    }
}
