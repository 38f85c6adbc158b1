//! Plasticity: 1D elastoplastic bar (permanent set against the analytic answer), no set below
//! yield, tangents against finite differences, and the multiplicative F_p of saito-barbic §3.2.

use softcap_fem::nalgebra::{Matrix3, Rotation3, Vector3};
use softcap_fem::*;

const L: f64 = 1.0;
const W: f64 = 0.2;

fn bar() -> softcap_mesh::TetMesh {
    softcap_mesh::box_tet_mesh([0.0; 3], [L, W, W], [4, 1, 1])
}

/// Roller supports: x = 0 face slides in its plane (x fixed), plus 3-2-1 to remove rigid modes,
/// so the bar is in exact uniaxial stress under an axial end load.
fn rollers(mesh: &softcap_mesh::TetMesh, end_x: Option<f64>) -> DirichletBc {
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.x.abs() < 1e-12 {
            bc.fix_dof(3 * i, 0.0);
            if v.y.abs() < 1e-12 && v.z.abs() < 1e-12 {
                bc.fix_node(i, *v);
            } else if v.y.abs() < 1e-12 {
                bc.fix_dof(3 * i + 1, 0.0);
            } else if v.z.abs() < 1e-12 {
                bc.fix_dof(3 * i + 2, 0.0);
            }
        }
        if let Some(xe) = end_x
            && (v.x - L).abs() < 1e-12
        {
            bc.fix_dof(3 * i, xe);
        }
    }
    bc
}

fn end_reaction(
    model: &ElastoplasticModel,
    mesh: &softcap_mesh::TetMesh,
    x: &[Vector3<f64>],
) -> f64 {
    let f = model.internal_forces(x);
    mesh.vertices
        .iter()
        .enumerate()
        .filter(|(_, v)| (v.x - L).abs() < 1e-12)
        .map(|(i, _)| f[i].x)
        .sum()
}

/// Loads the bar to axial strain `eps_max` in `steps` (committing after each), unloads to zero
/// force, and returns (peak end force [N], residual axial strain).
fn load_unload(eps_max: f64, steps: usize) -> (f64, f64, ElastoplasticModel) {
    let mesh = bar();
    let young = 1.0e4;
    let el = LinearParams::from_young_poisson(young, 0.3).unwrap();
    let pl = J2PlasticityParams {
        yield_stress_pa: 50.0,
        hardening_modulus_pa: 2.0e3,
    };
    let mut model = ElastoplasticModel::homogeneous(&mesh, el, pl).unwrap();
    let mut x = mesh.vertices.clone();
    let settings = EquilibriumSettings::newton();
    let load_bc = rollers(&mesh, Some(L));
    let mut solver = StaticSolver::with_bc(&model, &load_bc).unwrap();
    let zero = vec![Vector3::zeros(); x.len()];
    for s in 1..=steps {
        let bc = rollers(&mesh, Some(L * (1.0 + eps_max * s as f64 / steps as f64)));
        bc.apply(&mut x);
        let rep = solver.solve(&mut model, &mut x, &zero, None, &settings);
        assert!(rep.converged(), "load step {s}: {rep:?}");
        // The bound guards the consistent tangent's fast convergence. A load step past yield
        // takes 8 or 9 iterations, and which one depends on rounding at the tolerance: the
        // Newton polar factor the element uses and the SVD one differ in the last bits.
        assert!(
            rep.iterations <= 10,
            "Newton took {} iterations: {rep:?}",
            rep.iterations
        );
        model.commit(&x);
    }
    let peak = end_reaction(&model, &mesh, &x);
    // Unload: release the end (force-free), rollers kept.
    let free_bc = rollers(&mesh, None);
    let mut solver = StaticSolver::with_bc(&model, &free_bc).unwrap();
    let rep = solver.solve(&mut model, &mut x, &zero, None, &settings);
    assert!(rep.converged(), "unload: {rep:?}");
    model.commit(&x);
    let end: Vec<f64> = mesh
        .vertices
        .iter()
        .enumerate()
        .filter(|(_, v)| (v.x - L).abs() < 1e-12)
        .map(|(i, _)| x[i].x)
        .collect();
    let mean_end = end.iter().sum::<f64>() / end.len() as f64;
    for e in &end {
        assert!((e - mean_end).abs() < 1e-10, "end face not plane: {end:?}");
    }
    (peak, mean_end / L - 1.0, model)
}

