//! Transversely isotropic elasticity (thesis eq. 8.5): uniaxial stretch along and across the fibre
//! gives the analytic moduli, the isotropic special case is bickel2009 eq. 5, PD check/projection,
//! and tangent / parameter derivatives against finite differences.

use softcap_fem::nalgebra::{Matrix3, Matrix6, Rotation3, Unit, Vector3};
use softcap_fem::*;

const L: f64 = 1.0;
const W: f64 = 0.2;

/// Roller supports at x = 0 (plus 3-2-1), prescribed axial end position at x = L: uniaxial stress.
fn rollers(mesh: &softcap_mesh::TetMesh, end_x: f64) -> DirichletBc {
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
        if (v.x - L).abs() < 1e-12 {
            bc.fix_dof(3 * i, end_x);
        }
    }
    bc
}

/// Apparent modulus σ/ε and lateral strains (y, z) of a bar stretched by `strain` along x.
fn uniaxial(p: TransverselyIsotropicParams, fibre: Vector3<f64>, strain: f64) -> (f64, f64, f64) {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [L, W, W], [4, 1, 1]);
    let mut model = AnisotropicModel::homogeneous(&mesh, p, Unit::new_normalize(fibre)).unwrap();
    let bc = rollers(&mesh, L * (1.0 + strain));
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut x = mesh.vertices.clone();
    bc.apply(&mut x);
    let zero = vec![Vector3::zeros(); x.len()];
    let rep = solver.solve(
        &mut model,
        &mut x,
        &zero,
        None,
        &EquilibriumSettings::newton(),
    );
    assert!(rep.converged(), "{rep:?}");
    let f = model.internal_forces(&x);
    let mut force = 0.0;
    for (i, v) in mesh.vertices.iter().enumerate() {
        if (v.x - L).abs() < 1e-12 {
            force += f[i].x;
        }
    }
    let corner = mesh
        .vertices
        .iter()
        .position(|v| (v - Vector3::new(L, W, W)).norm() < 1e-12)
        .unwrap();
    let ey = x[corner].y / W - 1.0;
    let ez = x[corner].z / W - 1.0;
    (force / (W * W) / strain, ey, ez)
}

fn printed() -> TransverselyIsotropicParams {
    // Soft across the tubes, stiff along them: E_t = 2e4, E_a = 8e4, ν_t = 0.35, ν_a = 0.25,
    // G_a = 1.2e4 (Pa).
    TransverselyIsotropicParams::from_engineering(2.0e4, 8.0e4, 0.35, 0.25, 1.2e4).unwrap()
}

#[test]
fn uniaxial_stretch_along_and_across_the_fibre_gives_the_analytic_moduli() {
    let p = printed();
    // The closed-form moduli of the eq. 8.5 matrix equal the engineering constants.
    assert!((p.young_fibre_pa() - 8.0e4).abs() < 1e-8 * 8.0e4);
    assert!((p.young_transverse_pa() - 2.0e4).abs() < 1e-8 * 2.0e4);
    let strain = 0.01;
    // Along the fibre: modulus E_a, both lateral strains −ν_a ε.
    let (e_along, ey, ez) = uniaxial(p, Vector3::x(), strain);
    eprintln!(
        "anisotropy: along fibre {e_along:.6} Pa (analytic {:.6}), lateral {ey:.3e} {ez:.3e}",
        p.young_fibre_pa()
    );
    assert!(
        (e_along - p.young_fibre_pa()).abs() < 1e-6 * p.young_fibre_pa(),
        "along: {e_along} vs {}",
        p.young_fibre_pa()
    );
    assert!((ey + 0.25 * strain).abs() < 1e-8 && (ez + 0.25 * strain).abs() < 1e-8);
    // Across the fibre (fibre along y): modulus E_t; lateral −ν_t ε in the transverse plane (z)
    // and −ν_a E_t/E_a ε along the fibre (y) by compliance symmetry.
    let (e_across, ey, ez) = uniaxial(p, Vector3::y(), strain);
    eprintln!(
        "anisotropy: across fibre {e_across:.6} Pa (analytic {:.6})",
        p.young_transverse_pa()
    );
    assert!(
        (e_across - p.young_transverse_pa()).abs() < 1e-6 * p.young_transverse_pa(),
        "across: {e_across} vs {}",
        p.young_transverse_pa()
    );
    assert!((ez + 0.35 * strain).abs() < 1e-8, "{ez}");
    assert!((ey + 0.25 * 2.0e4 / 8.0e4 * strain).abs() < 1e-8, "{ey}");
    // Fibre along z is also "across".
    let (e_z, _, _) = uniaxial(p, Vector3::z(), strain);
    assert!((e_z - p.young_transverse_pa()).abs() < 1e-6 * p.young_transverse_pa());
}

