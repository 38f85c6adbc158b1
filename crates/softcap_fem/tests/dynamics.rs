//! Damped single-mode oscillation of a cantilever (wang2015 eq. 3 with Rayleigh damping): the
//! frequency and decay rate measured from the simulated motion against theory, for implicit Euler
//! and Newmark (average acceleration).
//!
//! The beam starts at rest displaced along its first mode φ₁ (from [`dense_modes`]); with
//! Rayleigh damping the modes decouple, so the modal coordinate q_n = φ₁ᵀM(x_n − X) is exactly a
//! damped oscillation q_n = Re(c zⁿ). z is measured by least squares on q_{n+1} = 2Re(z) q_n −
//! |z|² q_{n−1}; decay rate σ = −ln|z|/h and damped frequency ω_d = arg(z)/h. Theory: the
//! continuous pole s = −ζω + iω√(1 − ζ²) with ζ = α/(2ω) + βω/2, mapped by the integrator
//! (backward Euler z = 1/(1 − hs), average acceleration = trapezoidal rule z = (1 + hs/2)/(1 − hs/2)).

use crate::common;
use softcap_fem::nalgebra::{Complex, Vector3};
use softcap_fem::*;

fn measure(q: &[f64], h: f64) -> (f64, f64) {
    // min Σ (q_{n+1} − c1 q_n − c2 q_{n−1})²
    let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for n in 1..q.len() - 1 {
        let (x1, x2, y) = (q[n], q[n - 1], q[n + 1]);
        a11 += x1 * x1;
        a12 += x1 * x2;
        a22 += x2 * x2;
        b1 += x1 * y;
        b2 += x2 * y;
    }
    let det = a11 * a22 - a12 * a12;
    let c1 = (b1 * a22 - b2 * a12) / det;
    let c2 = (a11 * b2 - a12 * b1) / det;
    let r = (-c2).sqrt();
    let theta = (c1 / (2.0 * r)).acos();
    (-r.ln() / h, theta / h)
}

/// A 1 m × 0.1 m × 0.1 m beam of 10 × 1 × 1 boxes (density 1000 kg/m³) clamped at x = 0: its
/// mesh, corotational model of Young's modulus `young` \[Pa\] and Poisson ratio `nu`, lumped
/// masses and the clamp.
fn cantilever(
    young: f64,
    nu: f64,
) -> (
    softcap_mesh::TetMesh,
    CorotationalModel,
    Vec<f64>,
    DirichletBc,
) {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 0.1, 0.1], [10, 1, 1]);
    let model =
        CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(young, nu).unwrap())
            .unwrap();
    let masses = lumped_masses(&model, 1000.0);
    let bc = clamped_at_x0(&mesh);
    (mesh, model, masses, bc)
}

/// Every node at x = 0 held at its rest position.
fn clamped_at_x0(mesh: &softcap_mesh::TetMesh) -> DirichletBc {
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.x.abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    bc
}

fn run(integrator: Integrator) -> (f64, f64, Complex<f64>, f64) {
    let (mesh, mut model, masses, bc) = cantilever(1e4, 0.0);
    let modes = dense_modes(&model, &masses, &bc.dofs(), 1).unwrap();
    let omega = modes.eigenvalues[0].sqrt();
    let phi = &modes.shapes[0];
    let zeta = 0.03;
    let damping = RayleighDamping {
        alpha_per_s: zeta * omega,
        beta_s: zeta / omega,
    };
    let period = 2.0 * std::f64::consts::PI / omega;
    let h = period / 40.0;
    let settings = DynamicsSettings {
        integrator,
        time_step_s: h,
        damping,
        residual_tol_rel: 1e-10,
        displacement_tol_rel: 1e-14,
        ..DynamicsSettings::default()
    };
    let amp = 1e-4;
    let x0: Vec<Vector3<f64>> = mesh
        .vertices
        .iter()
        .zip(phi)
        .map(|(x, p)| x + p * amp)
        .collect();
    let mut state = DynamicState::at_rest(x0);
    let mut solver = DynamicSolver::with_bc(&model, masses.clone(), &bc).unwrap();
    let zero = vec![Vector3::zeros(); mesh.vertices.len()];
    solver.initialize_acceleration(&model, &mut state, &zero, &settings);
    let modal = |x: &[Vector3<f64>]| -> f64 {
        (0..x.len())
            .map(|a| masses[a] * phi[a].dot(&(x[a] - mesh.vertices[a])))
            .sum()
    };
    let mut q = vec![modal(&state.positions_m)];
    for _ in 0..160 {
        let rep = solver.step(&mut model, &mut state, &zero, None, None, &settings);
        assert_eq!(rep.status, DynamicStepStatus::Converged, "{rep:?}");
        q.push(modal(&state.positions_m));
    }
    let (sigma, omega_d) = measure(&q, h);
    let s = Complex::new(-zeta * omega, omega * (1.0 - zeta * zeta).sqrt());
    (sigma, omega_d, s, h)
}

