//! Forces and stiffness matrices of both elements, and the neo-Hookean PK1 / ∂P/∂F, against
//! central finite differences.

use softcap_fem::nalgebra::{Matrix3, Vector3};
use softcap_fem::*;

fn rest() -> Vec<Vector3<f64>> {
    vec![
        Vector3::new(0.1, 0.0, 0.0),
        Vector3::new(1.0, 0.2, 0.1),
        Vector3::new(0.2, 1.1, 0.0),
        Vector3::new(0.0, 0.3, 0.9),
    ]
}

fn deformed() -> Vec<Vector3<f64>> {
    // A large rotation plus stretch and shear.
    let r = softcap_fem::nalgebra::Rotation3::from_euler_angles(0.4, -0.7, 1.1);
    let a = Matrix3::new(1.2, 0.1, -0.05, 0.0, 0.85, 0.15, 0.05, -0.1, 1.05);
    rest()
        .iter()
        .enumerate()
        .map(|(i, p)| r * (a * p) + Vector3::new(0.3, -0.2, 0.1 * i as f64))
        .collect()
}

fn fd_matrix(f: impl Fn(&[Vector3<f64>]) -> [Vector3<f64>; 4], x: &[Vector3<f64>]) -> Matrix12 {
    let h = 1e-6;
    let mut k = Matrix12::zeros();
    for b in 0..4 {
        for j in 0..3 {
            let mut xp = x.to_vec();
            let mut xm = x.to_vec();
            xp[b][j] += h;
            xm[b][j] -= h;
            let (fp, fm) = (f(&xp), f(&xm));
            for a in 0..4 {
                for i in 0..3 {
                    k[(3 * a + i, 3 * b + j)] = (fp[a][i] - fm[a][i]) / (2.0 * h);
                }
            }
        }
    }
    k
}

#[test]
fn corotational_force_is_gradient_of_energy_and_matches_eq7() {
    let g = TetGeometry::new(0, [0, 1, 2, 3], &rest()).unwrap();
    let p = LinearParams::from_young_poisson(3.0e3, 0.35).unwrap();
    let x = deformed();
    // f = R K_e (Rᵀx − X) literally (bickel2009 eq. 7, Müller & Gross 2004).
    let (r, _) = corotated_strain(&g.deformation_gradient(&x));
    let k = element_stiffness(&g, &p);
    let mut u = softcap_fem::nalgebra::SVector::<f64, 12>::zeros();
    for a in 0..4 {
        u.fixed_rows_mut::<3>(3 * a)
            .copy_from(&(r.transpose() * x[a] - rest()[a]));
    }
    let fk = k * u;
    let f = corotational_forces(&g, &p, &x);
    for a in 0..4 {
        let lit = r * fk.fixed_rows::<3>(3 * a);
        assert!(
            (lit - f[a]).norm() < 1e-10 * lit.norm().max(1.0),
            "R K (R^T x - X) mismatch at node {a}"
        );
    }
    // Energy ½ εᵀEε V: force equals its FD gradient (hyperelastic at fixed (λ, α)).
    let energy = |x: &[Vector3<f64>]| {
        let (_, e) = corotated_strain(&g.deformation_gradient(x));
        let ev = strain_voigt(&e);
        0.5 * g.volume_m3 * (ev.transpose() * p.stress_strain_matrix() * ev)[(0, 0)]
    };
    let h = 1e-6;
    let mut max_err: f64 = 0.0;
    for a in 0..4 {
        for i in 0..3 {
            let mut xp = x.clone();
            let mut xm = x.clone();
            xp[a][i] += h;
            xm[a][i] -= h;
            let fd = (energy(&xp) - energy(&xm)) / (2.0 * h);
            max_err = max_err.max((fd - f[a][i]).abs());
        }
    }
    let scale = f.iter().map(|v| v.norm()).fold(0.0, f64::max);
    println!(
        "corotational force vs FD energy gradient: max abs err {max_err:.3e} (|f| {scale:.3e})"
    );
    assert!(max_err < 1e-6 * scale);
}

