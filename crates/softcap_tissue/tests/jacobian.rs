//! Tissue-level check of the eq. 9 Jacobian (bickel2009 appendix eq. 10–12): on a session read
//! the way `softcap tissue fit` reads it (capture.mcap in SI + the mm Gmsh mesh → embedded
//! markers, attached support region, force boundary condition over the probed patch of the
//! session's tip radius), the adjoint marker Jacobian ∂x_markers/∂(λ_e, α_e) of a heterogeneous
//! material at a captured example's equilibrium agrees with central finite differences of the
//! simulated markers.

use crate::common;

use common::{SessionSpec, write_session};
use softcap_fem::{CorotationalModel, EquilibriumSettings, LinearParams, StiffnessKind};
use softcap_mcap::capture::CaptureData;
use softcap_probing::{PatchSettings, marker_jacobian};
use softcap_tissue::{ExampleSelection, prepare, read_volume_mesh};

#[test]
fn marker_jacobian_of_a_prepared_session_matches_finite_differences() {
    let dir = tempfile::tempdir().unwrap();
    let s = write_session(
        dir.path(),
        &SessionSpec {
            locations: vec![[0.0105, 0.0150]],
            forces_n: vec![1.0],
            ..SessionSpec::default()
        },
    );
    let capture = CaptureData::read(&s.capture).unwrap();
    let mesh = read_volume_mesh(&s.mesh, 1e-3).unwrap();
    let prepared = prepare(&capture, mesh, &s.mesh, &ExampleSelection::default()).unwrap();
    let setup = &prepared.setup;
    let ex = &prepared.selected[0].example;
    assert!(ex.force_n.norm() > 0.5, "{:?}", ex.force_n);
    let t = setup.num_elements();
    // A heterogeneous material (E 20–50 kPa varying over the tets, ν 0.3–0.45), so the
    // Jacobian is not the symmetric one of a homogeneous block.
    let params: Vec<LinearParams> = (0..t)
        .map(|e| {
            let w = (e as f64 * 0.37).sin();
            LinearParams::from_young_poisson(3.5e4 + 1.5e4 * w, 0.375 + 0.075 * w).unwrap()
        })
        .collect();
    let patch = PatchSettings {
        radius_m: prepared.tip_radius_m,
        ..PatchSettings::default()
    };
    let forces = setup.nodal_forces(ex, &patch);
    let tight = EquilibriumSettings {
        max_iterations: 100,
        displacement_tol_rel: 1e-13,
        residual_tol_rel: 1e-12,
        ..EquilibriumSettings::newton()
    };
    let solve = |p: &[LinearParams]| {
        let mut model = CorotationalModel::new(&setup.mesh, p.to_vec()).unwrap();
        let mut solver = setup.solver(&model).unwrap();
        let mut x = setup.mesh.vertices.clone();
        let rep = setup.simulate(&mut solver, &mut model, &mut x, &forces, &tight);
        assert!(rep.converged(), "{rep:?}");
        (model, solver, x)
    };
    let (model, mut solver, x) = solve(&params);
    let rows = marker_jacobian(
        setup,
        &mut solver,
        &model,
        ex,
        &x,
        StiffnessKind::Consistent,
    )
    .unwrap();
    assert_eq!(rows.len(), 3 * ex.observed.len());
    // Columns to check: the 6 most sensitive parameters and 2 of middling sensitivity.
    let norm = |j: usize| rows.iter().map(|r| r[j] * r[j]).sum::<f64>().sqrt();
    let mut order: Vec<usize> = (0..2 * t).collect();
    order.sort_by(|&a, &b| norm(b).total_cmp(&norm(a)).then(a.cmp(&b)));
    let mut cols: Vec<usize> = order[..6].to_vec();
    cols.extend([order[t / 2], order[t]]);
    let markers = |x: &[softcap_fem::nalgebra::Vector3<f64>]| -> Vec<f64> {
        let pos = setup.marker_positions(x);
        ex.observed
            .iter()
            .flat_map(|o| pos[o.marker].iter().copied().collect::<Vec<_>>())
            .collect()
    };
    let scale = norm(order[0]) / (rows.len() as f64).sqrt();
    let mut worst: f64 = 0.0;
    for &j in &cols {
        let (e, is_alpha) = (j / 2, j % 2 == 1);
        let base = if is_alpha {
            params[e].alpha
        } else {
            params[e].lambda
        };
        let h = 1e-5 * params[e].lambda;
        let perturbed = |d: f64| {
            let mut p = params.clone();
            if is_alpha {
                p[e].alpha = base + d;
            } else {
                p[e].lambda = base + d;
            }
            markers(&solve(&p).2)
        };
        let (plus, minus) = (perturbed(h), perturbed(-h));
        for (i, row) in rows.iter().enumerate() {
            let fd = (plus[i] - minus[i]) / (2.0 * h);
            // Both in m/Pa; compared relative to the largest column's RMS entry.
            worst = worst.max((row[j] - fd).abs() / scale);
        }
    }
    eprintln!(
        "tissue-level adjoint vs central FD: worst |J − J_fd| / RMS(J[:, max]) = {worst:.2e} over {} columns (largest column RMS {scale:.3e} m/Pa)",
        cols.len()
    );
    // Central differences with h = 1e-5 λ: truncation O(h²) and round-off of the 1e-13 equilibrium
    // tolerance are both ≤ 1e-6 of the scale; 1e-4 leaves room for the Newton tolerance.
    assert!(worst < 1e-4, "{worst:e}");
}
