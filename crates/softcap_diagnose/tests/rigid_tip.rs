//! The rigid-tip replay (`ProbeSimulator::simulate_sequence_rigid_tip`, bickel2009 §3.4 rigid-probe
//! contact under position control) and the plasticity signature `Signatures::released_set_m`.
//!
//! Block 40 × 40 × 20 mm, 6 × 6 × 3 cells (648 tets, node spacing 6.67 mm), E = 20 kPa, ν = 0.45,
//! fixed base; a 5 mm sphere pressed straight down onto the top-centre node. At 2 mm depth the
//! sphere's footprint radius is √(2·5·2 − 2²) = 4 mm < 6.67 mm, so exactly one node is in contact
//! and position control must carry it to the tip: its displacement equals the commanded depth up to
//! the penalty penetration (measured 0.4–4.9 % of the depth).

use nalgebra::Vector3;
use softcap_diagnose::{
    Extension, FemProbeSimulator, FemSimSettings, Frame, ProbeLoad, ProbeSimulator, Recording,
    SegmentSettings, Segmentation, SequenceFrame, SimLoad, residuals, signatures,
};
use softcap_fem::{CorotationalModel, LinearParams, TipShape};

const SIZE: [f64; 3] = [0.04, 0.04, 0.02];
const CENTRE: [f64; 3] = [0.02, 0.02, 0.02];

fn markers() -> Vec<Vector3<f64>> {
    vec![
        Vector3::from(CENTRE),
        Vector3::new(0.02 + 0.04 / 6.0, 0.02, 0.02),
        Vector3::new(0.005, 0.005, 0.02),
    ]
}

fn simulator(tip: Option<TipShape>) -> FemProbeSimulator {
    simulator_with(&markers(), tip)
}

fn simulator_with(markers: &[Vector3<f64>], tip: Option<TipShape>) -> FemProbeSimulator {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], SIZE, [6, 6, 3]);
    let model =
        CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(2e4, 0.45).unwrap())
            .unwrap();
    let fixed = FemProbeSimulator::nodes_on_plane(&mesh, &Vector3::z(), 0.0, 1e-9);
    let sim =
        FemProbeSimulator::new(&mesh, model, &fixed, markers, FemSimSettings::default()).unwrap();
    match tip {
        Some(t) => sim.with_rigid_tip(t),
        None => sim,
    }
}

/// Tip depths below the top surface per frame (negative: hovering above it).
const DEPTHS_MM: [f64; 9] = [-3.0, 0.5, 1.0, 1.5, 2.0, 2.0, 1.0, 0.0, -3.0];

fn frames() -> Vec<SequenceFrame> {
    press_frames(&Vector3::from(CENTRE), &DEPTHS_MM)
}

/// A straight press down onto `centre`: one frame per depth below the top surface (mm).
fn press_frames(centre: &Vector3<f64>, depths_mm: &[f64]) -> Vec<SequenceFrame> {
    press_frames_along(centre, &-Vector3::z(), depths_mm)
}

/// A straight press onto `centre` along the unit `axis` (the tip's axis, into the body): one
/// frame per depth past `centre` along it (mm).
fn press_frames_along(
    centre: &Vector3<f64>,
    axis: &Vector3<f64>,
    depths_mm: &[f64],
) -> Vec<SequenceFrame> {
    depths_mm
        .iter()
        .enumerate()
        .map(|(k, d)| SequenceFrame {
            time_s: 0.05 * k as f64,
            load: SimLoad {
                probe: Some(ProbeLoad {
                    tip_m: centre + axis * (1e-3 * d),
                    axis: *axis,
                    force_n: Vector3::zeros(),
                }),
                body_force_n_m3: Vector3::zeros(),
            },
        })
        .collect()
}

fn sphere() -> TipShape {
    TipShape::Sphere { radius_m: 0.005 }
}

#[test]
fn rigid_replay_carries_the_contact_node_to_the_tip_and_back() {
    let sim = simulator(Some(sphere()));
    let x = sim
        .simulate_sequence_rigid_tip(&Extension::Elastic, &frames())
        .unwrap()
        .expect("the simulator has a rigid tip");
    let rest = markers();
    for (k, d) in DEPTHS_MM.iter().enumerate() {
        let dz = x[k][0].z - rest[0].z;
        let want = -1e-3 * d.max(0.0);
        // position control: the contact node follows the tip to 8 % of the depth (the penalty
        // penetration of softcap_fem's contact, penalty factor 10⁴; measured 0.4 % at 0.5 mm,
        // 1.1 % at 1 mm, 4.9 % at 2 mm)
        assert!(
            (dz - want).abs() <= 8e-2 * want.abs() + 1e-9,
            "frame {k}: centre marker dz {dz:e} m, tip depth {want:e} m"
        );
    }
    // the neighbour (one cell away, outside the footprint) is dragged down less than the tip
    let dz_nb = x[4][1].z - rest[1].z;
    assert!(dz_nb < -1e-4 && dz_nb > -2e-3, "neighbour dz {dz_nb:e} m");
    // elastic: no history, every marker back at rest once the tip is lifted
    for (m, r) in rest.iter().enumerate() {
        assert!((x[8][m] - r).norm() < 1e-9, "marker {m} not back at rest");
    }
}

