//! ∂K/∂p and J = ∂x/∂p (bickel2009 appendix eq. 10–12) against finite differences.

use softcap_fem::nalgebra::Vector3;
use softcap_fem::*;

struct Setup {
    mesh: softcap_mesh::TetMesh,
    model: CorotationalModel,
    bc: DirichletBc,
    f: Vec<Vector3<f64>>,
}

fn setup() -> Setup {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 2.0], [2, 2, 3]);
    let params: Vec<LinearParams> = (0..mesh.tets.len())
        .map(|e| {
            LinearParams::from_young_poisson(
                1.0e3 * (1.0 + 0.5 * ((e as f64) * 0.9).sin()),
                0.25 + 0.1 * ((e as f64) * 1.7).cos(),
            )
            .unwrap()
        })
        .collect();
    let model = CorotationalModel::new(&mesh, params).unwrap();
    let mut bc = DirichletBc::new();
    let mut f = vec![Vector3::zeros(); mesh.vertices.len()];
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.z == 0.0 {
            bc.fix_node(i, *v);
        }
        if v.z == 2.0 {
            f[i] = Vector3::new(60.0, 20.0, -30.0); // large enough to rotate the top noticeably
        }
    }
    Setup { mesh, model, bc, f }
}

fn solve(s: &Setup, model: &mut CorotationalModel) -> Vec<Vector3<f64>> {
    let mut solver = StaticSolver::with_bc(model, &s.bc).unwrap();
    let mut x = s.mesh.vertices.clone();
    let settings = EquilibriumSettings {
        residual_tol_rel: 1e-13,
        displacement_tol_rel: 1e-14,
        ..EquilibriumSettings::newton()
    };
    let rep = solver.solve(model, &mut x, &s.f, None, &settings);
    assert!(rep.converged() || rep.residual_norm_n < 1e-9, "{rep:?}");
    x
}

fn perturbed(model: &CorotationalModel, param: usize, h: f64) -> CorotationalModel {
    let mut m = model.clone();
    let mut p = m.params().to_vec();
    if param.is_multiple_of(2) {
        p[param / 2].lambda += h;
    } else {
        p[param / 2].alpha += h;
    }
    m.set_params(&p).unwrap();
    m
}

#[test]
fn exact_jacobian_matches_fd_of_nonlinear_solve() {
    let s = setup();
    let mut model = s.model.clone();
    let x = solve(&s, &mut model);
    let max_disp = x
        .iter()
        .zip(&s.mesh.vertices)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    let mut solver = StaticSolver::with_bc(&model, &s.bc).unwrap();
    let sens = Sensitivity::new(&mut solver, &model, &x, StiffnessKind::Consistent, None).unwrap();
    let params: Vec<usize> = vec![
        lambda_index(0),
        alpha_index(0),
        lambda_index(17),
        alpha_index(30),
        lambda_index(71),
        alpha_index(71),
    ];
    let j = sens.jacobian_columns(&params).unwrap();
    let mut worst: f64 = 0.0;
    println!(
        "max displacement {max_disp:.3} m; J = dx/dp (exact, consistent tangent) vs central FD of the nonlinear solve"
    );
    println!("| param | ||J_i|| | ||J_i - FD|| / ||FD|| |");
    for (c, &p) in params.iter().enumerate() {
        let base = if p.is_multiple_of(2) {
            model.params()[p / 2].lambda
        } else {
            model.params()[p / 2].alpha
        };
        let h = 1e-5 * base.abs();
        let xp = solve(&s, &mut perturbed(&model, p, h));
        let xm = solve(&s, &mut perturbed(&model, p, -h));
        let mut num = 0.0;
        let mut den = 0.0;
        let mut nj = 0.0;
        for d in 0..3 * x.len() {
            let fd = (xp[d / 3][d % 3] - xm[d / 3][d % 3]) / (2.0 * h);
            num += (j[(d, c)] - fd).powi(2);
            den += fd * fd;
            nj += j[(d, c)].powi(2);
        }
        let rel = (num / den).sqrt();
        println!("| {p} | {:.3e} | {rel:.2e} |", nj.sqrt());
        worst = worst.max(rel);
    }
    assert!(worst < 1e-5, "worst relative error {worst}");
    // Adjoint rows agree with the columns; Jᵀr agrees with the explicit product.
    let observed: Vec<usize> = (0..3 * x.len()).step_by(7).collect();
    let rows = sens.jacobian_rows(&observed).unwrap();
    for (r, &d) in observed.iter().enumerate() {
        for (c, &p) in params.iter().enumerate() {
            assert!((rows[(r, p)] - j[(d, c)]).abs() <= 1e-9 * (1.0 + j[(d, c)].abs()) * 1e3);
        }
    }
    let res: Vec<f64> = (0..3 * x.len())
        .map(|d| ((d as f64) * 0.37).sin())
        .collect();
    let jtr = sens.jt_times(&res).unwrap();
    for (c, &p) in params.iter().enumerate() {
        let explicit: f64 = (0..3 * x.len()).map(|d| j[(d, c)] * res[d]).sum();
        assert!((jtr[p] - explicit).abs() <= 1e-9 * explicit.abs().max(1e-12));
    }
}

