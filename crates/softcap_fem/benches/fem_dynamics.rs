//! Criterion benches of issue 4's dynamic terms at ~5k tets (a 10 × 10 × 9-cell block, 5,400 tets,
//! clamped at z = 0): one implicit time step (Newmark, Rayleigh damping, Newton to convergence)
//! with gravity, one viscoelastic quasi-static step, and a 20-mode shift-invert Lanczos eigen-solve.

use criterion::{Criterion, criterion_group, criterion_main};
use softcap_fem::nalgebra::Vector3;
use softcap_fem::*;
use std::hint::black_box;

fn block() -> (softcap_mesh::TetMesh, CorotationalModel, DirichletBc) {
    let cells = [10, 10, 9];
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.1, 0.1, 0.09], cells);
    let model = CorotationalModel::homogeneous(
        &mesh,
        LinearParams::from_young_poisson(5.0e4, 0.4).unwrap(),
    )
    .unwrap();
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.z.abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    (mesh, model, bc)
}

fn dynamic_step(c: &mut Criterion) {
    let (mesh, mut model, bc) = block();
    let masses = lumped_masses(&model, 1000.0);
    let gravity = gravity_forces(&masses, Vector3::new(9.81, 0.0, 0.0));
    let settings = DynamicsSettings {
        time_step_s: 1e-3,
        damping: RayleighDamping {
            alpha_per_s: 1.0,
            beta_s: 1e-3,
        },
        ..DynamicsSettings::default()
    };
    let mut solver = DynamicSolver::with_bc(&model, masses, &bc).unwrap();
    let mut g = c.benchmark_group("dynamics");
    g.sample_size(10);
    g.bench_function(format!("newmark_step_{}_tets", mesh.tets.len()), |b| {
        b.iter_batched(
            || DynamicState::at_rest(mesh.vertices.clone()),
            |mut state| {
                let rep = solver.step(&mut model, &mut state, &gravity, None, None, &settings);
                black_box(rep)
            },
            criterion::BatchSize::LargeInput,
        )
    });
    let (_, base, _) = block();
    let mut ve =
        ViscoelasticModel::new(base, PronySeries::standard_linear_solid(0.5, 0.1).unwrap())
            .unwrap();
    let mut statics = StaticSolver::with_bc(&ve, &bc).unwrap();
    g.bench_function(
        format!("viscoelastic_quasi_static_step_{}_tets", mesh.tets.len()),
        |b| {
            b.iter_batched(
                || mesh.vertices.clone(),
                |mut x| {
                    let rep = viscoelastic_quasi_static_step(
                        &mut statics,
                        &mut ve,
                        &mut x,
                        &gravity,
                        None,
                        None,
                        0.01,
                        &EquilibriumSettings::default(),
                    );
                    black_box(rep)
                },
                criterion::BatchSize::LargeInput,
            )
        },
    );
    g.finish();
}

fn eigen_solve(c: &mut Criterion) {
    let (mesh, model, bc) = block();
    let masses = lumped_masses(&model, 1000.0);
    let fixed = bc.dofs();
    let mut g = c.benchmark_group("modal");
    g.sample_size(10);
    g.bench_function(format!("lanczos_20_modes_{}_tets", mesh.tets.len()), |b| {
        b.iter(|| {
            let m = lanczos_modes(&model, &masses, &fixed, &ModalSettings::default()).unwrap();
            assert!(m.report.converged);
            black_box(m)
        })
    });
    g.finish();
}

criterion_group!(benches, dynamic_step, eigen_solve);
criterion_main!(benches);
