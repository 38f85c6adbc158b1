//! Viscoelastic bar (ν = 0, uniaxial stress) against the analytic generalized-Maxwell /
//! standard-linear-solid responses: stress relaxation under a held strain step and creep under a
//! held force step, for the corotational and the stable neo-Hookean base models.

use crate::common;
use softcap_fem::nalgebra::Vector3;
use softcap_fem::*;

const L: f64 = 1.0;
const W: f64 = 0.1;
const E_INF: f64 = 1.0e4;

fn bar() -> softcap_mesh::TetMesh {
    softcap_mesh::box_tet_mesh([0.0; 3], [L, W, W], [4, 1, 1])
}

fn end_nodes(mesh: &softcap_mesh::TetMesh) -> Vec<usize> {
    (0..mesh.vertices.len())
        .filter(|&i| (mesh.vertices[i].x - L).abs() < 1e-12)
        .collect()
}

fn clamp_base(mesh: &softcap_mesh::TetMesh) -> DirichletBc {
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.x.abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    bc
}

fn settings() -> EquilibriumSettings {
    EquilibriumSettings {
        residual_tol_rel: 1e-12,
        displacement_tol_rel: 1e-13,
        ..EquilibriumSettings::newton()
    }
}

/// Strain step ε0 at t = 0 (a Δt = 0 step), held; returns max relative error of the end reaction
/// against E_∞ A ε0 G(t)/G_∞ over the steps.
fn relaxation<M: ElasticModel>(
    base: M,
    prony: PronySeries,
    eps0: f64,
    dt: f64,
    steps: usize,
) -> f64 {
    let mesh = bar();
    let ends = end_nodes(&mesh);
    let mut bc = clamp_base(&mesh);
    for &i in &ends {
        bc.fix_dof(3 * i, L * (1.0 + eps0));
    }
    let mut model = ViscoelasticModel::new(base, prony.clone()).unwrap();
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut x = mesh.vertices.clone();
    let zero = vec![Vector3::zeros(); x.len()];
    let f0 = E_INF * W * W * eps0;
    let mut worst: f64 = 0.0;
    for n in 0..=steps {
        let h = if n == 0 { 0.0 } else { dt };
        let rep = viscoelastic_quasi_static_step(
            &mut solver,
            &mut model,
            &mut x,
            &zero,
            Some(&bc),
            None,
            h,
            &settings(),
        )
        .unwrap();
        assert!(rep.converged(), "{rep:?}");
        let t = n as f64 * dt;
        let f_int = model.committed_forces(&x);
        let reaction: f64 = ends.iter().map(|&i| f_int[i].x).sum();
        let exact = f0 * prony.relaxation(t);
        worst = worst.max(((reaction - exact) / exact).abs());
    }
    worst
}

#[test]
fn stress_relaxation_matches_prony_series() {
    let lin = LinearParams::from_young_poisson(E_INF, 0.0).unwrap();
    let mesh = bar();
    let sls = PronySeries::standard_linear_solid(1.5, 0.5).unwrap();
    let two = PronySeries::from_parameters(&[0.8, 0.1, 0.4, 2.0]).unwrap();
    let co = CorotationalModel::homogeneous(&mesh, lin).unwrap();
    let e_sls = relaxation(co.clone(), sls.clone(), 1e-3, 0.05, 40);
    let e_two = relaxation(co, two, 1e-3, 0.05, 40);
    let nh =
        NeoHookeanModel::homogeneous(&mesh, NeoHookeanParams::from_linear(&lin).unwrap()).unwrap();
    let e_nh = relaxation(nh, sls, 1e-5, 0.05, 40);
    println!(
        "relaxation, max rel. error of F(t): corotational SLS {e_sls:.2e}, corotational 2-branch {e_two:.2e}, neo-Hookean SLS (eps0 = 1e-5) {e_nh:.2e}"
    );
    assert!(e_sls < 1e-9 && e_two < 1e-9, "{e_sls:e} {e_two:e}");
    assert!(e_nh < 5e-5, "{e_nh:e}");
}

/// Force step σ0 A at t = 0, held; returns max |u(t) − u_exact(t)| / u_∞ over the steps, with
/// u(t) = σ0 L / E_∞ [1 − g/(1+g) e^{−t/τ_c}], τ_c = τ (1 + g) (SLS creep).
fn creep<M: ElasticModel>(base: M, g: f64, tau: f64, sigma0: f64, dt: f64, steps: usize) -> f64 {
    let mesh = bar();
    let ends = end_nodes(&mesh);
    let bc = clamp_base(&mesh);
    let f = common::traction_forces(
        &mesh,
        |p| p.iter().all(|v| (v.x - L).abs() < 1e-12),
        Vector3::new(sigma0, 0.0, 0.0),
    );
    let mut model =
        ViscoelasticModel::new(base, PronySeries::standard_linear_solid(g, tau).unwrap()).unwrap();
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut x = mesh.vertices.clone();
    let u_inf = sigma0 * L / E_INF;
    let tau_c = tau * (1.0 + g);
    let mut worst: f64 = 0.0;
    for n in 0..=steps {
        let h = if n == 0 { 0.0 } else { dt };
        let rep = viscoelastic_quasi_static_step(
            &mut solver,
            &mut model,
            &mut x,
            &f,
            None,
            None,
            h,
            &settings(),
        )
        .unwrap();
        assert!(rep.converged(), "{rep:?}");
        let t = n as f64 * dt;
        let u = ends.iter().map(|&i| x[i].x - L).sum::<f64>() / ends.len() as f64;
        let exact = u_inf * (1.0 - g / (1.0 + g) * (-t / tau_c).exp());
        worst = worst.max((u - exact).abs() / u_inf);
    }
    worst
}

#[test]
fn creep_matches_standard_linear_solid() {
    let lin = LinearParams::from_young_poisson(E_INF, 0.0).unwrap();
    let mesh = bar();
    let co = CorotationalModel::homogeneous(&mesh, lin).unwrap();
    let nh =
        NeoHookeanModel::homogeneous(&mesh, NeoHookeanParams::from_linear(&lin).unwrap()).unwrap();
    // τ = 0.4 s, g = 1.5 ⇒ τ_c = 1 s; 250 steps of τ/50 cover 5 τ_c.
    let mut rows = Vec::new();
    for (name, dt) in [("dt = tau/10", 0.04), ("dt = tau/50", 0.008)] {
        let steps = (5.0 / dt) as usize;
        let e = creep(co.clone(), 1.5, 0.4, 10.0, dt, steps);
        println!("creep, corotational, {name}: max |u - u_exact| / u_inf = {e:.2e}");
        rows.push(e);
    }
    // Second order in Δt (the recurrence is exact for piecewise-linear stress histories).
    assert!(rows[1] < 1e-4, "{rows:?}");
    assert!(rows[0] / rows[1] > 15.0, "not second order: {rows:?}");
    let e_nh = creep(nh, 1.5, 0.4, 0.1, 0.008, 625);
    println!("creep, neo-Hookean (sigma0 = 0.1 Pa, strain 1e-5), dt = tau/50: {e_nh:.2e}");
    assert!(e_nh < 1e-4, "{e_nh:e}");
}
