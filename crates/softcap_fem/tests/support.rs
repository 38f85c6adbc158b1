//! Support slip: a block whose bottom face rests on a plane with tangential springs, under a
//! uniform shear load on its top face, translates by F/k_t (area-weighted mean, k_t the whole
//! base's stiffness) plus its fixed-base elastic shear; with Coulomb friction below μP it sticks.

use softcap_fem::nalgebra::{Unit, Vector3};
use softcap_fem::*;

fn block() -> (
    softcap_mesh::TetMesh,
    CorotationalModel,
    Vec<usize>,
    Vec<usize>,
) {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [1.0, 1.0, 0.5], [3, 3, 2]);
    let model = CorotationalModel::homogeneous(
        &mesh,
        LinearParams::from_young_poisson(1.0e4, 0.3).unwrap(),
    )
    .unwrap();
    let bottom = (0..mesh.vertices.len())
        .filter(|&i| mesh.vertices[i].z.abs() < 1e-12)
        .collect();
    let top = (0..mesh.vertices.len())
        .filter(|&i| (mesh.vertices[i].z - 0.5).abs() < 1e-12)
        .collect();
    (mesh, model, bottom, top)
}

fn mean_x(x: &[Vector3<f64>], rest: &[Vector3<f64>], nodes: &[usize]) -> f64 {
    nodes.iter().map(|&n| x[n].x - rest[n].x).sum::<f64>() / nodes.len() as f64
}

#[test]
fn block_on_tangential_springs_translates_by_f_over_kt_plus_elastic_shear() {
    let (mesh, mut model, bottom, top) = block();
    let force_n = 20.0;
    // the whole base: 100 N/m for each of its 16 nodes on average
    let kt = 1600.0;
    let mut f_ext = vec![Vector3::zeros(); mesh.vertices.len()];
    for &n in &top {
        f_ext[n].x = force_n / top.len() as f64;
    }
    let settings = EquilibriumSettings::newton();
    // Fixed base: elastic shear only.
    let mut bc = DirichletBc::new();
    for &n in &bottom {
        bc.fix_node(n, mesh.vertices[n]);
    }
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut xf = mesh.vertices.clone();
    assert!(
        solver
            .solve(&mut model, &mut xf, &f_ext, None, &settings)
            .converged()
    );
    let shear = mean_x(&xf, &mesh.vertices, &top);
    // Sliding base on springs (no Dirichlet constraint at all).
    let mut support = SupportPlane::new(
        Unit::new_normalize(Vector3::z()),
        0.0,
        bottom.clone(),
        &mesh.vertices,
        &mesh.boundary_faces(),
        SupportTangential::Springs {
            stiffness_n_per_m: kt,
        },
    )
    .unwrap();
    let mut solver = NodalSolver::new(&model, &[]).unwrap();
    let mut x = mesh.vertices.clone();
    let rep = solver.solve(&mut model, &mut x, &f_ext, &mut [&mut support], &settings);
    assert!(rep.converged(), "{rep:?}");
    let sr = support.report(&x);
    let rigid = force_n / kt;
    // Equilibrium: Σ w_i k_t u_i = F, so the area-weighted mean base slip is exactly F/k_t.
    assert!(
        (sr.mean_slip_m.x - rigid).abs() < 1e-8 * rigid,
        "{} vs {rigid}",
        sr.mean_slip_m.x
    );
    assert!((sr.tangential_force_n.x + force_n).abs() < 1e-8 * force_n);
    // Normal constraint kept: penalty gap tiny compared with the slip; no net normal reaction.
    assert!(
        sr.max_normal_gap_m < 1e-5 * rigid,
        "gap {}",
        sr.max_normal_gap_m
    );
    assert!(sr.normal_force_n.abs() < 1e-8 * force_n);
    // Top = rigid translation + the fixed-base elastic shear. Not exact: on springs the base
    // traction is redistributed (and the base slip is not uniform), measured 0.44 % of the total
    // with the area-weighted springs (1.0 % with an equal split per node) for k_t = 0.3 × the
    // block's shear stiffness.
    let top_mean = mean_x(&x, &mesh.vertices, &top);
    let rel = (top_mean - (rigid + shear)).abs() / (rigid + shear);
    eprintln!(
        "support springs: mean base slip {:.10} m vs F/k_t {rigid:.10} m; top {top_mean:.6} vs {:.6} (rel {rel:.2e}); gap {:.1e} m",
        sr.mean_slip_m.x,
        rigid + shear,
        sr.max_normal_gap_m
    );
    assert!(
        rel < 0.015,
        "top {top_mean} vs {} + {shear} (rel {rel})",
        rigid
    );
}