/// `FemSimSettings::rigid_tip_contact` reaches the replay: with a soft penalty (factor p = 100, the
/// suite's probe-friction truth; docs/diagnose.md session 14 (fric2)) the one contact node lags
/// the tip by the spring's penetration. Penalty k_p = p k̄ (k̄ the node's mean diagonal stiffness)
/// in series with the body's stiffness at the node k_b: penetration d · k_b / (k_p + k_b) ≈
/// (d / p) · k_b / k̄, and k_b (the Schur complement at the node) is at most the normal diagonal
/// entry, of the order of k̄. At p = 10⁴ the penetration is 100 × smaller, so the extra lag of
/// p = 100 over the default is the penetration: asserted between 0.1 d / p and d / p at every
/// contact frame (measured 0.27–0.35 d / p; the default's own lag, 0.4–4.9 % of the depth, is the
/// sphere's geometry, not the penalty).
#[test]
fn soft_rigid_tip_penalty_lets_the_contact_node_lag_the_tip() {
    let lags = |penalty_factor: f64| {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], SIZE, [6, 6, 3]);
        let model = CorotationalModel::homogeneous(
            &mesh,
            LinearParams::from_young_poisson(2e4, 0.45).unwrap(),
        )
        .unwrap();
        let fixed = FemProbeSimulator::nodes_on_plane(&mesh, &Vector3::z(), 0.0, 1e-9);
        let mut settings = FemSimSettings::default();
        settings.rigid_tip_contact.penalty_factor = penalty_factor;
        let sim = FemProbeSimulator::new(&mesh, model, &fixed, &markers(), settings)
            .unwrap()
            .with_rigid_tip(sphere());
        let x = sim
            .simulate_sequence_rigid_tip(&Extension::Elastic, &frames())
            .unwrap()
            .expect("the simulator has a rigid tip");
        DEPTHS_MM
            .iter()
            .enumerate()
            .filter(|(_, d)| **d > 0.0)
            .map(|(k, d)| (1e-3 * d, 1e-3 * d + (x[k][0].z - CENTRE[2])))
            .collect::<Vec<_>>()
    };
    assert_eq!(
        FemSimSettings::default().rigid_tip_contact.penalty_factor,
        1e4
    );
    for ((d, stiff), (_, soft)) in lags(1e4).into_iter().zip(lags(100.0)) {
        eprintln!("depth {d:e} m: lag {stiff:e} m (penalty 1e4), {soft:e} m (penalty 100)");
        let ratio = (soft - stiff) * 100.0 / d;
        assert!(
            (0.1..1.0).contains(&ratio),
            "depth {d:e} m: lag {soft:e} m at penalty 100 vs {stiff:e} m at 1e4: extra {ratio} d / p"
        );
    }
}

#[test]
fn rigid_replay_is_none_without_a_tip() {
    let sim = simulator(None);
    assert!(
        sim.simulate_sequence_rigid_tip(&Extension::Elastic, &frames())
            .unwrap()
            .is_none()
    );
}

/// The rigid-tip replay of `frames()` under J2 plasticity (σ_y `yield_stress_pa`, H 200 Pa):
/// the first marker's vertical set after release (frame 8, m; negative is downward) and every
/// frame's markers.
fn plastic_set(sim: &FemProbeSimulator, yield_stress_pa: f64) -> (f64, Vec<Vec<Vector3<f64>>>) {
    let ext = Extension::Plastic {
        yield_stress_pa,
        hardening_pa: 200.0,
    };
    let x = sim
        .simulate_sequence_rigid_tip(&ext, &frames())
        .unwrap()
        .unwrap();
    (x[8][0].z - markers()[0].z, x)
}

/// Yielding leaves a permanent dent under the tip after release (downward), deeper for a lower
/// yield stress (0.5 against 2 kPa) and shallower than the deepest press (2 mm).
fn assert_set_grows_as_the_yield_stress_drops(sim: &FemProbeSimulator) {
    let (s_mid, _) = plastic_set(sim, 2000.0);
    let (s_lo, _) = plastic_set(sim, 500.0);
    assert!(s_mid < -1e-5, "set at 2 kPa {s_mid:e} m");
    assert!(
        s_lo < s_mid,
        "set at 0.5 kPa {s_lo:e} m vs 2 kPa {s_mid:e} m"
    );
    assert!(
        s_lo > -2e-3,
        "set at 0.5 kPa {s_lo:e} m, deeper than the 2 mm press"
    );
}

