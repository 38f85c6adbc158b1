//! Slender cantilever (L/h = 10) under a tip shear load: tip deflection vs Euler–Bernoulli
//! PL³/3EI plus the Timoshenko shear term PL/(κGA).

use crate::common;
use softcap_fem::nalgebra::Vector3;
use softcap_fem::*;

const L: f64 = 10.0;
const H: f64 = 1.0;
const E: f64 = 1000.0;
const NU: f64 = 0.0;
const P: f64 = 1.0e-3;

fn analytic() -> f64 {
    let i = H.powi(4) / 12.0;
    let g = E / (2.0 * (1.0 + NU));
    let kappa = 10.0 * (1.0 + NU) / (12.0 + 11.0 * NU); // Cowper's rectangular-section factor
    P * L.powi(3) / (3.0 * E * i) + P * L / (kappa * g * H * H)
}

fn tip_deflection(nx: usize, ny: usize, nz: usize) -> (f64, usize) {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [L, H, H], [nx, ny, nz]);
    let mut model =
        CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(E, NU).unwrap())
            .unwrap();
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.x.abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    let f = common::traction_forces(
        &mesh,
        |p| p.iter().all(|v| (v.x - L).abs() < 1e-12),
        Vector3::new(0.0, 0.0, -P / (H * H)),
    );
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut x = mesh.vertices.clone();
    let rep = solver.solve(
        &mut model,
        &mut x,
        &f,
        None,
        &EquilibriumSettings::default(),
    );
    assert!(rep.converged(), "{rep:?}");
    let tip: Vec<usize> = (0..x.len())
        .filter(|&i| (mesh.vertices[i].x - L).abs() < 1e-12)
        .collect();
    let w = -tip
        .iter()
        .map(|&i| x[i].z - mesh.vertices[i].z)
        .sum::<f64>()
        / tip.len() as f64;
    (w, mesh.tets.len())
}

fn table(levels: &[(usize, usize, usize)]) -> Vec<f64> {
    let exact = analytic();
    println!("cantilever L/h = 10, E = {E}, nu = {NU}, P = {P}: PL^3/3EI + PL/(kGA) = {exact:.6e}");
    println!("| cells (x × y × z) | tets | tip deflection | error |");
    println!("|---|---|---|---|");
    levels
        .iter()
        .map(|&(nx, ny, nz)| {
            let (w, t) = tip_deflection(nx, ny, nz);
            let err = (w - exact) / exact;
            println!(
                "| {nx} × {ny} × {nz} | {t} | {w:.6e} | {:+.2} % |",
                100.0 * err
            );
            err
        })
        .collect()
}

#[test]
fn cantilever_tip_deflection_within_3_percent() {
    let errs = table(&[(50, 2, 6), (100, 2, 10), (200, 2, 12)]);
    assert!(
        errs.windows(2).all(|w| w[1].abs() < w[0].abs()),
        "not converging: {errs:?}"
    );
    assert!(
        errs.last().unwrap().abs() < 0.03,
        "finest error {:?}",
        errs.last()
    );
}

#[test]
#[ignore = "full refinement table (slow in the dev profile)"]
fn cantilever_full_table() {
    table(&[
        (100, 2, 10),
        (200, 2, 12),
        (200, 2, 16),
        (250, 2, 16),
        (200, 4, 16),
    ]);
}
