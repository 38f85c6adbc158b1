//! Held-out probe on the three-layer block of tests/noise.rs: trained with a 4 mm disk (force
//! boundary condition) at four locations × 0.5 / 1.0 N, predicted: a 6 mm sphere pressed by rigid
//! contact (bickel2009 §3.4) to 0.8 N at a fifth location (issue 7: "a held-out probe — a location
//! and tip shape not in training — is predicted better than by the homogeneous model").

use softcap_fem::nalgebra::Vector3;
use softcap_fem::probing::{
    ContactSynthesisSettings, ObservedMarker, ProbeExample, ProbingSetup, probe_pose,
    simulate_probe_contact, support_nodes,
};
use softcap_fem::{
    CorotationalModel, EquilibriumSettings, NeoHookeanModel, NeoHookeanParams, PatchSettings,
    StrainSpaceModel, TipShape,
};
use softcap_mcap::capture::{Phase, SupportPlane};
use softcap_tissue::{FitSettings, PreparedSession, Progress, SessionExample, fit_session};

const SIZE_M: [f64; 3] = [0.03, 0.03, 0.015];
const TIP_RADIUS_M: f64 = 0.004;

/// Three layers (bottom → top) of stable neo-Hookean material, E in Pa.
const LAYERS_PA: [f64; 3] = [6.0e4, 3.0e4, 1.5e4];

fn three_layer_truth(mesh: &softcap_mesh::TetMesh) -> NeoHookeanModel {
    let params = mesh
        .tets
        .iter()
        .map(|t| {
            let z = t.iter().map(|&i| mesh.vertices[i].z).sum::<f64>() / 4.0;
            let layer = ((z / SIZE_M[2]) * 3.0).floor().clamp(0.0, 2.0) as usize;
            NeoHookeanParams::from_young_poisson(LAYERS_PA[layer], 0.45).unwrap()
        })
        .collect();
    NeoHookeanModel::new(mesh, params).unwrap()
}

fn setup() -> ProbingSetup {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], SIZE_M, [6, 6, 3]);
    let mut markers = Vec::new();
    for i in 0..6 {
        for j in 0..6 {
            markers.push(Vector3::new(
                0.0025 + 0.005 * i as f64,
                0.0025 + 0.005 * j as f64,
                SIZE_M[2],
            ));
        }
    }
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    ProbingSetup::new(mesh, &markers, fixed).unwrap()
}

/// Truth examples under the force boundary condition of a disk probe (bickel2009 §4.1).
fn truth_examples(
    setup: &ProbingSetup,
    truth: &mut NeoHookeanModel,
    locations: &[[f64; 2]],
    forces_n: &[f64],
) -> Vec<SessionExample> {
    let patch = PatchSettings {
        radius_m: TIP_RADIUS_M,
        ..Default::default()
    };
    let mut out = Vec::new();
    for (li, loc) in locations.iter().enumerate() {
        for &f in forces_n {
            let mut ex = ProbeExample {
                frame: out.len() as u64 + 1,
                time_s: 0.1 * (out.len() + 1) as f64,
                tip_m: Vector3::new(loc[0], loc[1], SIZE_M[2]),
                axis: -Vector3::z(),
                force_n: Vector3::new(0.0, 0.0, -f),
                observed: Vec::new(),
            };
            let nodes = setup.patch_nodes(&ex, &patch);
            let forces = setup.nodal_forces(&ex, &nodes);
            let mut solver = setup.solver(&*truth).unwrap();
            let mut x = setup.mesh.vertices.clone();
            let rep = setup.simulate(
                &mut solver,
                truth,
                &mut x,
                &forces,
                &EquilibriumSettings::newton(),
            );
            assert!(rep.converged(), "{rep:?}");
            ex.observed = setup
                .marker_positions(&x)
                .into_iter()
                .enumerate()
                .map(|(marker, position_m)| ObservedMarker { marker, position_m })
                .collect();
            out.push(SessionExample {
                example: ex,
                location: li,
                phase: Phase::Loading,
                frame_index: out.len() + 1,
                log_time_ns: 100_000_000 * (out.len() as u64 + 1),
            });
        }
    }
    out
}

fn prepared(setup: &ProbingSetup, examples: Vec<SessionExample>) -> PreparedSession {
    PreparedSession {
        setup: setup.clone(),
        locations: Vec::new(),
        all_examples: examples.clone(),
        selected: examples,
        tip_radius_m: TIP_RADIUS_M,
        support: SupportPlane {
            normal: [0.0, 0.0, 1.0],
            offset_m: 0.0,
            tolerance_m: 1e-9,
        },
    }
}

/// The default fit: γ_p of the per-example fits chosen by leave-one-location-out
/// cross-validation on the four training locations (the held-out sphere is never looked at).
fn settings() -> FitSettings {
    FitSettings {
        progress: false,
        ..FitSettings::default()
    }
}