#[test]
fn rigid_replay_of_j2_plasticity_leaves_a_set_that_grows_as_the_yield_stress_drops() {
    let sim = simulator(Some(sphere()));
    let elastic = sim
        .simulate_sequence_rigid_tip(&Extension::Elastic, &frames())
        .unwrap()
        .unwrap();
    // a yield stress far above any stress reached: the elastic replay to round-off
    let (s_hi, x_hi) = plastic_set(&sim, 1e9);
    assert!(s_hi.abs() < 1e-12, "no yield, set {s_hi:e} m");
    // the same equilibria as the elastic replay to 0.1 % of the 2 mm depth (measured 0.74 µm: the
    // J2 element and the corotational one differ only in round-off and solver tolerance paths)
    let max_diff = x_hi
        .iter()
        .zip(&elastic)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).norm()))
        .fold(0.0, f64::max);
    assert!(
        max_diff < 2e-6,
        "J2 without yield vs elastic: {max_diff:e} m"
    );
    assert_set_grows_as_the_yield_stress_drops(&sim);
}

/// `FemProbeSimulator::quadratic`: the plasticity replays on the 10-node tets of the same mesh
/// (small-strain J2 at their quadrature points). The markers read by the 10-node shape functions
/// sit at their rest positions while the tip hovers (the straight-sided 10-node tet interpolates
/// X exactly); without yield the contact node follows the tip as on the linear tets (position
/// control, within 8 % of the depth) and nothing is left after release; with yield a downward
/// set, larger for a lower yield stress and smaller than the 2 mm press.
#[test]
fn quadratic_replay_of_j2_plasticity_follows_the_tip_and_leaves_a_set() {
    let sim = simulator(Some(sphere())).quadratic().unwrap();
    let rest = markers();
    let (s_hi, x_hi) = plastic_set(&sim, 1e9);
    for (m, r) in rest.iter().enumerate() {
        assert!(
            (x_hi[0][m] - r).norm() < 1e-12,
            "marker {m} off rest while hovering"
        );
    }
    for (k, d) in DEPTHS_MM.iter().enumerate() {
        let (dz, want) = (x_hi[k][0].z - rest[0].z, -1e-3 * d.max(0.0));
        assert!(
            (dz - want).abs() <= 8e-2 * want.abs() + 1e-9,
            "frame {k}: centre marker dz {dz:e} m, tip depth {want:e} m"
        );
    }
    assert!(s_hi.abs() < 1e-9, "no yield, set {s_hi:e} m");
    assert_set_grows_as_the_yield_stress_drops(&sim);
}

/// A recording whose every frame is offset by the same vector (template ≠ observed rest shape,
/// as under gravity pre-load) has a released offset but no released SET; a dent that appears only
/// after the probe left has both.
#[test]
fn released_set_signature_cancels_a_constant_rest_offset() {
    let tip = |p: f64| Vector3::new(CENTRE[0], CENTRE[1], CENTRE[2] - 0.002 * p);
    let profile = [0.0, 0.0, 0.5, 1.0, 1.0, 0.5, 0.0, 0.0, 0.0];
    let rest = markers();
    let make = |dent_m: f64, offset_m: f64| {
        let frames = profile
            .iter()
            .enumerate()
            .map(|(k, &p)| {
                let released = k >= 6;
                Frame {
                    frame: k as u64,
                    time_s: 0.05 * k as f64,
                    tip_m: tip(p),
                    axis: -Vector3::z(),
                    force_n: -Vector3::z() * p,
                    markers_m: rest
                        .iter()
                        .enumerate()
                        .map(|(m, r)| {
                            let mut y = r + Vector3::new(0.0, 0.0, -offset_m);
                            if m == 0 && released {
                                y.z -= dent_m;
                            }
                            Some(y)
                        })
                        .collect(),
                }
            })
            .collect();
        Recording {
            marker_ids: vec!["a".into(), "b".into(), "c".into()],
            rest_markers_m: rest.clone(),
            normals: vec![Vector3::z(); 3],
            gravity_m_s2: Vector3::new(0.0, 0.0, -9.81),
            support: None,
            tip_radius_m: 0.005,
            frames,
        }
    };
    let baseline = vec![rest.clone(); profile.len()];
    let sig = |rec: &Recording| {
        let seg = Segmentation::new(rec, &SegmentSettings::default());
        signatures(rec, &seg, &residuals(rec, &baseline))
    };
    // constant 0.5 mm sag: released offset 0.5 mm, released set 0
    let s = sig(&make(0.0, 5e-4));
    assert!(
        (s.released_offset_m - 5e-4).abs() < 1e-12,
        "{}",
        s.released_offset_m
    );
    assert!(s.released_set_m < 1e-12, "{}", s.released_set_m);
    // plus a 0.3 mm dent of the probed marker after release: the set sees exactly the dent
    let s = sig(&make(3e-4, 5e-4));
    let probed = 2.0; // markers 0 and 1 are within the probed radius, marker 2 is not
    let want = (3e-4f64.powi(2) / probed).sqrt();
    assert!(
        (s.released_set_m - want).abs() < 1e-12,
        "released set {} m, want {want} m",
        s.released_set_m
    );
}