#[test]
fn newmark_damped_oscillator_matches_theory() {
    let (sigma, omega_d, s, h) = run(Integrator::NewmarkAverageAcceleration);
    let one = Complex::new(1.0, 0.0);
    let z = (one + s * (h / 2.0)) / (one - s * (h / 2.0));
    let (sd, wd) = (-z.norm().ln() / h, z.arg() / h);
    println!(
        "Newmark h = T/40: measured sigma {sigma:.8e} omega_d {omega_d:.8e}; discrete theory {sd:.8e} {wd:.8e}; continuous {:.8e} {:.8e}",
        -s.re, s.im
    );
    assert!((sigma - sd).abs() < 1e-6 * sd && (omega_d - wd).abs() < 1e-7 * wd);
    // Against the continuous oscillator at h = T/40: period elongation ≈ (ωh)²/12 = 2.1e-3,
    // decay-rate error 6.1e-3 (both second order in h).
    let ew = (omega_d - s.im).abs() / s.im;
    let es = (sigma + s.re).abs() / (-s.re);
    println!("Newmark vs continuous: rel. error omega_d {ew:.2e}, sigma {es:.2e}");
    assert!(ew < 3e-3 && es < 1e-2, "{ew:e} {es:e}");
}

#[test]
fn implicit_euler_damped_oscillator_matches_theory() {
    let (sigma, omega_d, s, h) = run(Integrator::ImplicitEuler);
    let z = Complex::new(1.0, 0.0) / (Complex::new(1.0, 0.0) - s * h);
    let (sd, wd) = (-z.norm().ln() / h, z.arg() / h);
    println!(
        "implicit Euler h = T/40: measured sigma {sigma:.8e} omega_d {omega_d:.8e}; discrete theory {sd:.8e} {wd:.8e}; continuous {:.8e} {:.8e}",
        -s.re, s.im
    );
    assert!((sigma - sd).abs() < 1e-6 * sd && (omega_d - wd).abs() < 1e-7 * wd);
    // Backward Euler adds numerical damping ≈ ω²h/2: the measured decay exceeds the physical one.
    assert!(sigma > -s.re);
}

