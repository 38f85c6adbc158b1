//! In-memory probing sessions with a known neo-Hookean truth (no capture.mcap): the three-layer
//! block of the bickel2009 §6 noise experiment (tests/noise.rs, tests/heldout.rs) and the
//! truth examples of the benches (benches/tissue.rs).

use softcap_fem::nalgebra::Vector3;
use softcap_fem::{
    ElasticModel, EquilibriumSettings, NeoHookeanModel, NeoHookeanParams, StaticSolver,
};
use softcap_mcap::capture::{Phase, SupportPlane};
use softcap_probing::PatchSettings;
use softcap_probing::{ObservedMarker, ProbeExample, ProbingSetup, support_nodes};
use softcap_tissue::{PreparedSession, SessionExample};

/// The three-layer block, m (the block of the module above: [`super::SIZE_M`]).
pub const THREE_LAYER_SIZE_M: [f64; 3] = super::SIZE_M;

/// Three layers (bottom → top) of stable neo-Hookean material, E in Pa (ν 0.45).
pub const LAYERS_PA: [f64; 3] = [6.0e4, 3.0e4, 1.5e4];

/// The three-layer truth of bickel2009 §6 ("a virtual block with three layers of user-defined
/// non-linear materials") on `mesh`: the layer of a tet by its centroid height.
pub fn three_layer_truth(mesh: &softcap_mesh::TetMesh) -> NeoHookeanModel {
    let height = THREE_LAYER_SIZE_M[2];
    let params = mesh
        .tets
        .iter()
        .map(|t| {
            let z = t.iter().map(|&i| mesh.vertices[i].z).sum::<f64>() / 4.0;
            let layer = ((z / height) * 3.0).floor().clamp(0.0, 2.0) as usize;
            NeoHookeanParams::from_young_poisson(LAYERS_PA[layer], 0.45).unwrap()
        })
        .collect();
    NeoHookeanModel::new(mesh, params).unwrap()
}

/// The three-layer block meshed 6 × 6 × 3 (648 tets), a 6 × 6 marker grid on top, the bottom
/// attached.
pub fn three_layer_setup() -> ProbingSetup {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], THREE_LAYER_SIZE_M, [6, 6, 3]);
    let mut markers = Vec::new();
    for i in 0..6 {
        for j in 0..6 {
            markers.push(Vector3::new(
                0.0025 + 0.005 * i as f64,
                0.0025 + 0.005 * j as f64,
                THREE_LAYER_SIZE_M[2],
            ));
        }
    }
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    ProbingSetup::new(mesh, &markers, fixed).unwrap()
}

/// One truth example: `truth` under the (lumped) force boundary condition of a footprint of
/// `tip_radius_m` (bickel2009 §4.1) pressing `force_n` down at `tip_m`, equilibrium by Newton from `x` (the rest
/// shape or a warm start; it holds the equilibrium afterwards); the markers are observed exactly.
/// `index` ≥ 1 numbers the example (frame, 0.1 s apart).
#[allow(clippy::too_many_arguments)]
pub fn truth_example<M: ElasticModel>(
    setup: &ProbingSetup,
    truth: &mut M,
    solver: &mut StaticSolver,
    x: &mut [Vector3<f64>],
    tip_m: Vector3<f64>,
    force_n: f64,
    tip_radius_m: f64,
    location: usize,
    index: usize,
) -> SessionExample {
    let patch = PatchSettings {
        radius_m: tip_radius_m,
        ..Default::default()
    };
    let mut ex = ProbeExample {
        frame: index as u64,
        time_s: 0.1 * index as f64,
        tip_m,
        axis: -Vector3::z(),
        force_n: Vector3::new(0.0, 0.0, -force_n),
        observed: Vec::new(),
    };
    let forces = setup.nodal_forces(&ex, &patch);
    let rep = setup.simulate(solver, truth, x, &forces, &EquilibriumSettings::newton());
    assert!(rep.converged(), "truth: {rep:?}");
    ex.observed = setup
        .marker_positions(x)
        .into_iter()
        .enumerate()
        .map(|(marker, position_m)| ObservedMarker { marker, position_m })
        .collect();
    SessionExample {
        example: ex,
        location,
        phase: Phase::Loading,
        frame_index: index,
        log_time_ns: 100_000_000 * index as u64,
    }
}

/// Truth examples of the 4 mm disk ([`super::TIP_RADIUS_M`]) on the top of the three-layer block:
/// every location × force, each solved from rest.
pub fn truth_examples(
    setup: &ProbingSetup,
    truth: &mut NeoHookeanModel,
    locations: &[[f64; 2]],
    forces_n: &[f64],
) -> Vec<SessionExample> {
    let mut out = Vec::new();
    for (li, loc) in locations.iter().enumerate() {
        for &f in forces_n {
            let mut solver = setup.solver(&*truth).unwrap();
            let mut x = setup.mesh.vertices.clone();
            let tip = Vector3::new(loc[0], loc[1], THREE_LAYER_SIZE_M[2]);
            let index = out.len() + 1;
            out.push(truth_example(
                setup,
                truth,
                &mut solver,
                &mut x,
                tip,
                f,
                super::TIP_RADIUS_M,
                li,
                index,
            ));
        }
    }
    out
}

/// A prepared session of `examples` (all selected) on `setup`: the 4 mm footprint
/// ([`super::TIP_RADIUS_M`]), support plane z = 0. No rigid tip (empty `tip_shape`): the truth
/// of [`truth_example`] IS the patch force `PatchSettings::default()` (lumped), so the fit keeps
/// that load (`FitSettings::disk_tip_load` applies to disk tips only).
pub fn prepared(setup: &ProbingSetup, examples: Vec<SessionExample>) -> PreparedSession {
    PreparedSession {
        setup: setup.clone(),
        locations: Vec::new(),
        all_examples: examples.clone(),
        selected: examples,
        tip_shape: String::new(),
        tip_radius_m: super::TIP_RADIUS_M,
        support: SupportPlane {
            normal: [0.0, 0.0, 1.0],
            offset_m: 0.0,
            tolerance_m: 1e-9,
        },
    }
}