/// How far the top-centre marker sags under gravity (ρ 1000 kg/m³), m.
fn gravity_sag(mut sim: FemProbeSimulator) -> f64 {
    let gravity = SimLoad {
        probe: None,
        body_force_n_m3: Vector3::new(0.0, 0.0, -1000.0 * 9.81),
    };
    let rest = sim.rest_markers_m()[0];
    let out = sim.simulate(&gravity, false).unwrap();
    rest.z - out.markers_m[0].z
}

/// `FemProbeSimulator::refined`: 8 × the tets, the same markers (re-embedded at the same rest
/// positions), the support plane's nodes fixed, the tip kept; under gravity (lumped ρg V/4 is the
/// consistent load of linear tets, the same load functional on both meshes) the nested, richer
/// displacement space is softer: the top-centre marker sags more, and by little (mesh convergence;
/// measured 0.0611 mm coarse, 0.0678 mm refined).
#[test]
fn refined_simulator_keeps_markers_support_and_tip_and_is_softer() {
    let coarse = simulator(Some(sphere()));
    let fine = coarse.refined().unwrap();
    assert_eq!(
        fine.setup().mesh.tets.len(),
        8 * coarse.setup().mesh.tets.len()
    );
    assert_eq!(fine.rigid_tip(), coarse.rigid_tip());
    let (rc, rf) = (coarse.rest_markers_m(), fine.rest_markers_m());
    assert_eq!(rc.len(), rf.len());
    for (a, b) in rc.iter().zip(&rf) {
        assert!((a - b).norm() < 1e-12, "{a} vs {b}");
    }
    let on_base = FemProbeSimulator::nodes_on_plane(&fine.setup().mesh, &Vector3::z(), 0.0, 1e-9);
    assert_eq!(fine.setup().attached_nodes, on_base);
    let (sc, sf) = (gravity_sag(coarse), gravity_sag(fine));
    println!(
        "top-centre sag under gravity: coarse {:.4} mm, refined {:.4} mm",
        1e3 * sc,
        1e3 * sf
    );
    assert!(sc > 0.0);
    assert!(sf >= sc, "refined {sf} < coarse {sc}");
    assert!(sf <= 1.25 * sc, "refined {sf} vs coarse {sc}");
}

/// `FemProbeSimulator::refined_near` (conforming longest-edge bisection inside balls, nested
/// midpoints): the markers kept, exactly the support plane's nodes fixed — a ball reaching the
/// base bisects base edges more than once, so the attached rule must follow midpoints of
/// midpoints — and, the displacement space being nested in the coarse one, softer under gravity
/// (measured: top-centre sag 0.0611 mm coarse, 0.0675 mm on the 14142-tet local refinement to a
/// quarter of the longest edge, 0.0678 mm on the uniform one).
#[test]
fn locally_refined_simulator_fixes_nested_midpoints_on_the_support_and_is_softer() {
    let coarse = simulator(Some(sphere()));
    let balls = [
        softcap_mesh::RefineBall {
            centre_m: Vector3::from(CENTRE),
            radius_m: 0.0125,
        },
        softcap_mesh::RefineBall {
            centre_m: Vector3::new(0.01, 0.01, 0.003),
            radius_m: 0.006,
        },
    ];
    let h = 0.25 * coarse.longest_edge_m();
    let fine = coarse.refined_near(&balls, h, 100_000).unwrap();
    let m = &fine.setup().mesh;
    let n = coarse.setup().mesh.tets.len();
    assert!(m.tets.len() > n && m.tets.len() < 64 * n);
    assert_eq!(fine.rigid_tip(), coarse.rigid_tip());
    let (rc, rf) = (coarse.rest_markers_m(), fine.rest_markers_m());
    for (a, b) in rc.iter().zip(&rf) {
        assert!((a - b).norm() < 1e-12, "{a} vs {b}");
    }
    let on_base = FemProbeSimulator::nodes_on_plane(m, &Vector3::z(), 0.0, 1e-9);
    let coarse_base = coarse.setup().attached_nodes.len();
    // base vertices ≥ 2 bisection levels deep exist (more than one level's worth of new ones)
    assert!(
        on_base.len() > coarse_base + 8,
        "{} vs {coarse_base}",
        on_base.len()
    );
    assert_eq!(fine.setup().attached_nodes, on_base);
    let n_fine = fine.setup().mesh.tets.len();
    let (sc, sf) = (gravity_sag(coarse), gravity_sag(fine));
    println!(
        "top-centre sag under gravity: coarse {:.4} mm, locally refined ({n_fine} tets) {:.4} mm",
        1e3 * sc,
        1e3 * sf
    );
    assert!(sc > 0.0);
    assert!(sf >= sc, "refined {sf} < coarse {sc}");
    assert!(sf <= 1.25 * sc, "refined {sf} vs coarse {sc}");
}