#[test]
fn corotational_consistent_tangent_matches_fd_and_warped_at_rest() {
    let g = TetGeometry::new(0, [0, 1, 2, 3], &rest()).unwrap();
    let p = LinearParams::from_young_poisson(3.0e3, 0.35).unwrap();
    let x = deformed();
    let k = corotational_tangent(&g, &p, &x);
    let fd = fd_matrix(|y| corotational_forces(&g, &p, y), &x);
    let rel = (k - fd).norm() / fd.norm();
    let warped = warped_stiffness(&g, &p, &corotated_strain(&g.deformation_gradient(&x)).0);
    let rel_warped = (warped - fd).norm() / fd.norm();
    println!(
        "corotational tangent vs FD: consistent rel err {rel:.3e}, warped (bickel2009) rel err {rel_warped:.3e}"
    );
    assert!(rel < 1e-6, "consistent tangent rel err {rel}");
    assert!(
        (k - k.transpose()).norm() < 1e-8 * k.norm(),
        "consistent tangent not symmetric"
    );
    // At rest (and under pure rotation) the warped and consistent matrices coincide.
    let rot = softcap_fem::nalgebra::Rotation3::from_euler_angles(0.3, 0.2, -0.5);
    let xr: Vec<_> = rest().iter().map(|v| rot * v).collect();
    let kc = corotational_tangent(&g, &p, &xr);
    let kw = warped_stiffness(&g, &p, rot.matrix());
    assert!((kc - kw).norm() < 1e-9 * kw.norm());
}

#[test]
fn neohookean_pk1_and_tangent_match_fd() {
    let g = TetGeometry::new(0, [0, 1, 2, 3], &rest()).unwrap();
    let p = NeoHookeanParams::from_young_poisson(3.0e3, 0.45).unwrap();
    let x = deformed();
    // PK1 vs FD of Ψ.
    let f = g.deformation_gradient(&x);
    let h = 1e-6;
    let pk = pk1(&p, &f);
    let mut err: f64 = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            let mut fp = f;
            let mut fm = f;
            fp[(i, j)] += h;
            fm[(i, j)] -= h;
            err = err.max(
                ((energy_density(&p, &fp) - energy_density(&p, &fm)) / (2.0 * h) - pk[(i, j)])
                    .abs(),
            );
        }
    }
    println!(
        "neo-Hookean PK1 vs FD: max abs err {err:.3e} (|P| {:.3e})",
        pk.norm()
    );
    assert!(err < 1e-6 * pk.norm());
    // Rest stability: P(I) = 0.
    assert!(pk1(&p, &Matrix3::identity()).norm() < 1e-12);
    // Element tangent vs FD of element forces.
    let k = neohookean_tangent(&g, &p, &x);
    let fd = fd_matrix(|y| neohookean_forces(&g, &p, y), &x);
    let rel = (k - fd).norm() / fd.norm();
    println!("neo-Hookean tangent vs FD: rel err {rel:.3e}");
    assert!(rel < 1e-6);
    // Also through an inverted configuration.
    let mut xi = x.clone();
    xi[3] = x[0] + (x[0] - x[3]) * 0.3;
    let k = neohookean_tangent(&g, &p, &xi);
    let fd = fd_matrix(|y| neohookean_forces(&g, &p, y), &xi);
    assert!((k - fd).norm() / fd.norm() < 1e-6);
    // Small-strain response equals the corotational/linear element with the same Lamé parameters.
    let lin = LinearParams::from_young_poisson(3.0e3, 0.45).unwrap();
    let k_lin = element_stiffness(&g, &lin);
    let k_nh = neohookean_tangent(&g, &p, &rest());
    assert!((k_lin - k_nh).norm() < 1e-9 * k_lin.norm());
}
