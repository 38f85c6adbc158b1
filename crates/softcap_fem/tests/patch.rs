//! Patch test: an affine displacement field prescribed on the boundary of an irregular tet patch is
//! reproduced exactly in the interior (corotational and neo-Hookean).

use softcap_fem::nalgebra::{Matrix3, Vector3};
use softcap_fem::*;

fn irregular_patch() -> (softcap_mesh::TetMesh, Vec<bool>) {
    let mut mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [3, 3, 3]);
    let on_boundary: Vec<bool> = mesh
        .vertices
        .iter()
        .map(|v| v.iter().any(|c| c.abs() < 1e-12 || (c - 1.0).abs() < 1e-12))
        .collect();
    // Deterministic perturbation of interior vertices (distorted elements).
    for (i, v) in mesh.vertices.iter_mut().enumerate() {
        if !on_boundary[i] {
            let s = i as f64;
            *v += Vector3::new((1.3 * s).sin(), (2.1 * s).cos(), (0.7 * s).sin()) * 0.08;
        }
    }
    (mesh, on_boundary)
}

fn run<M: ElasticModel>(
    model: &mut M,
    mesh: &softcap_mesh::TetMesh,
    boundary: &[bool],
    settings: &EquilibriumSettings,
) -> f64 {
    let a = Matrix3::new(1.05, 0.02, -0.03, 0.01, 0.97, 0.04, -0.02, 0.03, 1.02);
    let rot = softcap_fem::nalgebra::Rotation3::from_euler_angles(0.5, -0.3, 0.8);
    let b = Vector3::new(0.1, -0.2, 0.3);
    let exact = |p: &Vector3<f64>| rot * (a * p) + b;
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if boundary[i] {
            bc.fix_node(i, exact(v));
        }
    }
    let mut solver = StaticSolver::with_bc(model, &bc).unwrap();
    let mut x = mesh.vertices.clone();
    bc.apply(&mut x);
    let f = vec![Vector3::zeros(); x.len()];
    let rep = solver.solve(model, &mut x, &f, None, settings);
    assert!(rep.converged(), "{rep:?}");
    mesh.vertices
        .iter()
        .zip(&x)
        .map(|(p, q)| (exact(p) - q).norm())
        .fold(0.0, f64::max)
}

#[test]
fn affine_field_is_reproduced_exactly() {
    let (mesh, boundary) = irregular_patch();
    let interior = boundary.iter().filter(|b| !**b).count();
    assert!(interior >= 8);
    let mut co = CorotationalModel::homogeneous(
        &mesh,
        LinearParams::from_young_poisson(1.0e4, 0.3).unwrap(),
    )
    .unwrap();
    let err_co = run(&mut co, &mesh, &boundary, &EquilibriumSettings::default());
    let err_co_newton = run(&mut co, &mesh, &boundary, &EquilibriumSettings::newton());
    let mut nh = NeoHookeanModel::homogeneous(
        &mesh,
        NeoHookeanParams::from_young_poisson(1.0e4, 0.3).unwrap(),
    )
    .unwrap();
    let err_nh = run(&mut nh, &mesh, &boundary, &EquilibriumSettings::newton());
    println!(
        "patch test ({interior} interior nodes, rotated + stretched affine field): max |x - x_exact|"
    );
    println!("  corotational, warped fixed point: {err_co:.3e} m");
    println!("  corotational, Newton:             {err_co_newton:.3e} m");
    println!("  stable neo-Hookean, Newton:       {err_nh:.3e} m");
    assert!(err_co < 1e-10 && err_co_newton < 1e-10 && err_nh < 1e-10);
}
