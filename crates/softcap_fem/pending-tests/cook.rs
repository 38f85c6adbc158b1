//! Cook's membrane (thin 3D extrusion, one element through the unit thickness, plane stress,
//! E = 1, ν = 1/3, total shear 1 on the right edge, left edge clamped): u_y at the top-right
//! corner converges toward the reference 23.96.

mod common;
use softcap_fem::nalgebra::Vector3;
use softcap_fem::*;

const REFERENCE: f64 = 23.96;

fn corner_uy(n: usize) -> (f64, usize) {
    let mut mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [n, n, 1]);
    for v in &mut mesh.vertices {
        let (s, t) = (v.x, v.y);
        let yb = 44.0 * s;
        let yt = 44.0 + 16.0 * s;
        *v = Vector3::new(48.0 * s, yb + t * (yt - yb), v.z);
    }
    let model = CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(1.0, 1.0 / 3.0).unwrap()).unwrap();
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.x.abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    let f = common::traction_forces(&mesh, |p| p.iter().all(|v| (v.x - 48.0).abs() < 1e-9), Vector3::new(0.0, 1.0 / 16.0, 0.0));
    let total: Vector3<f64> = f.iter().sum();
    assert!((total.y - 1.0).abs() < 1e-12);
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut x = mesh.vertices.clone();
    // The reference is linear elasticity (u_y ≈ 24 on a 48-wide membrane is far outside small strain):
    // solve bickel2009 eq. 10 with rotations frozen at I, i.e. the linear problem K u = F.
    let rot = vec![softcap_fem::nalgebra::Matrix3::identity(); mesh.tets.len()];
    solver.solve_frozen_rotations(&model, &rot, &mut x, &f).unwrap();
    let corner: Vec<usize> = (0..x.len()).filter(|&i| (mesh.vertices[i].x - 48.0).abs() < 1e-9 && (mesh.vertices[i].y - 60.0).abs() < 1e-9).collect();
    assert_eq!(corner.len(), 2);
    let uy = corner.iter().map(|&i| x[i].y - mesh.vertices[i].y).sum::<f64>() / 2.0;
    (uy, mesh.tets.len())
}

fn table(levels: &[usize]) -> Vec<f64> {
    println!("Cook's membrane, E = 1, nu = 1/3, unit shear, thickness 1 (one element), reference u_y = {REFERENCE}");
    println!("| elements per side | tets | u_y (top-right) | error vs 23.96 |");
    println!("|---|---|---|---|");
    levels
        .iter()
        .map(|&n| {
            let (uy, t) = corner_uy(n);
            println!("| {n} | {t} | {uy:.4} | {:+.2} % |", 100.0 * (uy - REFERENCE) / REFERENCE);
            uy
        })
        .collect()
}

#[test]
fn cooks_membrane_converges_to_reference() {
    let uy = table(&[2, 4, 8, 16, 32]);
    // Monotone convergence from below (linear tets are too stiff) …
    assert!(uy.windows(2).all(|w| w[1] > w[0]), "{uy:?}");
    // … with the error shrinking at least ~2× per refinement at the finest levels and the finest mesh
    // within 3 % of the reference.
    let e: Vec<f64> = uy.iter().map(|u| (REFERENCE - u).abs()).collect();
    assert!(e[4] < 0.6 * e[3] && e[3] < 0.6 * e[2]);
    assert!(e[4] / REFERENCE < 0.03, "finest {:?}", uy.last());
}

#[test]
#[ignore = "adds 64 elements per side (slow in the dev profile)"]
fn cooks_membrane_full_table() {
    table(&[2, 4, 8, 16, 32, 64]);
}