/// `FemProbeSimulator::bisected` / `ProbeSimulator::bisected` (the ranking mesh of
/// `Replays::run_coarse_first`): on cubes split in six tets around their body diagonal, 2 × the
/// tets halves every body diagonal — each tet bisected once, no propagation — with the markers,
/// the support plane's nodes and the tip kept and, nested, softer under gravity; 4 × also halves
/// face diagonals; factor 1 is no copy.
#[test]
fn bisected_simulator_halves_body_diagonals_and_keeps_markers_and_support() {
    let coarse = simulator(Some(sphere()));
    let n = coarse.setup().mesh.tets.len();
    let fine = coarse.bisected(2).unwrap();
    let m = &fine.setup().mesh;
    assert_eq!(m.tets.len(), 2 * n);
    let longest = coarse.longest_edge_m();
    assert!(m.longest_edge() < 0.9 * longest, "{}", m.longest_edge());
    assert_eq!(fine.rigid_tip(), coarse.rigid_tip());
    for (a, b) in coarse.rest_markers_m().iter().zip(&fine.rest_markers_m()) {
        assert!((a - b).norm() < 1e-12, "{a} vs {b}");
    }
    let on_base = FemProbeSimulator::nodes_on_plane(m, &Vector3::z(), 0.0, 1e-9);
    assert_eq!(fine.setup().attached_nodes, on_base);
    let four = coarse.bisected(4).unwrap().setup().mesh.tets.len();
    assert!(four >= 4 * n && four < 8 * n, "{four}");
    assert!(ProbeSimulator::bisected(&coarse, 1).unwrap().is_none());
    let (sc, sf) = (gravity_sag(coarse), gravity_sag(fine));
    println!(
        "top-centre sag under gravity: coarse {:.4} mm, bisected 1 -> 2 {:.4} mm",
        1e3 * sc,
        1e3 * sf
    );
    assert!(sf >= sc && sf <= 1.25 * sc, "bisected {sf} vs coarse {sc}");
}

/// Press 2 mm beside the centre, drag 4 mm along +x across the centre marker while pressed,
/// lift off: per frame (depth mm, x offset mm) of the tip from the block's top centre.
const DRAG_MM: [(f64, f64); 10] = [
    (-3.0, -2.0),
    (1.0, -2.0),
    (2.0, -2.0),
    (2.0, -1.0),
    (2.0, 0.0),
    (2.0, 1.0),
    (2.0, 2.0),
    (1.0, 2.0),
    (-3.0, 2.0),
    (-3.0, 2.0),
];

fn drag_frames() -> Vec<SequenceFrame> {
    DRAG_MM
        .iter()
        .enumerate()
        .map(|(k, (d, s))| SequenceFrame {
            time_s: 0.05 * k as f64,
            load: SimLoad {
                probe: Some(ProbeLoad {
                    tip_m: Vector3::new(CENTRE[0] + 1e-3 * s, CENTRE[1], CENTRE[2] - 1e-3 * d),
                    axis: -Vector3::z(),
                    force_n: Vector3::zeros(),
                }),
                body_force_n_m3: Vector3::zeros(),
            },
        })
        .collect()
}

