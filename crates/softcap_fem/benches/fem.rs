//! Criterion benches: assemble + factor + solve at 1k / 10k / 50k tets, and incremental loading
//! of a ~1.7k-tet block with probe contact (bickel2009 §3.4 ran ~10 Hz on such a model).
//!
//! The interactive-frame rate is the "one frame … factor reuse (modified Newton)" row:
//! `Refactorization::WhenStale` is the policy for a probe loop, which only reads the equilibrium
//! positions and forces of each frame and never the tangent factor afterwards (the default
//! `EveryIteration` keeps the factor of A at the solution for ∂x/∂f and is kept as a row for
//! comparison). A linear predictor (start each frame from x + (x − x_prev)) was tried and dropped:
//! it saves iterations (2.9 instead of 4.9 per frame) but its smaller first residual makes the
//! factor look stale more often, and the frame costs more (examples/probe_frames `predict`).

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use softcap_fem::nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use softcap_fem::*;
use std::hint::black_box;

fn block(cells: [usize; 3]) -> (softcap_mesh::TetMesh, CorotationalModel, DirichletBc) {
    let mesh = softcap_mesh::box_tet_mesh(
        [0.0; 3],
        [
            cells[0] as f64 * 0.01,
            cells[1] as f64 * 0.01,
            cells[2] as f64 * 0.01,
        ],
        cells,
    );
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

fn assemble_factor_solve(c: &mut Criterion) {
    let mut g = c.benchmark_group("assemble_factor_solve");
    g.sample_size(10);
    for (label, cells) in [
        ("1k", [8, 8, 3]),
        ("10k", [12, 12, 12]),
        ("50k", [20, 20, 21]),
    ] {
        let (mesh, model, bc) = block(cells);
        let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
        let x = mesh.vertices.clone();
        let nf = solver.dofs().num_free();
        let rhs: Vec<f64> = (0..nf).map(|i| (i as f64).sin()).collect();
        let id = format!("{label} ({} tets, {nf} dofs)", mesh.tets.len());
        g.bench_function(BenchmarkId::new("assemble+factor+solve", &id), |b| {
            b.iter(|| {
                solver
                    .assemble_and_factor(&model, &x, StiffnessKind::Warped, None)
                    .unwrap();
                let mut y = rhs.clone();
                solver.cholesky().solve_in_place(&mut y).unwrap();
                black_box(y)
            })
        });
        g.bench_function(BenchmarkId::new("symbolic (once per mesh)", &id), |b| {
            b.iter(|| black_box(StaticSolver::with_bc(&model, &bc).unwrap()))
        });
    }
    g.finish();
}

fn probe_loading(c: &mut Criterion) {
    let mut g = c.benchmark_group("incremental_loading_probe");
    g.sample_size(10);
    let (mesh, model, bc) = block([10, 10, 3]);
    let top: Vec<usize> = (0..mesh.vertices.len())
        .filter(|&i| (mesh.vertices[i].z - 0.03).abs() < 1e-12)
        .collect();
    let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    let probe = Probe::new(
        TipShape::Disk {
            radius_m: 0.015,
            thickness_m: 0.01,
        },
        Isometry3::from_parts(Translation3::new(0.05, 0.05, 0.03), down),
    )
    .unwrap();
    let id = format!(
        "{} tets, disk probe, 10 increments to 3 mm",
        mesh.tets.len()
    );
    let settings = IncrementalSettings {
        steps: 10,
        equilibrium: EquilibriumSettings {
            residual_tol_rel: 1e-6,
            displacement_tol_rel: 1e-7,
            ..Default::default()
        },
    };
    for (policy, tag) in [
        (Refactorization::EveryIteration, ""),
        (
            Refactorization::WhenStale,
            ", factor reuse (modified Newton)",
        ),
    ] {
        let settings = IncrementalSettings {
            equilibrium: EquilibriumSettings {
                refactorization: policy,
                ..settings.equilibrium.clone()
            },
            ..settings.clone()
        };
        let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
        g.bench_function(BenchmarkId::new(format!("full run{tag}"), &id), |b| {
            b.iter(|| {
                let mut m = model.clone();
                let mut x = mesh.vertices.clone();
                let rep = incremental_loading(
                    &mut solver,
                    &mut m,
                    &mut x,
                    |t| LoadState {
                        external_forces_n: vec![],
                        prescribed: bc.clone(),
                        contact: Some(ContactProblem {
                            probe: probe.advanced(0.003 * t),
                            candidate_nodes: top.clone(),
                            settings: ContactSettings::default(),
                        }),
                    },
                    &settings,
                );
                assert_eq!(rep.status, SolveStatus::Converged);
                black_box(x)
            })
        });
        // One interactive frame: advance the probe by 0.1 mm from the previous equilibrium.
        let mut m = model.clone();
        let mut x = mesh.vertices.clone();
        let mut depth = 0.0;
        g.bench_function(
            BenchmarkId::new(
                format!("one frame (0.1 mm increment, warm start){tag}"),
                &id,
            ),
            |b| {
                b.iter(|| {
                    depth = if depth > 0.004 { 0.0 } else { depth + 1e-4 };
                    let contact = ContactProblem {
                        probe: probe.advanced(depth),
                        candidate_nodes: top.clone(),
                        settings: ContactSettings::default(),
                    };
                    let f = vec![Vector3::zeros(); x.len()];
                    black_box(solver.solve(
                        &mut m,
                        &mut x,
                        &f,
                        Some(&contact),
                        &settings.equilibrium,
                    ))
                })
            },
        );
    }
    g.finish();
}

criterion_group!(benches, assemble_factor_solve, probe_loading);
criterion_main!(benches);