#[test]
fn bar_loaded_past_yield_keeps_the_analytic_permanent_strain() {
    // E = 1e4 Pa, σ_y = 50 Pa (yield strain 0.005), H = 2e3 Pa, strain-controlled to 0.02:
    // ε_p = (E ε_max − σ_y)/(E + H) = 150/12000 = 0.0125; peak stress σ_y + H ε_p = 75 Pa.
    let (young, sy, h, eps_max) = (1.0e4, 50.0, 2.0e3, 0.02);
    let eps_p = (young * eps_max - sy) / (young + h);
    let (peak, residual, model) = load_unload(eps_max, 4);
    eprintln!(
        "plasticity: permanent strain {residual:.10} vs analytic {eps_p:.10} (err {:.1e}), peak force {peak:.6} N",
        (residual - eps_p).abs()
    );
    assert!(
        (residual - eps_p).abs() < 1e-8,
        "permanent strain {residual} vs analytic {eps_p}"
    );
    let area = W * W;
    let peak_expected = (sy + h * eps_p) * area;
    assert!(
        (peak - peak_expected).abs() < 1e-8 * peak_expected,
        "peak force {peak} vs {peak_expected}"
    );
    // Every element carries the same J2 state: ε_p = diag(1, −½, −½) ε_p, ᾱ = ε_p.
    for st in model.plastic_states() {
        assert!((st.equivalent_plastic_strain - eps_p).abs() < 1e-9);
        assert!((st.plastic_strain[(0, 0)] - eps_p).abs() < 1e-9);
        assert!((st.plastic_strain[(1, 1)] + 0.5 * eps_p).abs() < 1e-9);
    }
}

#[test]
fn bar_loaded_below_yield_has_no_permanent_set() {
    // ε_max = 0.004 < σ_y/E = 0.005.
    let (peak, residual, model) = load_unload(0.004, 2);
    eprintln!("plasticity: below yield residual strain {residual:.1e}");
    assert!(residual.abs() < 1e-12, "residual strain {residual}");
    assert!((peak - 1.0e4 * 0.004 * W * W).abs() < 1e-9);
    assert!(
        model
            .plastic_states()
            .iter()
            .all(|s| s.equivalent_plastic_strain == 0.0)
    );
}

#[test]
fn elastoplastic_tangent_matches_finite_differences_while_yielding() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [1, 1, 1]);
    let el = LinearParams::from_young_poisson(1.0e4, 0.3).unwrap();
    let pl = J2PlasticityParams {
        yield_stress_pa: 20.0,
        hardening_modulus_pa: 1.0e3,
    };
    let model = ElastoplasticModel::homogeneous(&mesh, el, pl).unwrap();
    let rot = Rotation3::from_euler_angles(0.4, -0.2, 0.7);
    let a = Matrix3::new(1.03, 0.01, 0.02, -0.01, 0.98, 0.015, 0.0, 0.02, 1.01);
    let x: Vec<Vector3<f64>> = mesh.vertices.iter().map(|v| rot * (a * v)).collect();
    let h = 1e-7;
    let mut worst: f64 = 0.0;
    for e in 0..model.elements().len() {
        let (rm, _, _) = model.element_return(e, &x);
        assert!(rm.delta_gamma > 0.0, "element {e} should yield");
        let k = model.element_matrix(e, &x, StiffnessKind::Consistent);
        let nodes = model.elements()[e].nodes;
        for b in 0..4 {
            for j in 0..3 {
                let mut xp = x.clone();
                let mut xm = x.clone();
                xp[nodes[b]][j] += h;
                xm[nodes[b]][j] -= h;
                let fp = model.element_forces(e, &xp);
                let fm = model.element_forces(e, &xm);
                for a in 0..4 {
                    let d = (fp[a] - fm[a]) / (2.0 * h);
                    for i in 0..3 {
                        worst = worst.max((d[i] - k[(3 * a + i, 3 * b + j)]).abs());
                    }
                }
            }
        }
        assert!(
            worst < 1e-5 * k.norm(),
            "element {e}: FD mismatch {worst} vs ‖K‖ {}",
            k.norm()
        );
    }
}