#[test]
fn frictional_rigid_replay_drags_the_surface_along_and_lets_go_after_lift_off() {
    let sim = simulator(Some(sphere()));
    let run = |ext: Extension| {
        sim.simulate_sequence_rigid_tip(&ext, &drag_frames())
            .unwrap()
            .expect("the simulator has a rigid tip")
    };
    // the frictional replay runs on the mesh refined once (6.7 mm surface spacing > 0.8 × the
    // 5 mm tip radius: `friction_refinement`), so compare with the frictionless replay there
    assert_eq!(
        softcap_diagnose::sim::friction_refinement(&sim.setup().mesh, &sphere(), &[]),
        1
    );
    let elastic = sim
        .refined()
        .unwrap()
        .simulate_sequence_rigid_tip(&Extension::Elastic, &drag_frames())
        .unwrap()
        .unwrap();
    let frictionless = run(Extension::ProbeFriction { mu: 0.0 });
    let rough = run(Extension::ProbeFriction { mu: 0.8 });
    // μ = 0: the frictional solver (NodalSolver, lagged f_n) reproduces the penalty-contact
    // replay (StaticSolver) to 1 % of the depth
    let max_diff = frictionless
        .iter()
        .zip(&elastic)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).norm()))
        .fold(0.0, f64::max);
    // measured 0.015 µm (the nodal and the static solver stop at different iterates)
    eprintln!("mu = 0 vs frictionless replay: {max_diff:e} m");
    assert!(
        max_diff < 2e-5,
        "mu = 0 vs frictionless replay: {max_diff:e} m"
    );
    // μ = 0.8: while the tip slides +x over the centre, the surface under it is dragged along +x
    // beyond the frictionless field (frames 4–6, the centre marker under the travelling tip)
    let rest = markers();
    for k in 4..=6 {
        let ux_rough = rough[k][0].x - rest[0].x;
        let ux_smooth = frictionless[k][0].x - rest[0].x;
        eprintln!("frame {k}: centre marker ux {ux_rough:e} m (mu 0.8) vs {ux_smooth:e} m (mu 0)");
        assert!(
            ux_rough > ux_smooth + 5e-5,
            "frame {k}: centre marker ux {ux_rough:e} m with friction vs {ux_smooth:e} m without"
        );
    }
    // elastic material, stick history forgotten at lift-off: every marker back at rest
    for (m, r) in rest.iter().enumerate() {
        assert!(
            (rough[9][m] - r).norm() < 1e-9,
            "marker {m} not back at rest after lift-off"
        );
    }
    // the force boundary condition has no stick history to carry friction
    let mut sim = simulator(Some(sphere()));
    assert!(
        ProbeSimulator::simulate_sequence(
            &mut sim,
            &Extension::ProbeFriction { mu: 0.8 },
            &drag_frames()
        )
        .is_err()
    );
}

/// A 5 mm disk pressed straight down with a top node 0.2 mm inside its rim (disk centre 1.87 mm
/// beside the top-centre node, the next node along x 4.8 mm from the axis): as a flat punch
/// (`softcap_fem::Probe::with_punch_face`) the replay carries that node down with the face. The
/// closest-feature projection pushed it out through the rim instead (measured: 0.20 mm sideways,
/// 0.09 of the 0.5 mm depth down), the failure behind replays that jumped to a second equilibrium
/// in the middle of a hold.
#[test]
fn disk_replay_presses_a_node_under_its_rim_down_not_sideways() {
    let centre = Vector3::new(CENTRE[0] + 0.00187, CENTRE[1], CENTRE[2]);
    let rim_node = Vector3::new(0.02 + 0.04 / 6.0, 0.02, 0.02);
    let markers = vec![Vector3::from(CENTRE), rim_node];
    let sim = simulator_with(
        &markers,
        Some(TipShape::Disk {
            radius_m: 0.005,
            thickness_m: 0.005,
        }),
    );
    let depths_mm = [-3.0, 0.5, 1.0, 1.5, 1.5, 1.0, -3.0];
    let frames = press_frames(&centre, &depths_mm);
    let x = sim
        .simulate_sequence_rigid_tip(&Extension::Elastic, &frames)
        .unwrap()
        .expect("the simulator has a rigid tip");
    for (k, d) in depths_mm.iter().enumerate() {
        let want = 1e-3 * d.max(0.0);
        for (m, name) in [(0, "centre"), (1, "rim")] {
            let u = x[k][m] - markers[m];
            // both nodes lie under the punch: carried down to its face (penalty penetration
            // ≤ 8 % of the depth, as above), not pushed out through the rim
            assert!(
                (u.z + want).abs() <= 8e-2 * want + 1e-9,
                "frame {k}: {name} node dz {:e} m, depth {want:e} m",
                u.z
            );
        }
    }
}