/// A flat disk probe (radius 0.3 m) pressed 20 mm into a clamped block (ramped over 10 steps, then held): the damped
/// motion (implicit Euler, Rayleigh damping, contact springs re-queried per Newton iteration) settles
/// on the static contact solution of [`incremental_loading`] with the same probe path.
#[test]
fn probe_contact_dynamics_settle_on_static_solution() {
    use softcap_fem::nalgebra::{Isometry3, Translation3, UnitQuaternion};
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 0.5], [8, 8, 4]);
    let mut model =
        CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(1e4, 0.3).unwrap())
            .unwrap();
    let (bc, top) = common::block_supports(&mesh, 0.0, 0.5, false);
    let contact_at = |t: f64| ContactProblem {
        probe: Probe::new(
            TipShape::Disk {
                radius_m: 0.3,
                thickness_m: 0.05,
            },
            Isometry3::from_parts(
                Translation3::new(0.5, 0.5, 0.5 - 0.02 * t),
                UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
            ),
        )
        .unwrap(),
        candidate_nodes: top.clone(),
        settings: ContactSettings::default(),
    };
    let zero = vec![Vector3::zeros(); mesh.vertices.len()];
    let mut statics = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut xs = mesh.vertices.clone();
    let inc = incremental_loading(
        &mut statics,
        &mut model,
        &mut xs,
        |t| LoadState {
            external_forces_n: zero.clone(),
            prescribed: bc.clone(),
            contact: Some(contact_at(t)),
        },
        &IncrementalSettings::default(),
    );
    assert_eq!(inc.status, SolveStatus::Converged, "{inc:?}");
    let f_static = inc
        .steps
        .last()
        .unwrap()
        .equilibrium
        .contact
        .contact_force_n;
    let masses = lumped_masses(&model, 1000.0);
    let modes = dense_modes(&model, &masses, &bc.dofs(), 1).unwrap();
    let omega = modes.eigenvalues[0].sqrt();
    let settings = DynamicsSettings {
        integrator: Integrator::ImplicitEuler,
        time_step_s: 0.5 * 2.0 * std::f64::consts::PI / omega,
        damping: RayleighDamping {
            alpha_per_s: omega,
            beta_s: 0.0,
        },
        ..DynamicsSettings::default()
    };
    let mut solver = DynamicSolver::with_bc(&model, masses, &bc).unwrap();
    let mut state = DynamicState::at_rest(mesh.vertices.clone());
    let mut last = None;
    for n in 1..=60 {
        let c = contact_at((n as f64 / 10.0).min(1.0));
        last = Some(solver.step(&mut model, &mut state, &zero, None, Some(&c), &settings));
    }
    let last = last.unwrap();
    let err = state
        .positions_m
        .iter()
        .zip(&xs)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    let df = (last.contact.contact_force_n - f_static).norm() / f_static.norm();
    println!(
        "probe contact: static force {:.6e} N ({} nodes), dynamic (settled) {:.6e} N ({} nodes), max |x_dyn − x_static| {err:.2e} m, status {:?}",
        f_static.z,
        inc.steps
            .last()
            .unwrap()
            .equilibrium
            .contact
            .patch_nodes
            .len(),
        last.contact.contact_force_n.z,
        last.contact.patch_nodes.len(),
        last.status
    );
    assert!(f_static.norm() > 0.0);
    assert!(err < 1e-6, "{err:e}");
    assert!(df < 1e-4, "{df:e}");
}

