//! Hertz contact: a rigid sphere (R = 1) indenting a large elastic block (quarter model with
//! symmetry planes x = 0, y = 0; graded mesh refined under the probe) must follow
//! F = (4/3) E* √R d^{3/2}, E* = E/(1 − ν²), within 5 % for d ≪ R.

mod common;
use softcap_fem::nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use softcap_fem::*;

const R: f64 = 1.0;
const E: f64 = 1.0;
const NU: f64 = 0.3;

#[test]
fn sphere_indentation_follows_hertz() {
    let xs = common::graded_line(0.025, 0.2, 1.6, 4.0);
    let zs: Vec<f64> = xs.iter().rev().map(|z| -z).collect();
    let mesh = common::graded_box(&xs, &xs, &zs);
    let mut model = CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(E, NU).unwrap()).unwrap();
    let mut bc = DirichletBc::new();
    let bottom = zs[0];
    for (i, v) in mesh.vertices.iter().enumerate() {
        if (v.z - bottom).abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
        if v.x.abs() < 1e-12 {
            bc.fix_dof(3 * i, 0.0);
        }
        if v.y.abs() < 1e-12 {
            bc.fix_dof(3 * i + 1, 0.0);
        }
    }
    let top: Vec<usize> = (0..mesh.vertices.len()).filter(|&i| mesh.vertices[i].z.abs() < 1e-12).collect();
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let e_star = E / (1.0 - NU * NU);
    println!("Hertz, quarter model: {} tets, {} nodes, block 4 x 4 x 4 (quarter), R = {R}, E = {E}, nu = {NU}", mesh.tets.len(), mesh.vertices.len());
    println!("| d | a = sqrt(Rd) | F (FEM) | F (Hertz) | error | patch nodes |");
    println!("|---|---|---|---|---|---|");
    // The probe approaches along world −z: probe +z ↦ world −z.
    let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    let mut x = mesh.vertices.clone();
    let mut results = Vec::new();
    for d in [0.01, 0.02] {
        let probe = Probe::new(TipShape::Sphere { radius_m: R }, Isometry3::from_parts(Translation3::new(0.0, 0.0, -d), down)).unwrap();
        let contact = ContactProblem { probe, candidate_nodes: top.clone(), settings: ContactSettings::default() };
        let f = vec![Vector3::zeros(); x.len()];
        let rep = solver.solve(&mut model, &mut x, &f, Some(&contact), &EquilibriumSettings::default());
        assert!(rep.converged(), "{:?} after {} iterations, residual {}", rep.status, rep.iterations, rep.residual_norm_n);
        let force = 4.0 * rep.contact.axial_force_n;
        let hertz = 4.0 / 3.0 * e_star * R.sqrt() * d.powf(1.5);
        let err = (force - hertz) / hertz;
        println!("| {d} | {:.3} | {force:.5e} | {hertz:.5e} | {:+.2} % | {} |", (R * d).sqrt(), 100.0 * err, rep.contact.patch_nodes.len());
        // The probe reaction is the opposite of the force on the body.
        assert!((rep.contact.probe_reaction_n + rep.contact.contact_force_n).norm() < 1e-15);
        results.push((d, force, err));
    }
    let slope = (results[1].1 / results[0].1).ln() / (results[1].0 / results[0].0).ln();
    println!("log-log slope F(d): {slope:.3} (Hertz 1.5)");
    for (_, _, err) in &results {
        assert!(err.abs() < 0.05, "Hertz error {err}");
    }
    assert!((slope - 1.5).abs() < 0.05);
}