/// The batched re-simulations (`ProbeSimulator::simulate_sequences_rigid_tip` /
/// `simulate_sequences`, run in parallel by `FemProbeSimulator`) give every sequence bit for bit
/// as it comes alone, in the order of the jobs — the frictional replays sharing one refined mesh,
/// the history-carrying models their own state.
#[test]
fn batched_replays_equal_the_replays_one_at_a_time() {
    let mut sim = simulator(Some(sphere()));
    let exts = [
        Extension::ProbeFriction { mu: 0.8 },
        Extension::Elastic,
        Extension::Plastic {
            yield_stress_pa: 2e3,
            hardening_pa: 1e3,
        },
        Extension::ProbeFriction { mu: 0.4 },
    ];
    let frames = drag_frames();
    let batch = ProbeSimulator::simulate_sequences_rigid_tip(&mut sim, &exts, &frames);
    assert_eq!(batch.len(), exts.len());
    let alone: Vec<_> = exts
        .iter()
        .map(|ext| sim.simulate_sequence_rigid_tip(ext, &frames).unwrap())
        .collect();
    for ((ext, got), alone) in exts.iter().zip(batch).zip(&alone) {
        assert_eq!(&got.unwrap(), alone, "{ext:?}");
    }
    // the two frictional replays differ (the jobs are not mixed up)
    assert_ne!(alone[0], alone[3]);
    // force-driven sequences under the measured force over the patch
    let pressed: Vec<SequenceFrame> = frames
        .iter()
        .map(|f| {
            let mut f = *f;
            if let Some(p) = &mut f.load.probe {
                p.force_n = Vector3::new(0.0, 0.0, 0.05 * (p.tip_m.z - CENTRE[2]).min(0.0) / 1e-3);
            }
            f
        })
        .collect();
    let jobs: Vec<(Extension, Vec<SequenceFrame>)> = [
        Extension::Elastic,
        Extension::Viscoelastic { g: 1.0, tau_s: 0.1 },
        Extension::Plastic {
            yield_stress_pa: 2e3,
            hardening_pa: 1e3,
        },
    ]
    .into_iter()
    .map(|e| (e, pressed.clone()))
    .collect();
    let batch = ProbeSimulator::simulate_sequences(&mut sim, &jobs);
    assert_eq!(batch.len(), jobs.len());
    for ((ext, f), got) in jobs.iter().zip(batch) {
        let alone = sim.simulate_sequence(ext, f).unwrap();
        assert_eq!(got.unwrap(), alone, "{ext:?}");
    }
}

/// The anisotropy re-simulation refines the fit mesh only where it does not resolve the tip
/// (`ProbeSimulator::resolves_footprint`, the ≤ 0.8 tip-radius node spacing of
/// `extend::friction_refinement`): the 6.7 mm block does not resolve a 5 mm tip, the block refined
/// once (3.3 mm) does, and the 6.7 mm block resolves a 20 mm tip.
#[test]
fn footprint_resolution_follows_the_friction_refinement_rule() {
    let sim = simulator(None);
    let tips = [Vector3::from(CENTRE)];
    assert!(!ProbeSimulator::resolves_footprint(&sim, 0.005, &tips));
    assert!(ProbeSimulator::resolves_footprint(
        &sim.refined().unwrap(),
        0.005,
        &tips
    ));
    assert!(ProbeSimulator::resolves_footprint(&sim, 0.02, &tips));
}

