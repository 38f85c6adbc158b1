//! Property tests (docs/reliability.md): random valid meshes, materials and loads through the
//! static and dynamic solvers. Every outcome is a converged result or a reported status — never a
//! panic — and a converged result has finite positions (a non-finite one is reported, not
//! returned as converged). Case counts are kept CI-cheap (`PROPTEST_CASES` raises them).

use crate::common;

use proptest::prelude::*;
use softcap_fem::nalgebra::Vector3;
use softcap_fem::*;

/// A jittered box mesh: size (m), cells per axis, a jitter fraction of a cell per vertex.
fn mesh(size: [f64; 3], cells: [usize; 3], jitter: &[f64]) -> softcap_mesh::TetMesh {
    let mut m = softcap_mesh::box_tet_mesh([0.0; 3], size, cells);
    let h = [0, 1, 2].map(|k| size[k] / cells[k] as f64);
    for (i, v) in m.vertices.iter_mut().enumerate() {
        for k in 0..3 {
            // Interior displacement only along each axis away from the faces the BC and load use.
            let at_face = v[k].abs() < 1e-12 || (v[k] - size[k]).abs() < 1e-12;
            if !at_face {
                v[k] += 0.2 * h[k] * jitter[(3 * i + k) % jitter.len()];
            }
        }
    }
    m
}

/// Bottom fixed, a uniform traction on the top.
fn problem(
    m: &softcap_mesh::TetMesh,
    size: [f64; 3],
    traction: Vector3<f64>,
) -> (DirichletBc, Vec<Vector3<f64>>) {
    let mut bc = DirichletBc::new();
    for (i, v) in m.vertices.iter().enumerate() {
        if v.z.abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    let f = common::traction_forces(
        m,
        |p| p.iter().all(|v| (v.z - size[2]).abs() < 1e-12),
        traction,
    );
    (bc, f)
}

fn finite(x: &[Vector3<f64>]) -> bool {
    x.iter().all(|v| v.iter().all(|c| c.is_finite()))
}

fn inputs() -> impl Strategy<Value = ([f64; 3], [usize; 3], Vec<f64>, f64, f64, [f64; 3])> {
    (
        [0.005f64..0.2, 0.005f64..0.2, 0.005f64..0.2],
        [1usize..4, 1usize..4, 1usize..3],
        prop::collection::vec(-1.0f64..1.0, 1..16),
        1.0e3f64..1.0e7,
        0.0f64..0.49,
        // Traction in units of E: up to a few percent strain, some far beyond.
        [-0.05f64..0.05, -0.05f64..0.05, -0.3f64..0.05],
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn static_solves_converge_or_report(
        (size, cells, jitter, young, nu, t) in inputs()
    ) {
        let m = mesh(size, cells, &jitter);
        let p = LinearParams::from_young_poisson(young, nu).unwrap();
        let (bc, f) = problem(&m, size, Vector3::from(t) * young);
        let settings = EquilibriumSettings::default();
        let mut corot = CorotationalModel::homogeneous(&m, p).unwrap();
        let mut solver = StaticSolver::with_bc(&corot, &bc).unwrap();
        let mut x = m.vertices.clone();
        let rep = solver.solve(&mut corot, &mut x, &f, None, &settings);
        prop_assert!(!rep.converged() || finite(&x), "converged with non-finite positions: {rep:?}");
        let nh = NeoHookeanParams::from_linear(&p).unwrap();
        let mut neo = NeoHookeanModel::homogeneous(&m, nh).unwrap();
        let mut solver = StaticSolver::with_bc(&neo, &bc).unwrap();
        let mut x = m.vertices.clone();
        let rep = solver.solve(&mut neo, &mut x, &f, None, &settings);
        prop_assert!(!rep.converged() || finite(&x), "neo-Hookean: {rep:?}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    #[test]
    fn dynamic_steps_converge_or_report(
        (size, cells, jitter, young, nu, t) in inputs(),
        density in 100.0f64..3000.0,
        dt in 1.0e-4f64..1.0e-1,
    ) {
        let m = mesh(size, cells, &jitter);
        let p = LinearParams::from_young_poisson(young, nu).unwrap();
        let (bc, f) = problem(&m, size, Vector3::from(t) * young);
        let mut model = CorotationalModel::homogeneous(&m, p).unwrap();
        let masses = lumped_masses(&model, density);
        let mut solver = DynamicSolver::with_bc(&model, masses, &bc).unwrap();
        let settings = DynamicsSettings { time_step_s: dt, ..DynamicsSettings::default() };
        let mut state = DynamicState::at_rest(m.vertices.clone());
        for _ in 0..3 {
            let rep = solver.step(&mut model, &mut state, &f, None, None, &settings);
            match rep.status {
                DynamicStepStatus::Failed { .. } => break,
                _ => prop_assert!(finite(&state.positions_m) && finite(&state.velocities_m_s),
                    "a step reported {:?} with non-finite state", rep.status),
            }
        }
    }
}