#[test]
fn paper_jacobian_eq11_matches_fd_of_frozen_rotation_problem() {
    let s = setup();
    let mut model = s.model.clone();
    let x = solve(&s, &mut model);
    let rotations = model.rotations(&x);
    let frozen = |m: &CorotationalModel| {
        let mut solver = StaticSolver::with_bc(m, &s.bc).unwrap();
        let mut y = x.clone();
        solver
            .solve_frozen_rotations(m, &rotations, &mut y, &s.f)
            .unwrap();
        y
    };
    // At the nonlinear equilibrium, eq. 10 with frozen rotations returns the same x.
    let x10 = frozen(&model);
    let drift = x10
        .iter()
        .zip(&x)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(drift < 1e-9, "eq. 10 fixed point drift {drift}");
    let mut solver = StaticSolver::with_bc(&model, &s.bc).unwrap();
    let sens = Sensitivity::new(&mut solver, &model, &x, StiffnessKind::Warped, None).unwrap();
    let params = vec![
        lambda_index(3),
        alpha_index(3),
        lambda_index(50),
        alpha_index(64),
    ];
    let j = sens.jacobian_columns(&params).unwrap();
    let mut worst: f64 = 0.0;
    for (c, &p) in params.iter().enumerate() {
        let base = if p.is_multiple_of(2) {
            model.params()[p / 2].lambda
        } else {
            model.params()[p / 2].alpha
        };
        let h = 1e-5 * base.abs();
        let (xp, xm) = (
            frozen(&perturbed(&model, p, h)),
            frozen(&perturbed(&model, p, -h)),
        );
        let (mut num, mut den) = (0.0, 0.0);
        for d in 0..3 * x.len() {
            let fd = (xp[d / 3][d % 3] - xm[d / 3][d % 3]) / (2.0 * h);
            num += (j[(d, c)] - fd).powi(2);
            den += fd * fd;
        }
        worst = worst.max((num / den).sqrt());
    }
    println!("bickel2009 eq. 11 (warped, frozen R) vs FD of eq. 10: worst rel err {worst:.2e}");
    assert!(worst < 1e-6);
}

#[test]
fn stiffness_parameter_derivative_matches_fd() {
    let s = setup();
    let e = 11;
    let g = &s.model.elements()[e];
    let p = s.model.params()[e];
    let rot = softcap_fem::nalgebra::Rotation3::from_euler_angles(0.2, 0.9, -0.4).into_inner();
    for param in [lambda_index(e), alpha_index(e)] {
        let dk = element_stiffness_derivative(&s.model, param);
        let h = 1e-3 * p.lambda;
        let (mut pp, mut pm) = (p, p);
        if param.is_multiple_of(2) {
            pp.lambda += h;
            pm.lambda -= h;
        } else {
            pp.alpha += h;
            pm.alpha -= h;
        }
        let fd = (warped_stiffness(g, &pp, &rot) - warped_stiffness(g, &pm, &rot)) / (2.0 * h);
        let mut analytic = Matrix12::zeros();
        for a in 0..4 {
            for b in 0..4 {
                let blk = rot * dk.fixed_view::<3, 3>(3 * a, 3 * b) * rot.transpose();
                analytic
                    .fixed_view_mut::<3, 3>(3 * a, 3 * b)
                    .copy_from(&blk);
            }
        }
        let rel = (analytic - fd).norm() / fd.norm();
        println!("dK/dp_{param} (R dK_e R^T) vs FD: rel err {rel:.2e}");
        assert!(rel < 1e-9);
    }
}