#[test]
fn block_on_frictional_plane_sticks_below_mu_p() {
    let (mesh, mut model, bottom, top) = block();
    let mu = 0.5;
    let pressure_n = 50.0;
    let shear_n = 0.5 * mu * pressure_n;
    let mut support = SupportPlane::new(
        Unit::new_normalize(Vector3::z()),
        0.0,
        bottom.clone(),
        &mesh.vertices,
        &mesh.boundary_faces(),
        SupportTangential::Friction(FrictionParams {
            mu,
            slip_distance_m: 1e-6,
        }),
    )
    .unwrap();
    let mut solver = NodalSolver::new(&model, &[]).unwrap();
    let mut x = mesh.vertices.clone();
    let settings = EquilibriumSettings::newton();
    // Press first, then shear (two load steps; friction history committed in between).
    for (fz, fx) in [(-pressure_n, 0.0), (-pressure_n, shear_n)] {
        let mut f = vec![Vector3::zeros(); x.len()];
        for &n in &top {
            f[n] = Vector3::new(fx, 0.0, fz) / top.len() as f64;
        }
        let rep = solver.solve(&mut model, &mut x, &f, &mut [&mut support], &settings);
        assert!(rep.converged(), "{rep:?}");
        support.commit(&x);
    }
    let sr = support.report(&x);
    assert!((sr.normal_force_n - pressure_n).abs() < 1e-6 * pressure_n);
    assert!((sr.tangential_force_n.x + shear_n).abs() < 1e-6 * shear_n);
    // Stuck: the base slips by a few regularization distances at most (nodes with little normal
    // load at the base rim may micro-slip), negligible against the elastic shear of the block.
    let top_mean = mean_x(&x, &mesh.vertices, &top);
    assert!(
        sr.mean_slip_m.norm() < 1e-2 * top_mean,
        "slip {} vs top {top_mean}",
        sr.mean_slip_m
    );
}

#[test]
fn block_dragged_over_frictional_plane_slides_at_mu_n() {
    // Top face clamped to a rigid plate: pressed down by 5 mm, then dragged 40 mm along x. Once
    // the base slides, the plane's tangential reaction is μ times its normal reaction.
    let (mesh, mut model, bottom, top) = block();
    let mu = 0.4;
    let mut support = SupportPlane::new(
        Unit::new_normalize(Vector3::z()),
        0.0,
        bottom.clone(),
        &mesh.vertices,
        &mesh.boundary_faces(),
        SupportTangential::Friction(FrictionParams {
            mu,
            slip_distance_m: 1e-5,
        }),
    )
    .unwrap();
    let mut bc = DirichletBc::new();
    for &n in &top {
        bc.fix_node(n, mesh.vertices[n]);
    }
    let mut solver = NodalSolver::new(&model, &bc.dofs()).unwrap();
    let mut x = mesh.vertices.clone();
    let zero = vec![Vector3::zeros(); x.len()];
    let settings = EquilibriumSettings::newton();
    let mut ratios = Vec::new();
    for k in 0..=8 {
        let s = 0.005 * k as f64;
        for &n in &top {
            x[n] = mesh.vertices[n] + Vector3::new(s, 0.0, -0.005);
        }
        let rep = solver.solve(&mut model, &mut x, &zero, &mut [&mut support], &settings);
        assert!(rep.converged(), "drag {s}: {rep:?}");
        support.commit(&x);
        let sr = support.report(&x);
        assert!(sr.normal_force_n > 0.0);
        ratios.push(sr.tangential_force_n.norm() / sr.normal_force_n);
    }
    // Never above μ; reaches μ (to 1e-4) once sliding; the base has slid most of the drag.
    assert!(ratios.iter().all(|&r| r <= mu * (1.0 + 1e-9)), "{ratios:?}");
    let last = *ratios.last().unwrap();
    eprintln!("support friction drag: T/N per step {ratios:.5?} (μ = {mu})");
    assert!((last - mu).abs() < 1e-4 * mu, "T/N = {last}");
    let sr = support.report(&x);
    assert!(sr.mean_slip_m.x > 0.02, "slip {}", sr.mean_slip_m.x);
    assert!(sr.tangential_force_n.x < 0.0);
}