/// A disk (r 5 mm) tilted 20° and pushed along its own axis onto a 12 × 12 × 6 block (5,184
/// tets, surface spacing h = 3.3 mm < 0.8 r: no friction refinement), from hovering to 0.4 mm in
/// one frame. A node that touches the face in that frame sticks where it touched (Coulomb stick
/// with the anchor at the point of first contact and the return mapping inside the same solve;
/// Wriggers, *Computational Contact Mechanics*, 2nd ed., §5.2): the tip moves along its axis, so
/// relative to the tip the stuck node moves across the axis by at most the regularization slip
/// ε = h/10 (measured 2.3 µm with μ 5, 0.14 mm frictionless, ε 0.33 mm). The node under the disk's
/// centre is not in contact at that frame: dragged down by the stuck nodes under the low rim, it
/// ends 0.31 mm beyond the face (μ 5; 0.62 mm sideways, the tip 0.14 mm), so no stick holds it.
#[test]
fn a_node_sticks_to_a_tilted_disk_where_it_first_touched() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], SIZE, [12, 12, 6]);
    let model =
        CorotationalModel::homogeneous(&mesh, LinearParams::from_young_poisson(2e4, 0.45).unwrap())
            .unwrap();
    let fixed = FemProbeSimulator::nodes_on_plane(&mesh, &Vector3::z(), 0.0, 1e-9);
    let centre = Vector3::from(CENTRE);
    // a top node under the disk's low rim, 3.3 mm from the centre (deepest in the face)
    let low = centre - Vector3::x() * (0.04 / 12.0);
    let disk = TipShape::Disk {
        radius_m: 0.005,
        thickness_m: 0.005,
    };
    let sim = FemProbeSimulator::new(
        &mesh,
        model,
        &fixed,
        &[centre, low],
        FemSimSettings::default(),
    )
    .unwrap()
    .with_rigid_tip(disk.clone());
    assert_eq!(
        softcap_diagnose::sim::friction_refinement(&sim.setup().mesh, &disk, &[centre]),
        0
    );
    let tilt = 20f64.to_radians();
    let axis = Vector3::new(tilt.sin(), 0.0, -tilt.cos());
    let frames = press_frames_along(&centre, &axis, &[-3.0, 0.4]);
    let tip = frames[1].load.probe.unwrap().tip_m;
    let eps = softcap_diagnose::sim::friction_slip_distance_m(
        &sim.setup().mesh,
        0.005,
        &[tip],
        FemSimSettings::default().friction_slip_fraction,
    );
    // the face meets the node on its path along the axis, so the point where it touched is the
    // node's rest position shifted along the axis: its slip is its displacement across the axis
    let across = |u: Vector3<f64>| (u - axis * u.dot(&axis)).norm();
    let replay = |mu: f64| {
        sim.simulate_sequence_rigid_tip(&Extension::ProbeFriction { mu }, &frames)
            .unwrap()
            .expect("the simulator has a rigid tip")
    };
    let free = replay(0.0);
    let slide = across(free[1][1] - low);
    for mu in [5.0, 1000.0] {
        let x = replay(mu);
        let slip = across(x[1][1] - low);
        // > 0: beyond the face (the disk lies behind it, (p − tip)·axis < 0)
        let gap = (x[1][0] - tip).dot(&axis);
        eprintln!(
            "mu {mu}: low-rim node slip {:.4} mm (frictionless {:.4} mm, eps {:.4} mm); centre \
             node {:.4?} mm, {gap:.3e} m beyond the face",
            slip * 1e3,
            slide * 1e3,
            eps * 1e3,
            (x[1][0] - centre) * 1e3
        );
        assert!(
            slip <= eps && slip <= 0.1 * slide,
            "mu {mu}: the low-rim node slipped {slip:e} m (eps {eps:e} m, frictionless {slide:e} m)"
        );
        assert!(
            gap > 0.1e-3,
            "mu {mu}: centre node {gap:e} m beyond the face"
        );
    }
}

/// Under position control a J2 replay depends on σ_y/E, H/E and ν only — the premise of the
/// plasticity hypothesis's rigid-tip grid in units of the fit's E
/// (`softcap_diagnose::hypotheses::plasticity::RIGID_YIELD_STRAINS`, Simo & Hughes 1998 Box 3.1:
/// at fixed strains the trial stress, the yield function and the return scale with E): E, σ_y
/// and H doubled together leave the markers, while σ_y doubled alone moves the set.
/// `ProbeSimulator::young_pa` reads the homogeneous E.
#[test]
fn rigid_replay_of_j2_plasticity_depends_on_the_yield_strain_only() {
    let replay = |young_pa: f64, yield_strain: f64| {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], SIZE, [6, 6, 3]);
        let params = LinearParams::from_young_poisson(young_pa, 0.45).unwrap();
        let model = CorotationalModel::homogeneous(&mesh, params).unwrap();
        let fixed = FemProbeSimulator::nodes_on_plane(&mesh, &Vector3::z(), 0.0, 1e-9);
        let sim =
            FemProbeSimulator::new(&mesh, model, &fixed, &markers(), FemSimSettings::default())
                .unwrap()
                .with_rigid_tip(sphere());
        let e = sim.young_pa().unwrap();
        assert!((e - young_pa).abs() < 1e-9 * young_pa, "E {e} Pa");
        sim.simulate_sequence_rigid_tip(
            &Extension::Plastic {
                yield_stress_pa: yield_strain * e,
                hardening_pa: 0.01 * e,
            },
            &frames(),
        )
        .unwrap()
        .unwrap()
    };
    let max_diff = |a: &[Vec<Vector3<f64>>], b: &[Vec<Vector3<f64>>]| {
        a.iter()
            .zip(b)
            .flat_map(|(p, q)| p.iter().zip(q).map(|(u, v)| (u - v).norm()))
            .fold(0.0, f64::max)
    };
    let soft = replay(2e4, 0.1);
    let stiff = replay(4e4, 0.1);
    let set = soft[8][0].z - markers()[0].z;
    assert!(set < -1e-5, "no set at σ_y/E 0.1: {set:e} m");
    let same = max_diff(&soft, &stiff);
    // to the solver's tolerance paths (measured 1.95 µm of the 2 mm depth, as J2 without yield
    // against the elastic replay above)
    assert!(same < 5e-6, "E 20 vs 40 kPa at σ_y/E 0.1: {same:e} m");
    let other = max_diff(&soft, &replay(2e4, 0.2));
    assert!(
        other > 5.0 * same,
        "σ_y/E 0.1 vs 0.2: {other:e} m against {same:e} m"
    );
}
