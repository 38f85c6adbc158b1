//! The composite Newton solver (exact tangent, band LU) reaches the same
//! equilibrium as the thesis §8.2 fixed-point iteration ("refresh E, re-solve") of
//! `softcap_fem::StaticSolver` on the same `CompositeModel`, in far fewer iterations.

use nalgebra::Vector3;
use softcap_design::softcap_fem::{EquilibriumSettings, StaticSolver};
use softcap_design::*;
use std::sync::Arc;

#[test]
fn newton_equals_fixed_point_iteration_of_static_solver() {
    let lib = Arc::new(reference_library());
    let settings = CompositeSettings::default();
    let block = Arc::new(LayeredBlock::uniform(&settings).unwrap());
    let mut sim = CompositeSimulator::new(block.clone(), lib.clone(), &settings).unwrap();
    let tight = EquilibriumSettings {
        max_iterations: 500,
        displacement_tol_rel: 1e-11,
        residual_tol_rel: 1e-10,
        line_search: false,
        ..EquilibriumSettings::default()
    };
    for design in [[0, 3, 6, 7, 8], [2, 8, 0, 5, 1]] {
        let r = sim.simulate(&design).unwrap();
        // Reference: softcap_fem's solver on the same model (E refreshed every iteration).
        let mut model =
            CompositeModel::new(&block.mesh, lib.clone(), block.element_materials(&design))
                .unwrap();
        let mut solver = StaticSolver::new(&model, &block.bc.dofs()).unwrap();
        let rest = block.mesh.vertices.clone();
        let mut x = rest.clone();
        let mut f_ext = vec![Vector3::zeros(); rest.len()];
        let mut fixed_point_iterations = 0;
        let mut max_diff = 0.0f64;
        let mut max_u = 0.0f64;
        for (k, &force) in settings.forces_n.iter().enumerate() {
            for &(node, share) in &block.patch {
                f_ext[node] = Vector3::new(0.0, 0.0, -force * share);
            }
            let rep = solver.solve(&mut model, &mut x, &f_ext, None, &tight);
            assert!(rep.converged(), "{:?}", rep.status);
            fixed_point_iterations += rep.iterations;
            for (a, &i) in block.top_nodes.iter().enumerate() {
                let u = x[i] - rest[i];
                for c in 0..3 {
                    let un = r.displacements_m[(k * block.top_nodes.len() + a) * 3 + c];
                    max_diff = max_diff.max((un - u[c]).abs());
                    max_u = max_u.max(u[c].abs());
                }
            }
        }
        println!(
            "{design:?}: max |u| {:.4} mm, Newton − fixed point {:.2e} m, iterations Newton {} vs fixed point {}",
            max_u * 1e3,
            max_diff,
            r.iterations,
            fixed_point_iterations
        );
        assert!(max_diff < 1e-9, "{max_diff}");
        assert!(r.iterations * 2 < fixed_point_iterations);
    }
}

#[test]
fn element_tangent_matches_finite_differences_of_forces() {
    let lib = Arc::new(reference_library());
    let m = LayeredBlock::uniform(&CompositeSettings::default())
        .unwrap()
        .mesh;
    for mat in [2usize, 7] {
        let model = CompositeModel::new(&m, lib.clone(), vec![mat; m.tets.len()]).unwrap();
        // A deformed state with ≈ 3 % strains and a small rotation.
        let rot = nalgebra::Rotation3::from_euler_angles(0.05, -0.03, 0.02);
        let x: Vec<Vector3<f64>> = m
            .vertices
            .iter()
            .map(|v| rot * Vector3::new(v.x * 1.03, v.y * 0.98 + 0.02 * v.z, v.z * 0.97))
            .collect();
        for e in [0, 3] {
            let (_, k) = model.element_force_tangent(e, &x);
            let nodes = model.element_nodes(e);
            let h = 1e-9;
            let mut err = 0.0f64;
            for b in 0..4 {
                for d in 0..3 {
                    let mut xp = x.clone();
                    let mut xm = x.clone();
                    xp[nodes[b]][d] += h;
                    xm[nodes[b]][d] -= h;
                    let (fp, _) = model.element_force_tangent(e, &xp);
                    let (fm, _) = model.element_force_tangent(e, &xm);
                    for a in 0..4 {
                        for c in 0..3 {
                            let fd = (fp[a][c] - fm[a][c]) / (2.0 * h);
                            err = err.max((fd - k[(3 * a + c, 3 * b + d)]).abs());
                        }
                    }
                }
            }
            // The tangent is exact: analytic C_t = ∂σ/∂ε and the rotation derivative.
            println!(
                "material {mat} element {e}: max |K − FD| / max |K| = {:.2e}",
                err / k.amax()
            );
            assert!(err < 1e-5 * k.amax(), "{err} vs {}", k.amax());
        }
    }
}