/// Factorization reuse (`DynamicSolver::set_refactor_ratio`, a modified Newton method with
/// renewal) on a cantilever swinging through large rotations (tip 0.1 m on a 1 m beam): every
/// step converges to the same tolerance as Newton with a factorization per update, so the
/// trajectories agree to that tolerance, with fewer factorizations.
#[test]
fn factorization_reuse_follows_newtons_trajectory_with_fewer_factorizations() {
    let (mesh, model, masses, bc) = cantilever(3e6, 0.3);
    let gravity = gravity_forces(&masses, Vector3::new(0.0, 0.0, -9.81));
    let settings = DynamicsSettings {
        time_step_s: 0.01,
        damping: RayleighDamping {
            alpha_per_s: 0.5,
            beta_s: 1e-3,
        },
        residual_tol_rel: 1e-10,
        ..DynamicsSettings::default()
    };
    let run = |ratio: Option<f64>, residual_only: bool| {
        let mut model = model.clone();
        let mut solver = DynamicSolver::with_bc(&model, masses.clone(), &bc).unwrap();
        solver.set_refactor_ratio(ratio);
        solver.set_residual_only(residual_only);
        // Released from the straight bar: it falls and swings under gravity.
        let mut state = DynamicState::at_rest(mesh.vertices.clone());
        let mut tip = 0.0f64;
        let mut path = Vec::new();
        for _ in 0..100 {
            let rep = solver.step(&mut model, &mut state, &gravity, None, None, &settings);
            assert_eq!(
                rep.status,
                DynamicStepStatus::Converged,
                "{ratio:?}: {rep:?}"
            );
            tip = tip.max(state.positions_m.iter().map(|p| -p.z).fold(0.0, f64::max));
            path.push(state.positions_m.clone());
        }
        (path, solver.factorizations(), tip)
    };
    let (newton, newton_factors, tip) = run(None, true);
    let (reused, reused_factors, _) = run(Some(0.3), true);
    // The updates that reuse the factor evaluate the residual only (no element matrices): the
    // same iterates as assembling the matrix there too, to round-off.
    let (assembled, assembled_factors, _) = run(Some(0.3), false);
    let residual_only_gap = assembled
        .iter()
        .zip(&reused)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).norm()))
        .fold(0.0f64, f64::max);
    eprintln!(
        "residual-only vs assembled: {residual_only_gap:.2e} m, factorizations {reused_factors} vs {assembled_factors}"
    );
    assert!(
        residual_only_gap < 1e-9,
        "residual-only passes moved the trajectory by {residual_only_gap} m"
    );
    eprintln!(
        "tip {tip:.3} m; factorizations {newton_factors} (Newton) vs {reused_factors} (reuse)"
    );
    assert!(
        tip > 0.1,
        "tip deflection {tip} m: rotations too small to test"
    );
    let largest = newton
        .iter()
        .zip(&reused)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).norm()))
        .fold(0.0f64, f64::max);
    eprintln!("largest node distance {largest:.2e} m");
    // Both stop at ‖r‖ ≤ 1e-10 of the load, from different iterates: 1.4e-8 m measured.
    assert!(largest < 1e-7, "trajectories differ by {largest} m");
    assert!(
        2 * reused_factors < newton_factors,
        "{reused_factors} factorizations with reuse, {newton_factors} without"
    );
}

/// The residual-only element pass ([`ElasticModel::element_forces_products`], what an update
/// that reuses a factored matrix evaluates) against the full one
/// ([`ElasticModel::linearize_elements`]): the same element forces, and K_e v_e equal to the
/// formed element matrices times the nodal velocities, to round-off — for the corotational
/// model's closed form R K_e Rᵀ v_e = V R σ(sym(Rᵀ Ḟ)) g_a (warped), its formed consistent
/// tangent, and the trait default (neo-Hookean), on a bent, twisted and rotated bar with a
/// non-uniform velocity field (864 tets: the parallel element loop).
#[test]
fn residual_only_pass_equals_the_full_element_pass() {
    use softcap_fem::nalgebra::{Rotation3, SVector};
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.2, 0.03, 0.03], [16, 3, 3]);
    let rot = Rotation3::from_scaled_axis(Vector3::new(0.3, -1.1, 0.7));
    let x: Vec<Vector3<f64>> = mesh
        .vertices
        .iter()
        .map(|p| {
            let (s, c) = (4.0 * p.x).sin_cos();
            let bent = Vector3::new(
                p.x * (1.0 + 0.05 * p.y / 0.03),
                p.y * c - p.z * s + 0.02 * p.x * p.x,
                p.y * s + p.z * c - 0.3 * p.x * p.x,
            );
            rot * bent + Vector3::new(0.01, -0.02, 0.005)
        })
        .collect();
    let v: Vec<Vector3<f64>> = mesh
        .vertices
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let w = (i as f64 * 0.37).sin();
            Vector3::new(0.1 * w, -2.0 * p.x + 0.3 * p.z, 0.5 * p.x * p.x - 0.2 * w)
        })
        .collect();
    let corotational =
        CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(5e5, 0.45).unwrap())
            .unwrap();
    let neohookean = NeoHookeanModel::homogeneous(
        &mesh,
        NeoHookeanParams::from_young_poisson(5e5, 0.45).unwrap(),
    )
    .unwrap();
    let cases: [(&dyn ElasticModel, StiffnessKind, &str); 3] = [
        (&corotational, StiffnessKind::Warped, "corotational, warped"),
        (
            &corotational,
            StiffnessKind::Consistent,
            "corotational, consistent",
        ),
        (&neohookean, StiffnessKind::Consistent, "neo-Hookean"),
    ];
    let n = mesh.tets.len();
    assert!(n >= 256, "{n} tets: below the parallel loop's threshold");
    for (model, kind, what) in cases {
        let mut forces = vec![[Vector3::zeros(); 4]; n];
        let mut matrices = vec![Matrix12::zeros(); n];
        model.linearize_elements(0, &x, kind, &mut forces, &mut matrices);
        let mut only = vec![[Vector3::zeros(); 4]; n];
        let mut products = vec![[Vector3::zeros(); 4]; n];
        model.element_forces_products(0, &x, Some(&v), kind, &mut only, &mut products);
        let (mut f_err, mut f_max, mut p_err, mut p_max) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (e, g) in model.elements().iter().enumerate() {
            let mut ve = SVector::<f64, 12>::zeros();
            for q in 0..4 {
                ve.fixed_rows_mut::<3>(3 * q).copy_from(&v[g.nodes[q]]);
            }
            let kv = matrices[e] * ve;
            for q in 0..4 {
                f_err = f_err.max((only[e][q] - forces[e][q]).norm());
                f_max = f_max.max(forces[e][q].norm());
                p_err = p_err.max((products[e][q] - kv.fixed_rows::<3>(3 * q)).norm());
                p_max = p_max.max(kv.fixed_rows::<3>(3 * q).norm());
            }
        }
        eprintln!("{what}: forces {f_err:.1e} of {f_max:.1e}, K v {p_err:.1e} of {p_max:.1e}");
        assert!(f_max > 0.0 && p_max > 0.0, "{what}: nothing to compare");
        assert!(f_err <= 1e-12 * f_max, "{what}: forces differ by {f_err:e}");
        assert!(
            p_err <= 1e-12 * p_max,
            "{what}: K_e v_e differs by {p_err:e}"
        );
        // Without velocities the products are left as they were.
        let before = products.clone();
        model.element_forces_products(0, &x, None, kind, &mut only, &mut products);
        assert_eq!(products, before, "{what}");
    }
}