fn nh() -> NeoHookeanParams {
    NeoHookeanParams::from_young_poisson(1.0e4, 0.4).unwrap()
}

#[test]
fn plastic_gradient_shape_is_stress_free() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 0.5, 0.4], [3, 2, 2]);
    let mut model = PlasticNeoHookeanModel::homogeneous(&mesh, nh()).unwrap();
    let fp = Matrix3::new(1.3, 0.1, -0.05, 0.1, 0.8, 0.07, -0.05, 0.07, 1.1);
    model
        .set_plastic_gradients(&vec![fp; mesh.tets.len()])
        .unwrap();
    let rot = Rotation3::from_euler_angles(0.3, 1.1, -0.6);
    let x: Vec<Vector3<f64>> = mesh
        .vertices
        .iter()
        .map(|v| rot * (fp * v) + Vector3::new(0.2, -0.1, 0.3))
        .collect();
    let f = model.internal_forces(&x);
    let worst = f.iter().fold(0.0f64, |m, v| m.max(v.norm()));
    // Force scale: μ · area ≈ 4e3 · 0.1 = 4e2 N; stress-free to round-off.
    assert!(worst < 1e-10, "residual force {worst} N at F = R F_p");
    assert!(model.energy(&x).unwrap().abs() < 1e-12);
    // The undeformed rest shape is *not* stress-free under F_p ≠ I.
    let f0 = model.internal_forces(&mesh.vertices);
    assert!(f0.iter().fold(0.0f64, |m, v| m.max(v.norm())) > 1.0);
    // det F_p ≤ 0 is rejected with the tet named.
    let bad = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
    assert!(matches!(
        model.set_plastic_gradient(2, bad),
        Err(FemError::InvalidPlasticGradient { tet: 2, .. })
    ));
}

#[test]
fn equilibrium_under_piecewise_plastic_gradient_is_the_plastic_shape() {
    // Left half stretched plastically by 1.2 along x, right half virgin: a compatible plastic
    // field whose stress-free shape is x = 1.2 X (X ≤ ½), 0.6 + (X − ½) (X > ½).
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 0.2, 0.2], [4, 1, 1]);
    let mut model = PlasticNeoHookeanModel::homogeneous(&mesh, nh()).unwrap();
    let stretch = Matrix3::from_diagonal(&Vector3::new(1.2, 1.0, 1.0));
    let fps: Vec<Matrix3<f64>> = mesh
        .tets
        .iter()
        .map(|t| {
            let cx = t.iter().map(|&v| mesh.vertices[v].x).sum::<f64>() / 4.0;
            if cx < 0.5 {
                stretch
            } else {
                Matrix3::identity()
            }
        })
        .collect();
    model.set_plastic_gradients(&fps).unwrap();
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.norm() < 1e-12 {
            bc.fix_node(i, *v);
        } else if v.x.abs() < 1e-12 && v.z.abs() < 1e-12 {
            bc.fix_dof(3 * i, 0.0);
            bc.fix_dof(3 * i + 2, 0.0);
        } else if v.x.abs() < 1e-12 && v.y.abs() < 1e-12 {
            bc.fix_dof(3 * i, 0.0);
        }
    }
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut x = mesh.vertices.clone();
    let zero = vec![Vector3::zeros(); x.len()];
    let rep = solver.solve(
        &mut model,
        &mut x,
        &zero,
        None,
        &EquilibriumSettings::newton(),
    );
    assert!(rep.converged(), "{rep:?}");
    for (i, v) in mesh.vertices.iter().enumerate() {
        let ex = if v.x <= 0.5 {
            1.2 * v.x
        } else {
            0.6 + (v.x - 0.5)
        };
        let expect = Vector3::new(ex, v.y, v.z);
        assert!(
            (x[i] - expect).norm() < 1e-8,
            "node {i}: {} vs {expect}",
            x[i]
        );
    }
}