#[test]
fn isotropic_special_case_is_bickel_eq5_in_any_fibre_frame() {
    let iso = LinearParams::from_young_poisson(3.0e4, 0.3).unwrap();
    let p = TransverselyIsotropicParams::from_isotropic(&iso);
    let fibre = Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8));
    let c = stiffness_in_frame(&p.stiffness_local(), &fibre);
    let e = iso.stress_strain_matrix();
    assert!((c - e).norm() < 1e-9 * e.norm(), "{c} vs {e}");
    // A rotated TI material: C(fibre) = T(Q) C_local T(Q)ᵀ is symmetric and PD-preserving.
    let c2 = stiffness_in_frame(&printed().stiffness_local(), &fibre);
    assert!((c2 - c2.transpose()).norm() < 1e-9 * c2.norm());
    // E_a along an arbitrary fibre: σ_aa for a uniaxial stress state along the fibre.
    let comp = c2.try_inverse().unwrap();
    let a = fibre.into_inner();
    let sigma = voigt_dyad(&a);
    let eps = comp * sigma;
    let eaa = eps.dot(&sigma);
    assert!((1.0 / eaa - 8.0e4).abs() < 1e-6 * 8.0e4, "{}", 1.0 / eaa);
}

#[test]
fn positive_definiteness_check_and_projection() {
    let good = printed();
    assert!(good.is_positive_definite());
    // Projection leaves a PD set (above the floor) unchanged.
    let same = good.project_positive_definite(1.0);
    for (a, b) in same.to_vector().iter().zip(good.to_vector()) {
        assert!((a - b).abs() < 1e-9 * b.abs().max(1.0));
    }
    // E13 too large: the normal block is indefinite.
    let bad = TransverselyIsotropicParams {
        e13_pa: 1.0e5,
        ..good
    };
    assert!(!bad.is_positive_definite());
    assert!(matches!(
        bad.validate(4),
        Err(FemError::NotPositiveDefinite { element: 4, .. })
    ));
    let floor = 1.0e3;
    let fixed = bad.project_positive_definite(floor);
    let eig = fixed.mandel_eigenvalues();
    assert!(eig.iter().all(|&l| l >= floor * (1.0 - 1e-9)), "{eig:?}");
    // Unaffected eigenvalues are kept (E11 − E12 and 2E44).
    let before = bad.mandel_eigenvalues();
    assert!((eig[0] - before[0]).abs() < 1e-9 * before[0]);
    assert!((eig[1] - before[1]).abs() < 1e-9 * before[1]);
    assert!((eig[3] - before[3]).abs() < 1e-9 * before[3]);
    // The 6×6 Mandel matrix really is PD (smallest eigenvalue from nalgebra).
    let c = fixed.stiffness_local();
    let t = softcap_fem::nalgebra::Matrix6::from_diagonal(&softcap_fem::nalgebra::Vector6::new(
        1.0,
        1.0,
        1.0,
        2f64.sqrt(),
        2f64.sqrt(),
        2f64.sqrt(),
    ));
    let mandel = t * c * t;
    let min = mandel.symmetric_eigenvalues().min();
    assert!(min >= floor * (1.0 - 1e-9), "min eigenvalue {min}");
    // A fitter's set_params projects and reports.
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [1, 1, 1]);
    let mut model =
        AnisotropicModel::homogeneous(&mesh, good, Unit::new_normalize(Vector3::z())).unwrap();
    let mut ps = model.params().to_vec();
    ps[1] = bad;
    assert_eq!(model.set_params(&ps, 1e-3).unwrap(), 1);
    assert!(model.params().iter().all(|p| p.is_positive_definite()));
    assert!(AnisotropicModel::homogeneous(&mesh, bad, Unit::new_normalize(Vector3::z())).is_err());
}