/// Measured (docs/tissue.md): held-out marker RMS material 0.181 mm (depth 2.97 mm) vs
/// homogeneous 0.212 mm (depth 2.72 mm), truth depth 3.68 mm — with the trust-region LM and the
/// shrinkage γ_p = 1 of the per-example fits toward the reference field (session 4: 0.302 mm;
/// trust region alone 0.255 mm; eq. 8 without tail, session 3: 0.474 mm). At the truth's
/// held-out strains the material's λ stays within 1.22× of the tet's mean sample λ. Tolerances:
/// λ ratio ≤ 1.6; the relaxed synthesis converges to the force within 1 %; the material predicts
/// the held-out probe better than the homogeneous model (by ≥ 5 %).
#[test]
fn held_out_sphere_probe_is_predicted_better_than_by_the_homogeneous_model() {
    let setup = setup();
    let mut truth = three_layer_truth(&setup.mesh);
    let train = [
        [0.0105, 0.0105],
        [0.0195, 0.0105],
        [0.0105, 0.0195],
        [0.0195, 0.0195],
    ];
    let examples = truth_examples(&setup, &mut truth, &train, &[0.5, 1.0]);
    let fit = fit_session(
        &prepared(&setup, examples),
        &settings(),
        &Progress::hidden(),
    )
    .unwrap();
    assert_eq!(fit.outcome.material_failures, 0);
    for g in &fit.outcome.gamma_prior_scores {
        eprintln!(
            "γ_p = {}: leave-one-location-out RMS {:.4} mm ({} not converged), per-example fits {:.4} mm",
            g.gamma_prior,
            1e3 * g.heldout_rms_m,
            g.heldout_failures,
            1e3 * g.example_rms_m
        );
    }
    eprintln!("chosen γ_p = {}", fit.outcome.gamma_prior);
    assert_eq!(
        fit.outcome.gamma_prior_scores.len(),
        softcap_tissue::fit::DEFAULT_GAMMA_PRIOR_CANDIDATES.len()
    );
    let tip = TipShape::Sphere { radius_m: 0.006 };
    let pose = probe_pose(&Vector3::new(0.015, 0.0135, 0.025), &-Vector3::z());
    let force = 0.8;
    let cs = ContactSynthesisSettings::default();
    let truth_x =
        simulate_probe_contact(&setup, &mut truth, tip.clone(), pose, force, &cs).unwrap();
    // The material at the truth's held-out strains vs the tet's mean sample λ.
    let t = setup.num_elements();
    let homog = CorotationalModel::homogeneous(&setup.mesh, fit.homogeneous.params).unwrap();
    let strains = homog.strains(&truth_x.positions_m);
    let worst = (0..t)
        .map(|e| {
            let mean =
                fit.fits.iter().map(|f| f.params[e].lambda).sum::<f64>() / fit.fits.len() as f64;
            fit.material.evaluate(e, &strains[e]).lambda / mean
        })
        .fold(0.0, f64::max);
    let mut material = StrainSpaceModel::new(fit.material.clone(), &setup.mesh, 0.5).unwrap();
    let mat_x =
        simulate_probe_contact(&setup, &mut material, tip.clone(), pose, force, &cs).unwrap();
    eprintln!(
        "training examples: marker RMS homogeneous {:.4} mm, per-example {:.4} mm, material {:.4} mm",
        1e3 * fit.outcome.homogeneous_rms_m,
        1e3 * fit.outcome.example_rms_m,
        1e3 * fit.outcome.material_rms_m
    );
    let mut homog = homog;
    let hom_x = simulate_probe_contact(&setup, &mut homog, tip, pose, force, &cs).unwrap();
    let rms = |x: &[Vector3<f64>]| {
        let a = setup.marker_positions(x);
        let b = setup.marker_positions(&truth_x.positions_m);
        (a.iter()
            .zip(&b)
            .map(|(p, q)| (p - q).norm_squared())
            .sum::<f64>()
            / a.len() as f64)
            .sqrt()
    };
    let (e_mat, e_hom) = (rms(&mat_x.positions_m), rms(&hom_x.positions_m));
    eprintln!(
        "held-out sphere: truth depth {:.3} mm; material RMS {:.4} mm (depth {:.3} mm, F {:.3} N), homogeneous {:.4} mm (depth {:.3} mm); max λ / sample mean {:.2}",
        1e3 * truth_x.depth_m,
        1e3 * e_mat,
        1e3 * mat_x.depth_m,
        mat_x.axial_force_n,
        1e3 * e_hom,
        1e3 * hom_x.depth_m,
        worst
    );
    assert!(worst <= 1.6, "{worst}");
    assert_eq!(mat_x.status, softcap_fem::SolveStatus::Converged);
    assert!((mat_x.axial_force_n - force).abs() <= 0.01 * force);
    assert!(e_mat <= 0.95 * e_hom, "{e_mat} vs {e_hom}");
}