#[test]
fn plastic_neohookean_forces_and_tangent_match_finite_differences() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [1, 1, 1]);
    let mut model = PlasticNeoHookeanModel::homogeneous(&mesh, nh()).unwrap();
    let fps: Vec<Matrix3<f64>> = (0..mesh.tets.len())
        .map(|e| {
            let s = e as f64;
            plastic_from_vector(&softcap_fem::nalgebra::Vector6::new(
                1.1 + 0.05 * s.sin(),
                0.9,
                1.05,
                0.04 * s.cos(),
                -0.03,
                0.02,
            ))
        })
        .collect();
    model.set_plastic_gradients(&fps).unwrap();
    let x: Vec<Vector3<f64>> = mesh
        .vertices
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let s = i as f64;
            v * 1.05 + Vector3::new((1.3 * s).sin(), (0.7 * s).cos(), (2.1 * s).sin()) * 0.04
        })
        .collect();
    let h = 1e-6;
    // Forces = ∂E/∂x.
    let f = model.internal_forces(&x);
    let mut worst_f: f64 = 0.0;
    let fscale = f.iter().fold(0.0f64, |m, v| m.max(v.norm()));
    for n in 0..x.len() {
        for j in 0..3 {
            let mut xp = x.clone();
            let mut xm = x.clone();
            xp[n][j] += h;
            xm[n][j] -= h;
            let d = (model.energy(&xp).unwrap() - model.energy(&xm).unwrap()) / (2.0 * h);
            worst_f = worst_f.max((d - f[n][j]).abs());
        }
    }
    assert!(
        worst_f < 1e-6 * fscale,
        "force FD {worst_f} vs scale {fscale}"
    );
    // Tangent = ∂f/∂x, element by element.
    for e in 0..model.elements().len() {
        let k = model.element_matrix(e, &x, StiffnessKind::Consistent);
        let nodes = model.elements()[e].nodes;
        let mut worst: f64 = 0.0;
        for b in 0..4 {
            for j in 0..3 {
                let mut xp = x.clone();
                let mut xm = x.clone();
                xp[nodes[b]][j] += h;
                xm[nodes[b]][j] -= h;
                let fp = model.element_forces(e, &xp);
                let fm = model.element_forces(e, &xm);
                for a in 0..4 {
                    let d = (fp[a] - fm[a]) / (2.0 * h);
                    for i in 0..3 {
                        worst = worst.max((d[i] - k[(3 * a + i, 3 * b + j)]).abs());
                    }
                }
            }
        }
        assert!(worst < 1e-6 * k.norm(), "element {e}: tangent FD {worst}");
    }
    // The analytic ∂f/∂s (saito-barbic Appendix B) against central differences of the element
    // forces in each of the six plastic-strain components, every element (rel. 1e-7).
    let h = 1e-6;
    for e in 0..model.elements().len() {
        let jac = model.plastic_force_jacobian(e, &x);
        let s0 = plastic_to_vector(&fps[e]);
        for k in 0..6 {
            let force_at = |d: f64| {
                let mut m = model.clone();
                let mut s = s0;
                s[k] += d;
                m.set_plastic_gradient(e, plastic_from_vector(&s)).unwrap();
                m.element_forces(e, &x)
            };
            let (fp, fm) = (force_at(h), force_at(-h));
            for a in 0..4 {
                let fd = (fp[a] - fm[a]) / (2.0 * h);
                let an = jac.fixed_view::<3, 1>(3 * a, k).into_owned();
                assert!(
                    (fd - an).norm() < 1e-7 * jac.norm(),
                    "element {e} component {k} node {a}: analytic {an} vs FD {fd}"
                );
            }
        }
    }
}
