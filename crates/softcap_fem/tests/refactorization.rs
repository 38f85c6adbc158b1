//! Modified Newton for interactive probe loops ([`Refactorization::WhenStale`]): the numeric
//! factor is reused across iterations and frames, and the equilibria must be the ones of the
//! default solver ([`Refactorization::EveryIteration`]) to the solver tolerance — positions within
//! 2 × the displacement tolerance, probe force within 10 × the relative residual tolerance — for a
//! flat disk (fixed active set) and a sphere (growing patch, curved normals), frame by frame.
//! Full Newton that factors only at iterates taking a step ([`Refactorization::EveryStep`]) must
//! take the iterates of [`Refactorization::EveryIteration`]: the same iteration counts and
//! equilibria, also for J2 plasticity (no energy: the residual line search hands its forces to
//! the forces-only convergence test) pressed in and released with its history committed.

use softcap_fem::nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use softcap_fem::*;

type Frames = Vec<(Vec<Vector3<f64>>, f64, usize)>;

fn probe_loop(tip: TipShape, policy: Refactorization) -> Frames {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.06, 0.06, 0.02], [6, 6, 2]);
    let model = CorotationalModel::homogeneous(
        &mesh,
        LinearParams::from_young_poisson(5.0e4, 0.4).unwrap(),
    )
    .unwrap();
    press(
        &mesh,
        model,
        tip,
        policy,
        &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12],
        |_, _| {},
    )
}

/// The block `mesh` (base fixed) pressed by `tip` to 0.2 mm × each of `depths`, one solve per
/// frame, `commit` after each: per frame the positions, axial force and iterations.
fn press<M: ElasticModel>(
    mesh: &softcap_mesh::TetMesh,
    mut model: M,
    tip: TipShape,
    policy: Refactorization,
    depths: &[usize],
    commit: impl Fn(&mut M, &[Vector3<f64>]),
) -> Frames {
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.z.abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    let top: Vec<usize> = (0..mesh.vertices.len())
        .filter(|&i| (mesh.vertices[i].z - 0.02).abs() < 1e-12)
        .collect();
    let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    let probe = Probe::new(
        tip,
        Isometry3::from_parts(Translation3::new(0.03, 0.03, 0.02), down),
    )
    .unwrap();
    let settings = EquilibriumSettings {
        residual_tol_rel: 1e-6,
        displacement_tol_rel: 1e-7,
        refactorization: policy,
        ..Default::default()
    };
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut x = mesh.vertices.clone();
    let f = vec![Vector3::zeros(); x.len()];
    let mut out = Vec::new();
    for (frame, &depth) in depths.iter().enumerate() {
        let contact = ContactProblem {
            probe: probe.advanced(2e-4 * depth as f64),
            candidate_nodes: top.clone(),
            settings: ContactSettings::default(),
        };
        let rep = solver.solve(&mut model, &mut x, &f, Some(&contact), &settings);
        assert!(rep.converged(), "{policy:?} frame {frame}: {rep:?}");
        commit(&mut model, &x);
        out.push((x.clone(), rep.contact.axial_force_n, rep.iterations));
    }
    out
}

#[test]
fn factor_reuse_reaches_the_same_equilibria() {
    let tol_x = 1e-7 * (0.06f64 * 0.06 * 2.0 + 0.02 * 0.02).sqrt();
    for tip in [
        TipShape::Disk {
            radius_m: 0.012,
            thickness_m: 0.01,
        },
        TipShape::Sphere { radius_m: 0.02 },
    ] {
        let every = probe_loop(tip.clone(), Refactorization::EveryIteration);
        let reuse = probe_loop(tip.clone(), Refactorization::WhenStale);
        let (mut dx_max, mut df_max) = (0.0f64, 0.0f64);
        for ((xa, fa, _), (xb, fb, _)) in every.iter().zip(&reuse) {
            for (a, b) in xa.iter().zip(xb) {
                dx_max = dx_max.max((a - b).norm());
            }
            df_max = df_max.max(((fa - fb) / fa).abs());
        }
        let its = |r: &[(Vec<Vector3<f64>>, f64, usize)]| r.iter().map(|t| t.2).sum::<usize>();
        println!(
            "{tip:?}: max |Δx| {dx_max:.2e} m (tol {tol_x:.2e}), max rel ΔF {df_max:.2e}, iterations {} vs {}",
            its(&every),
            its(&reuse)
        );
        assert!(dx_max <= 2.0 * tol_x, "{dx_max}");
        assert!(df_max <= 1e-5, "{df_max}");
        assert!(every.last().unwrap().1 > 0.1, "probe must load the block");
    }
}

/// The largest position difference of two runs, and whether their iteration counts agree.
fn compare(a: &Frames, b: &Frames) -> (f64, bool) {
    let dx = a
        .iter()
        .zip(b)
        .flat_map(|(p, q)| p.0.iter().zip(&q.0).map(|(u, v)| (u - v).norm()))
        .fold(0.0, f64::max);
    let same_iterations = a.iter().zip(b).all(|(p, q)| p.2 == q.2);
    (dx, same_iterations)
}

#[test]
fn factoring_only_at_steps_takes_the_full_newton_iterates() {
    let tol_x = 1e-7 * (0.06f64 * 0.06 * 2.0 + 0.02 * 0.02).sqrt();
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.06, 0.06, 0.02], [6, 6, 2]);
    let disk = TipShape::Disk {
        radius_m: 0.012,
        thickness_m: 0.01,
    };
    for tip in [disk.clone(), TipShape::Sphere { radius_m: 0.02 }] {
        let every = probe_loop(tip.clone(), Refactorization::EveryIteration);
        let step = probe_loop(tip.clone(), Refactorization::EveryStep);
        let (dx, same) = compare(&every, &step);
        println!("{tip:?}: max |Δx| {dx:.2e} m, same iterations {same}");
        assert!(same && dx <= 2.0 * tol_x, "{dx}");
    }
    // J2 plasticity: in to 2.4 mm, out to 0.4 mm, in again; the set stays.
    let plastic = |policy| {
        let model = ElastoplasticModel::homogeneous(
            &mesh,
            LinearParams::from_young_poisson(5.0e4, 0.4).unwrap(),
            J2PlasticityParams {
                yield_stress_pa: 4.0e3,
                hardening_modulus_pa: 2.0e3,
            },
        )
        .unwrap();
        let depths = [2, 4, 6, 8, 10, 12, 12, 8, 4, 2, 6, 12];
        press(&mesh, model, disk.clone(), policy, &depths, |m, x| {
            m.commit(x);
        })
    };
    let every = plastic(Refactorization::EveryIteration);
    let step = plastic(Refactorization::EveryStep);
    let (dx, same) = compare(&every, &step);
    let its = |r: &Frames| r.iter().map(|t| t.2).sum::<usize>();
    println!(
        "J2: max |Δx| {dx:.2e} m, iterations {} vs {}",
        its(&every),
        its(&step)
    );
    assert!(same && dx <= 2.0 * tol_x, "{dx}");
}