#[test]
fn tangent_and_parameter_forces_match_finite_differences() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [1, 1, 1]);
    let fibre = Unit::new_normalize(Vector3::new(0.2, 0.9, -0.4));
    let model = AnisotropicModel::homogeneous(&mesh, printed(), fibre).unwrap();
    let rot = Rotation3::from_euler_angles(0.5, -0.4, 0.9);
    let a = Matrix3::new(1.04, 0.02, -0.01, 0.03, 0.97, 0.02, -0.02, 0.01, 1.05);
    let x: Vec<Vector3<f64>> = mesh
        .vertices
        .iter()
        .enumerate()
        .map(|(i, v)| rot * (a * v) + Vector3::new((i as f64).sin(), 0.0, (i as f64).cos()) * 0.01)
        .collect();
    let h = 1e-6;
    assert!(model.energy(&x).is_none());
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
                for aa in 0..4 {
                    let d = (fp[aa] - fm[aa]) / (2.0 * h);
                    for i in 0..3 {
                        worst = worst.max((d[i] - k[(3 * aa + i, 3 * b + j)]).abs());
                    }
                }
            }
        }
        assert!(worst < 1e-6 * k.norm(), "element {e}: tangent FD {worst}");
        // Forces are linear in p: f(p) = Σ_k p_k ∂f/∂p_k exactly.
        let pf = model.parameter_forces(e, &x);
        let pv = printed().to_vector();
        let fe = model.element_forces(e, &x);
        for aa in 0..4 {
            let mut sum = Vector3::zeros();
            for kk in 0..5 {
                sum += pf[kk][aa] * pv[kk];
            }
            assert!((sum - fe[aa]).norm() < 1e-9 * fe[aa].norm().max(1e-9));
        }
    }
}

/// Regression (issue 8, synth's anisotropy truth diverged above fibre ratio 5): Newton with the
/// exact non-symmetric tangent of the anisotropic corotational element must be solved with that
/// matrix (sparse LU, `SparseCholesky::factor_general`), not with a symmetric factorization of its
/// lower triangle. A 40 × 40 × 20 mm block (E 50 kPa, ν_t 0.4, ν_a 0.1, tendon-like fibre 10× and
/// 20× stiffer, 45° to the surface), base fixed, pressed 2.6 mm by a 5 mm-radius disk in 4
/// increments (synth's ramp): every increment converges, quadratically (few iterations), to the
/// synth truth's tolerances.
#[test]
fn newton_converges_on_a_stiff_oblique_fibre_under_a_disk_press() {
    use softcap_fem::nalgebra::{Isometry3, Translation3, UnitQuaternion};
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [6, 6, 3]);
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.z <= 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    let candidates: Vec<usize> = (0..mesh.vertices.len())
        .filter(|&i| mesh.vertices[i].z >= 0.02 - 1e-12)
        .collect();
    let settings = EquilibriumSettings {
        max_iterations: 60,
        displacement_tol_rel: 1e-9,
        residual_tol_rel: 1e-7,
        ..EquilibriumSettings::newton()
    };
    let e = 5.0e4;
    for ratio in [10.0, 20.0] {
        let p =
            TransverselyIsotropicParams::from_engineering(e, ratio * e, 0.4, 0.1, e / 2.8).unwrap();
        let fibre = Unit::new_normalize(Vector3::new(1.0, 0.0, 1.0));
        let mut model = AnisotropicModel::homogeneous(&mesh, p, fibre).unwrap();
        assert!(!model.tangent_is_symmetric(StiffnessKind::Consistent));
        assert!(model.tangent_is_symmetric(StiffnessKind::Warped));
        let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
        let mut x = mesh.vertices.clone();
        let zero = vec![Vector3::zeros(); x.len()];
        let mut worst_iterations = 0;
        for step in 1..=4 {
            let depth = 0.0026 * step as f64 / 4.0;
            let pose = Isometry3::from_parts(
                Translation3::new(0.021, 0.019, 0.02 - depth),
                UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
            );
            let contact = ContactProblem {
                probe: Probe::new(
                    TipShape::Disk {
                        radius_m: 0.005,
                        thickness_m: 0.002,
                    },
                    pose,
                )
                .unwrap(),
                candidate_nodes: candidates.clone(),
                settings: ContactSettings::default(),
            };
            let rep = solver.solve(&mut model, &mut x, &zero, Some(&contact), &settings);
            eprintln!(
                "ratio {ratio}, depth {:.2} mm: {:?} after {} iterations, |r| {:.3e} N, force {:.4} N",
                depth * 1e3,
                rep.status,
                rep.iterations,
                rep.residual_norm_n,
                rep.contact.contact_force_n.norm()
            );
            assert!(rep.converged(), "ratio {ratio}, step {step}: {rep:?}");
            assert_eq!(solver.cholesky().kind(), Some(FactorKind::Lu));
            worst_iterations = worst_iterations.max(rep.iterations);
        }
        // Newton with the exact tangent: 4 iterations per increment measured (the symmetric
        // factor of the lower triangle took 6–12 at ratio 10 and 8–45 at ratio 20 on this mesh,
        // and diverged on synth's 3000-tet truth mesh at ratio 10).
        assert!(
            worst_iterations <= 8,
            "ratio {ratio}: {worst_iterations} iterations"
        );
    }
}