/// [`ElasticModel::step_tangent`] — the exact derivative of a step's element pass that
/// [`DynamicSolver::step_sensitivities`] iterates with — against central differences of the
/// step residual R = f_ext − f_int(x) − D v − M a ([`DynamicSolver::step_residual`]) along a
/// direction du on a bent, twisted, moving bar (Newmark, α = 0.8 1/s, β = 0.02 s, rotations up
/// to 1.3 rad): ∂R/∂x du = −(Σ_e df_e + (c_x + α c_v) M du), c_x = 4/h², c_v = 2/h. Within
/// 10⁻⁷ of |∂R/∂x du| (measured 3.0·10⁻¹⁰ with steps of 10⁻⁷ m, the differences' truncation
/// error: 3.0·10⁻⁶ at 10⁻⁵ m); the product the same bits on one thread and two. Checked to
/// fail: without the rotation derivative (w = 0) the miss is 3.9·10⁻², without the damping
/// force's change through R (β W σ_v and β W Rᵀ Ḟ dropped) 3.9·10⁻².
#[test]
fn step_tangent_matches_central_differences_of_the_step_residual() {
    use softcap_fem::nalgebra::Rotation3;
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.2, 0.03, 0.03], [16, 3, 3]);
    let model =
        CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(5e5, 0.45).unwrap())
            .unwrap();
    let masses = lumped_masses(&model, 1100.0);
    let bc = clamped_at_x0(&mesh);
    let mut solver = DynamicSolver::with_bc(&model, masses.clone(), &bc).unwrap();
    let bend = |curl: f64, twist: f64| -> Vec<Vector3<f64>> {
        let rot = Rotation3::from_scaled_axis(Vector3::new(0.0, 0.0, twist));
        mesh.vertices
            .iter()
            .map(|p| {
                let (s, c) = (curl * p.x).sin_cos();
                rot * Vector3::new(
                    p.x * (1.0 + 0.05 * p.y / 0.03),
                    p.y * c - p.z * s + 0.02 * p.x * p.x,
                    p.y * s + p.z * c - 0.3 * p.x * p.x,
                )
            })
            .collect()
    };
    let h = 2.5e-3;
    let settings = DynamicsSettings {
        integrator: Integrator::NewmarkAverageAcceleration,
        time_step_s: h,
        damping: RayleighDamping {
            alpha_per_s: 0.8,
            beta_s: 0.02,
        },
        ..DynamicsSettings::default()
    };
    let wave = |i: usize, k: f64| (i as f64 * k).sin();
    let before = DynamicState {
        time_s: 0.0,
        positions_m: bend(6.0, 0.2),
        velocities_m_s: (0..mesh.vertices.len())
            .map(|i| Vector3::new(0.1 * wave(i, 0.37), -0.4, 0.2 * wave(i, 0.11)))
            .collect(),
        accelerations_m_s2: (0..mesh.vertices.len())
            .map(|i| Vector3::new(wave(i, 0.23), 2.0, -wave(i, 0.7)))
            .collect(),
    };
    let x = bend(6.5, 0.21);
    let forces: Vec<Vector3<f64>> = masses
        .iter()
        .map(|m| Vector3::new(0.0, 0.0, -9.81 * m))
        .collect();
    let mut du: Vec<Vector3<f64>> = (0..mesh.vertices.len())
        .map(|i| Vector3::new(wave(i, 0.53), wave(i, 0.31), wave(i, 0.17)) * 1e-3)
        .collect();
    for d in bc.dofs() {
        du[d / 3][d % 3] = 0.0;
    }
    let t = 1e-4;
    let at = |solver: &mut DynamicSolver, sign: f64| {
        let xt: Vec<Vector3<f64>> = x.iter().zip(&du).map(|(a, d)| a + d * (sign * t)).collect();
        solver.step_residual(&model, &before, &xt, &forces, &settings)
    };
    let plus = at(&mut solver, 1.0);
    let minus = at(&mut solver, -1.0);
    let fd: Vec<f64> = plus
        .iter()
        .zip(&minus)
        .map(|(p, m)| (p - m) / (2.0 * t))
        .collect();
    // v_{n+1} of Newmark at x, and the tangent's product.
    let v: Vec<Vector3<f64>> = (0..x.len())
        .map(|i| {
            let a = (x[i] - before.positions_m[i] - before.velocities_m_s[i] * h) * (4.0 / (h * h))
                - before.accelerations_m_s2[i];
            before.velocities_m_s[i] + (before.accelerations_m_s2[i] + a) * (0.5 * h)
        })
        .collect();
    let (cx, cv) = (4.0 / (h * h), 2.0 / h);
    let tangent = model
        .step_tangent(&x, &v, StiffnessKind::Warped, settings.damping.beta_s, cv)
        .expect("corotational warped tangent");
    // The same bits on one thread and two (864 tets: the parallel element loop).
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut out = vec![Vec::new()];
        pool.install(|| tangent.apply(model.elements(), &[&du], &mut out));
        out
    };
    let out = on(1);
    assert_eq!(on(2), out, "one thread vs two");
    let c_mass = cx + settings.damping.alpha_per_s * cv;
    let full: Vec<Vector3<f64>> = out[0]
        .iter()
        .zip(&du)
        .zip(&masses)
        .map(|((o, d), m)| -(o + d * (c_mass * m)))
        .collect();
    let predicted = solver.dofs().gather(&full);
    let norm = |a: &[f64]| a.iter().map(|v| v * v).sum::<f64>().sqrt();
    let miss: Vec<f64> = predicted.iter().zip(&fd).map(|(p, f)| p - f).collect();
    let relative = norm(&miss) / norm(&fd);
    eprintln!(
        "|dR| {:.3e}, miss {relative:.2e}; strain part without the mass {:.3e}",
        norm(&fd),
        norm(&solver.dofs().gather(&out[0]))
    );
    assert!(norm(&fd) > 0.0 && relative < 1e-7, "{relative:.3e}");
    // The consistent tangent and strain-dependent models have none.
    assert!(
        model
            .step_tangent(&x, &v, StiffnessKind::Consistent, 0.02, cv)
            .is_none()
    );
}