/// The springs are weighted by the lumped area of the attached face: with the base's grid lines
/// moved to x = 0, 0.1, 0.2, 1 the area shares' centroid Σ w_i x_i is the face's, 0.5 (the equal
/// split's node mean is 0.325), the shares sum to 1, and a corner node of the wide column carries
/// more than one of the narrow columns.
#[test]
fn support_springs_are_weighted_by_lumped_area() {
    let (mesh, _, bottom, _) = block();
    let squeeze = |x: f64| match (3.0 * x).round() as i32 {
        0 => 0.0,
        1 => 0.1,
        2 => 0.2,
        _ => 1.0,
    };
    let positions: Vec<Vector3<f64>> = mesh
        .vertices
        .iter()
        .map(|v| Vector3::new(squeeze(v.x), v.y, v.z))
        .collect();
    let support = SupportPlane::new(
        Unit::new_normalize(Vector3::z()),
        0.0,
        bottom.clone(),
        &positions,
        &mesh.boundary_faces(),
        SupportTangential::Springs {
            stiffness_n_per_m: 100.0,
        },
    )
    .unwrap();
    let w = support.area_shares();
    assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    let centroid: Vector3<f64> = bottom
        .iter()
        .zip(w)
        .map(|(&n, &wi)| positions[n] * wi)
        .sum();
    assert!((centroid.x - 0.5).abs() < 1e-12, "{centroid}");
    assert!((centroid.y - 0.5).abs() < 1e-12, "{centroid}");
    let at = |x: f64, y: f64| {
        let i = bottom
            .iter()
            .position(|&n| (positions[n].x - x).abs() < 1e-12 && (positions[n].y - y).abs() < 1e-12)
            .unwrap();
        w[i]
    };
    assert!(
        at(1.0, 0.0) > 2.0 * at(0.0, 0.0),
        "{} vs {}",
        at(1.0, 0.0),
        at(0.0, 0.0)
    );
    // No attached triangle: springs cannot be weighted.
    assert!(
        SupportPlane::new(
            Unit::new_normalize(Vector3::z()),
            0.0,
            bottom,
            &positions,
            &[],
            SupportTangential::Springs {
                stiffness_n_per_m: 100.0,
            },
        )
        .is_err()
    );
}

/// Modified Newton with the factor reused across iterations and solves
/// (`Refactorization::WhenStale`, the springs' constant blocks never make it stale) reaches the
/// equilibria of full Newton (`EveryIteration`) on a loading sequence large enough to rotate the
/// corotational elements (top pushed down and sideways, 10 % of the height): every node within
/// 10⁻⁶ of the largest displacement, both converged at every step.
#[test]
fn support_springs_with_reused_factor_reach_full_newtons_equilibria() {
    let (mesh, model, bottom, top) = block();
    let support = SupportPlane::new(
        Unit::new_normalize(Vector3::z()),
        0.0,
        bottom,
        &mesh.vertices,
        &mesh.boundary_faces(),
        SupportTangential::Springs {
            stiffness_n_per_m: 1600.0,
        },
    )
    .unwrap();
    let run = |policy: Refactorization| {
        let (mut model, mut support) = (model.clone(), support.clone());
        let settings = EquilibriumSettings {
            refactorization: policy,
            ..EquilibriumSettings::newton()
        };
        let mut solver = NodalSolver::new(&model, &[]).unwrap();
        let mut x = mesh.vertices.clone();
        let mut steps = Vec::new();
        for k in 1..=6 {
            let load = Vector3::new(60.0, 20.0, -150.0) * (k as f64 / 6.0);
            let mut f = vec![Vector3::zeros(); x.len()];
            for &n in &top {
                f[n] = load / top.len() as f64;
            }
            let rep = solver.solve(&mut model, &mut x, &f, &mut [&mut support], &settings);
            assert!(rep.converged(), "{policy:?} step {k}: {rep:?}");
            steps.push(x.clone());
        }
        steps
    };
    let full = run(Refactorization::EveryIteration);
    let reused = run(Refactorization::WhenStale);
    let largest = full
        .last()
        .unwrap()
        .iter()
        .zip(&mesh.vertices)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(largest > 0.05, "displacement {largest} m");
    let worst = full
        .iter()
        .zip(&reused)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).norm()))
        .fold(0.0, f64::max);
    eprintln!(
        "support springs, reused factor: worst node difference {worst:.2e} m of {largest:.4} m"
    );
    assert!(worst < 1e-6 * largest, "{worst} m of {largest} m");
}