/// HGO fibre families (HGO 2000 §4.2, linearized): one family along the fibre axis of an isotropic
/// matrix is exactly the transversely isotropic matrix of eq. 8.5 with E33 raised by 4 k1 (same
/// element forces at a finitely rotated, strained configuration); two families at ±θ about x in the
/// xy-plane are orthotropic in the (x, y, z) frame (no normal–shear coupling) and stiffer along x
/// than along y for θ < 45° (by 4 k1 · 2 (cos⁴θ − sin⁴θ) on the normal diagonal); the tangent
/// matches finite differences.
#[test]
fn fibre_families_are_hgo_linearized_and_orthotropic() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [1, 1, 1]);
    let iso = TransverselyIsotropicParams::from_isotropic(
        &LinearParams::from_young_poisson(5.0e4, 0.45).unwrap(),
    );
    let nt = mesh.tets.len();
    let z = Unit::new_normalize(Vector3::z());
    let k1 = 2.0e4;
    let one = vec![
        vec![FibreFamily {
            direction: z,
            k1_pa: k1
        }];
        nt
    ];
    let fam =
        AnisotropicModel::with_fibre_families(&mesh, vec![iso; nt], vec![z; nt], &one).unwrap();
    let mut ti = iso;
    ti.e33_pa += 4.0 * k1;
    let reference = AnisotropicModel::homogeneous(&mesh, ti, z).unwrap();
    let rot = Rotation3::from_euler_angles(0.3, -0.2, 0.7);
    let a = Matrix3::new(1.03, 0.02, -0.01, 0.01, 0.98, 0.03, -0.02, 0.01, 1.04);
    let x: Vec<Vector3<f64>> = mesh.vertices.iter().map(|v| rot * (a * v)).collect();
    for e in 0..nt {
        let (f, g) = (fam.element_forces(e, &x), reference.element_forces(e, &x));
        for i in 0..4 {
            assert!(
                (f[i] - g[i]).norm() < 1e-9 * g[i].norm().max(1.0),
                "element {e}"
            );
        }
    }
    // two families at ±30° about x in the xy-plane
    let theta = 30f64.to_radians();
    let pair = symmetric_fibre_pair(&Vector3::x(), &Vector3::z(), theta).unwrap();
    assert!((pair[0].y + pair[1].y).abs() < 1e-15 && (pair[0].x - theta.cos()).abs() < 1e-15);
    let two: Vec<FibreFamily> = pair
        .iter()
        .map(|&direction| FibreFamily {
            direction,
            k1_pa: k1,
        })
        .collect();
    let c: Matrix6<f64> = two.iter().map(fibre_family_stiffness).sum();
    for (i, j) in [
        (0, 3),
        (1, 3),
        (2, 3),
        (0, 4),
        (1, 5),
        (3, 4),
        (3, 5),
        (4, 5),
    ] {
        assert!(
            c[(i, j)].abs() < 1e-9 * k1,
            "coupling ({i}, {j}) = {}",
            c[(i, j)]
        );
    }
    let (c4, s4) = (theta.cos().powi(4), theta.sin().powi(4));
    assert!((c[(0, 0)] - c[(1, 1)] - 8.0 * k1 * (c4 - s4)).abs() < 1e-9 * k1);
    assert!(symmetric_fibre_pair(&Vector3::z(), &Vector3::z(), theta).is_none());
    let model =
        AnisotropicModel::with_fibre_families(&mesh, vec![iso; nt], vec![z; nt], &vec![two; nt])
            .unwrap();
    assert!(
        AnisotropicModel::with_fibre_families(
            &mesh,
            vec![iso; nt],
            vec![z; nt],
            &vec![
                vec![FibreFamily {
                    direction: z,
                    k1_pa: -1.0
                }];
                nt
            ],
        )
        .is_err()
    );
    let h = 1e-6;
    for e in 0..nt {
        let k = model.element_matrix(e, &x, StiffnessKind::Consistent);
        let nodes = model.elements()[e].nodes;
        let mut worst: f64 = 0.0;
        for b in 0..4 {
            for j in 0..3 {
                let (mut xp, mut xm) = (x.clone(), x.clone());
                xp[nodes[b]][j] += h;
                xm[nodes[b]][j] -= h;
                let (fp, fm) = (model.element_forces(e, &xp), model.element_forces(e, &xm));
                for aa in 0..4 {
                    let d = (fp[aa] - fm[aa]) / (2.0 * h);
                    for i in 0..3 {
                        worst = worst.max((d[i] - k[(3 * aa + i, 3 * b + j)]).abs());
                    }
                }
            }
        }
        assert!(worst < 1e-6 * k.norm(), "element {e}: tangent FD {worst}");
    }
}
