//! `softcap_probing`: marker Jacobian vs finite differences, recovery of a known homogeneous
//! material, per-example fits that reduce the marker error on a non-linear (neo-Hookean) truth,
//! the strain-space material reproducing its samples, and force-controlled contact synthesis.

use softcap_fem::nalgebra::{Vector3, Vector6};
use softcap_fem::{
    CorotationalModel, EquilibriumSettings, LinearParams, NeoHookeanModel, NeoHookeanParams,
    StiffnessKind, TipShape,
};
use softcap_probing::{
    ContactSynthesisSettings, ExampleFit, ExampleFitSettings, FitStart, FootprintLoad,
    HomogeneousFitSettings, ObservedMarker, PatchSettings, ProbeExample, ProbingSetup,
    StrainBasisSettings, StrainSample, StrainSpaceMaterial, fit_examples, fit_homogeneous,
    marker_jacobian, probe_pose, simulate_probe_contact, support_nodes,
};
use std::sync::Arc;

/// 30 × 30 × 12 mm block, bottom attached, 7 × 7 markers on the top face.
fn block() -> (ProbingSetup, Vec<Vector3<f64>>) {
    block_with([5, 5, 2])
}

fn block_with(cells: [usize; 3]) -> (ProbingSetup, Vec<Vector3<f64>>) {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.03, 0.03, 0.012], cells);
    let mut markers = Vec::new();
    for i in 0..7 {
        for j in 0..7 {
            markers.push(Vector3::new(
                0.003 + 0.004 * i as f64,
                0.003 + 0.004 * j as f64,
                0.012,
            ));
        }
    }
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    (ProbingSetup::new(mesh, &markers, fixed).unwrap(), markers)
}

fn example(
    setup: &ProbingSetup,
    x: &[Vector3<f64>],
    tip: Vector3<f64>,
    force_z: f64,
) -> ProbeExample {
    let pos = setup.marker_positions(x);
    ProbeExample {
        frame: 1,
        time_s: 0.1,
        tip_m: tip,
        axis: -Vector3::z(),
        force_n: Vector3::new(0.0, 0.0, force_z),
        observed: pos
            .iter()
            .enumerate()
            .map(|(marker, p)| ObservedMarker {
                marker,
                position_m: *p,
            })
            .collect(),
    }
}

/// Simulates the force BC of `ex` (positions of `ex.observed` are ignored) with `model`.
fn simulate<M: softcap_fem::ElasticModel>(
    setup: &ProbingSetup,
    model: &mut M,
    ex: &ProbeExample,
    settings: &EquilibriumSettings,
) -> Vec<Vector3<f64>> {
    let f = setup.nodal_forces(ex, &Default::default());
    let mut solver = setup.solver(&*model).unwrap();
    let mut x = setup.mesh.vertices.clone();
    let rep = setup.simulate(&mut solver, model, &mut x, &f, settings);
    assert!(rep.converged(), "{rep:?}");
    x
}

/// Regression guard of the consistent footprint loads (bickel2009 §4.1): on the flat top face
/// of the 6 mm-spaced block a 5 mm footprint anywhere carries the whole force AND its first
/// moment sits on the probe axis (Σ w_n x_n = the tip), whatever the nodes near the tip — the
/// area-lumped load on the nodes inside the footprint missed the axis by up to half a spacing.
#[test]
fn footprint_loads_carry_the_force_centred_on_the_probe_axis() {
    let (setup, _) = block();
    let patch = PatchSettings {
        load: FootprintLoad::Consistent,
        ..PatchSettings::default()
    };
    let top = 0.012;
    for (i, (x, y)) in [
        (0.0137, 0.0161),
        (0.015, 0.015),
        (0.0071, 0.0222),
        (0.012, 0.018),
    ]
    .into_iter()
    .enumerate()
    {
        let ex = ProbeExample {
            frame: i as u64,
            time_s: 0.0,
            // Pressed 1.5 mm in: the footprint is cast back onto the rest surface.
            tip_m: Vector3::new(x, y, top - 0.0015),
            axis: -Vector3::z(),
            force_n: Vector3::new(0.05, -0.02, -1.0),
            observed: Vec::new(),
        };
        let w = setup.load_weights(&ex, &patch);
        let sum: f64 = w.iter().map(|e| e.1).sum();
        assert!((sum - 1.0).abs() < 1e-14, "Σw = {sum}");
        assert!(w.len() >= 4, "{w:?}");
        let mut moment = Vector3::zeros();
        for &(n, wn) in &w {
            let xn = setup.mesh.vertices[n];
            assert!(wn > 0.0 && (xn.z - top).abs() < 1e-12, "node {n} at {xn:?}");
            moment += xn * wn;
        }
        assert!(
            (moment.x - x).abs() < 1e-12 && (moment.y - y).abs() < 1e-12,
            "load centre {moment:?} vs tip ({x}, {y})"
        );
        let f = setup.nodal_forces(&ex, &patch);
        let total: Vector3<f64> = f.iter().sum();
        assert!((total - ex.force_n).norm() < 1e-14, "{total:?}");
    }
    // A footprint over the block's edge: the part in contact carries the whole force, its
    // centre moves inwards; a tip beside the block loads the closest surface point.
    for (tip, inside) in [
        (Vector3::new(0.028, 0.015, top), true),
        (Vector3::new(0.045, 0.015, top), false),
    ] {
        let ex = ProbeExample {
            frame: 0,
            time_s: 0.0,
            tip_m: tip,
            axis: -Vector3::z(),
            force_n: Vector3::new(0.0, 0.0, -1.0),
            observed: Vec::new(),
        };
        let w = setup.load_weights(&ex, &patch);
        let sum: f64 = w.iter().map(|e| e.1).sum();
        assert!((sum - 1.0).abs() < 1e-14, "Σw = {sum}");
        let cx: f64 = w.iter().map(|&(n, wn)| setup.mesh.vertices[n].x * wn).sum();
        if inside {
            assert!(cx < 0.028 && cx > 0.024, "centre x {cx}");
        } else {
            assert!((cx - 0.03).abs() < 1e-12, "centre x {cx}");
        }
    }
}

/// The equal-load ring radii of the axisymmetric footprint pressures invert their cumulative
/// loads, and R rings sampled at the load midpoints put the share C(½) of the force inside
/// half the footprint radius to within 1/(2R): the flat punch (Sneddon) 1 − √¾ ≈ 0.134 (rim
/// heavy), uniform ¼, Hertz 1 − (¾)^{3/2} ≈ 0.350 (centre heavy).
#[test]
fn footprint_pressures_put_their_analytic_share_inside_half_the_radius() {
    for (load, inside_half) in [
        (FootprintLoad::FlatPunch, 1.0 - 0.75f64.sqrt()),
        (FootprintLoad::Consistent, 0.25),
        (FootprintLoad::Hertz, 1.0 - 0.75f64.powf(1.5)),
    ] {
        assert!((load.load_fraction_inside(0.5) - inside_half).abs() < 1e-15);
        for k in 0..=100 {
            let u = k as f64 / 100.0;
            let rho = load.ring_radius_fraction(u);
            assert!((0.0..=1.0).contains(&rho), "{load:?}: ρ({u}) = {rho}");
            let back = load.load_fraction_inside(rho);
            assert!((back - u).abs() < 1e-12, "{load:?}: C(ρ({u})) = {back}");
        }
        for rings in [8usize, 64, 501] {
            let share = (0..rings)
                .filter(|&k| load.ring_radius_fraction((k as f64 + 0.5) / rings as f64) < 0.5)
                .count() as f64
                / rings as f64;
            assert!(
                (share - inside_half).abs() <= 0.5 / rings as f64 + 1e-15,
                "{load:?}, {rings} rings: {share} inside r = a/2 vs {inside_half}"
            );
        }
    }
}

/// The footprint loads' report names are their settings (serde) names and read back.
#[test]
fn footprint_load_names_are_the_settings_names() {
    use serde::Deserialize;
    use serde::de::IntoDeserializer;
    for load in FootprintLoad::ALL {
        let de: serde::de::value::StrDeserializer<'_, serde::de::value::Error> =
            load.name().into_deserializer();
        assert_eq!(FootprintLoad::deserialize(de).unwrap(), load);
        assert_eq!(FootprintLoad::from_name(load.name()), Some(load));
    }
    assert_eq!(FootprintLoad::from_name("punch"), None);
}

/// The consistent nodal loads of every footprint pressure on a flat face carry the force and
/// its first moment exactly (on the probe axis), and their second moment Σ w_n |x_n − tip|²
/// is the pressure's ∫ r² p dA / F — flat punch ⅔a², uniform ½a², Hertz ⅖a² — plus the excess
/// of the linear interpolation of r² over the surface triangles: Σ λ_i |x_i − x|² at a point of
/// barycentric λ, whose mean over a right triangle with legs h (the box face's) is
/// (Σ edge²)/12 = h²/3 (h = 1 mm, a = 5 mm: 0.0133 a²). Tolerance 0.002 a² (32 × 48 samples).
#[test]
fn footprint_loads_have_the_pressures_first_and_second_moments() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.03, 0.03, 0.004], [30, 30, 1]);
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    let setup = ProbingSetup::new(mesh, &[Vector3::new(0.015, 0.015, 0.004)], fixed).unwrap();
    let a = 0.005;
    let excess = 0.001f64.powi(2) / 3.0 / (a * a);
    for (load, second) in [
        (FootprintLoad::FlatPunch, 2.0 / 3.0),
        (FootprintLoad::Consistent, 0.5),
        (FootprintLoad::Hertz, 0.4),
    ] {
        let patch = PatchSettings {
            load,
            radius_m: a,
            rings: 32,
            samples_per_ring: 48,
            ..PatchSettings::default()
        };
        for (x, y) in [(0.015, 0.015), (0.0137, 0.0161)] {
            let ex = ProbeExample {
                frame: 0,
                time_s: 0.0,
                tip_m: Vector3::new(x, y, 0.004),
                axis: -Vector3::z(),
                force_n: Vector3::new(0.0, 0.0, -1.0),
                observed: Vec::new(),
            };
            let w = setup.load_weights(&ex, &patch);
            let sum: f64 = w.iter().map(|e| e.1).sum();
            assert!((sum - 1.0).abs() < 1e-13, "{load:?}: Σw = {sum}");
            let mut first = Vector3::zeros();
            let mut m2 = 0.0;
            for &(n, wn) in &w {
                let d = setup.mesh.vertices[n] - ex.tip_m;
                first += d * wn;
                m2 += wn * (d.x * d.x + d.y * d.y);
            }
            assert!(
                first.x.abs() < 1e-12 && first.y.abs() < 1e-12,
                "{load:?}: load centre off the axis by {first:?}"
            );
            let m2 = m2 / (a * a);
            assert!(
                (m2 - second - excess).abs() < 0.002,
                "{load:?} at ({x}, {y}): second moment {m2:.4} a² vs {second:.4} + {excess:.4} a²"
            );
        }
    }
}

/// A flat disk tilted by θ in the x–z plane, its centre `depth` below the flat top face (z = 4 mm
/// of a 30 × 30 mm, 1 mm-spaced plate) along the axis under (15, 15) mm, the flat-punch load:
/// (the load centre Σ w_n x_n, where the disk point (2/3)·tanθ·a²/depth toward the low side cast
/// along the axis meets the face, the shares).
fn tilted_disk(theta_deg: f64, depth: f64, patch: &PatchSettings) -> (Vector3<f64>, Vector3<f64>) {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.03, 0.03, 0.004], [30, 30, 1]);
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    let setup = ProbingSetup::new(mesh, &[Vector3::new(0.015, 0.015, 0.004)], fixed).unwrap();
    let th = theta_deg.to_radians();
    let axis = Vector3::new(th.sin(), 0.0, -th.cos());
    let surface = Vector3::new(0.015, 0.015, 0.004);
    let tip = surface + axis * depth;
    let ex = ProbeExample {
        frame: 0,
        time_s: 0.0,
        tip_m: tip,
        axis,
        force_n: axis,
        observed: Vec::new(),
    };
    let w = setup.load_weights(&ex, patch);
    let sum: f64 = w.iter().map(|e| e.1).sum();
    assert!((sum - 1.0).abs() < 1e-12, "Σw = {sum}");
    assert!(w.iter().all(|e| e.1 > 0.0), "{w:?}");
    let centre: Vector3<f64> = w.iter().map(|&(n, wn)| setup.mesh.vertices[n] * wn).sum();
    // The low side of the disk (its face points' z falls along −(cos θ, 0, sin θ)).
    let low = -Vector3::new(th.cos(), 0.0, th.sin());
    let e = 2.0 / 3.0 * th.tan() * patch.radius_m.powi(2) / depth;
    let c = tip + low * e;
    let expected = c + axis * ((c.z - 0.004) / th.cos());
    (centre, expected)
}

/// A tilted rigid disk in full contact with a half-space (δ₀ ≥ 2a·tanθ) carries the pressure
/// E*(δ₀ + 2g·x)/(π√(a² − r²)): its load centre lies (2/3)·tanθ·a²/δ₀ from the axis toward the
/// low side. Tilted 4° (5 mm disk, 2 mm deep: 2a·tanθ = 0.70 mm), the flat-punch nodal loads'
/// first moment lands there to 0.3 % of the shift (0.61 mm; the 8 rings' discrete second moment
/// is 1/(12·8²) off the pressure's); the same disk aligned with the face has its load centre on
/// the axis and loads that do not depend on the depth (the face parallel to the surface: the
/// rings of Sneddon's pressure, weights for weights).
#[test]
fn tilted_disk_in_full_contact_shifts_its_load_to_the_low_side() {
    let patch = PatchSettings {
        load: FootprintLoad::FlatPunch,
        ..PatchSettings::default()
    };
    let (centre, expected) = tilted_disk(4.0, 0.002, &patch);
    let shift = 2.0 / 3.0 * 4f64.to_radians().tan() * 0.005f64.powi(2) / 0.002;
    assert!(
        (centre - expected).norm() < 3e-3 * shift,
        "load centre {centre:?} vs {expected:?} (shift {shift:e} m)"
    );
    // Aligned: the load does not depend on the depth and is centred on the axis.
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.03, 0.03, 0.004], [30, 30, 1]);
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    let setup = ProbingSetup::new(mesh, &[Vector3::new(0.015, 0.015, 0.004)], fixed).unwrap();
    let weights = |depth: f64| {
        let ex = ProbeExample {
            frame: 0,
            time_s: 0.0,
            tip_m: Vector3::new(0.0137, 0.0161, 0.004 - depth),
            axis: -Vector3::z(),
            force_n: -Vector3::z(),
            observed: Vec::new(),
        };
        setup.load_weights(&ex, &patch)
    };
    let shallow = weights(0.0005);
    assert_eq!(shallow, weights(0.003));
    let c: Vector3<f64> = shallow
        .iter()
        .map(|&(n, w)| setup.mesh.vertices[n] * w)
        .sum();
    assert!(
        (c.x - 0.0137).abs() < 1e-12 && (c.y - 0.0161).abs() < 1e-12,
        "{c:?}"
    );
}

/// Tilted beyond full contact (δ₀ < 2a·tanθ) the high rim lifts off: the half-space contact
/// solve puts the load on the low side. Just inside the incomplete regime (δ₀ = 0.97 · 2a·tanθ)
/// the solve meets the full-contact limit, whose centre is a/3 from the axis (to 6 %, the
/// 16-cell grid's resolution of the rim singularity); a 20° disk (the third-party
/// probe-friction fixture's) 0.5 → 1 → 2 → 3 mm deep carries its load beyond a/3 toward the
/// low rim, spreading toward the centre as it goes deeper.
#[test]
fn tilted_disk_in_partial_contact_presses_with_its_low_side() {
    let patch = PatchSettings {
        load: FootprintLoad::FlatPunch,
        ..PatchSettings::default()
    };
    let a = patch.radius_m;
    let shift = |theta: f64, depth: f64| {
        let (centre, _) = tilted_disk(theta, depth, &patch);
        let th = theta.to_radians();
        // Where the axis meets the face, and the load centre's distance from it in the disk's
        // plane, toward the low side (the cast along the axis stretches x by 1/cos θ).
        let on_axis = Vector3::new(0.015, 0.015, 0.004);
        -(centre.x - on_axis.x) * th.cos()
    };
    let th = 4f64.to_radians();
    let limit = shift(4.0, 0.97 * 2.0 * a * th.tan());
    assert!(
        (limit / (a / 3.0) - 1.0).abs() < 0.06,
        "centre {:.3} a at the full-contact limit vs 1/3",
        limit / a
    );
    let mut last = a;
    for depth in [0.0005, 0.001, 0.002, 0.003] {
        let e = shift(20.0, depth);
        assert!(
            e > a / 3.0 && e < last,
            "20°, {depth} m deep: load centre {:.3} a (previous {:.3} a)",
            e / a,
            last / a
        );
        last = e;
    }
}

/// A rigid flat punch's surface displacement is uniform over its footprint (Sneddon 1946);
/// the uniform pressure's dent is rounded, its rim displacement (2/π)·E(r/a) of the centre's on
/// a half-space (0.64 at the rim). On a 40 × 40 × 20 mm block (2 mm tets, bottom attached) the
/// flat-punch nodal loads of a 6 mm footprint make a markedly flatter dent than the uniform
/// pressure's: the mean axial displacement of the top nodes at 0.7a ≤ r ≤ a over that of the
/// centre node is closer to 1.
#[test]
fn flat_punch_load_makes_a_flatter_dent_than_uniform_pressure() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [20, 20, 10]);
    let fixed = support_nodes(&mesh, &Vector3::z(), 0.0, 1e-9);
    let setup = ProbingSetup::new(mesh, &[Vector3::new(0.02, 0.02, 0.02)], fixed).unwrap();
    let a = 0.006;
    let params = LinearParams::from_young_poisson(2.0e4, 0.45).unwrap();
    let tip = Vector3::new(0.02, 0.02, 0.02);
    let ex = ProbeExample {
        frame: 0,
        time_s: 0.0,
        tip_m: tip,
        axis: -Vector3::z(),
        // ≈ 0.1 % strain under the tip: the linear regime the half-space solutions describe.
        force_n: Vector3::new(0.0, 0.0, -0.002),
        observed: Vec::new(),
    };
    let centre = setup
        .boundary_nodes
        .iter()
        .copied()
        .find(|&n| (setup.mesh.vertices[n] - tip).norm() < 1e-9)
        .unwrap();
    let rim: Vec<usize> = setup
        .boundary_nodes
        .iter()
        .copied()
        .filter(|&n| {
            let d = setup.mesh.vertices[n] - tip;
            let r = (d.x * d.x + d.y * d.y).sqrt();
            d.z.abs() < 1e-9 && (0.7 * a..=a + 1e-9).contains(&r)
        })
        .collect();
    assert!(rim.len() >= 8, "{rim:?}");
    let ratio = |load: FootprintLoad| {
        let patch = PatchSettings {
            load,
            radius_m: a,
            ..PatchSettings::default()
        };
        let mut model = CorotationalModel::homogeneous(&setup.mesh, params).unwrap();
        let f = setup.nodal_forces(&ex, &patch);
        let mut solver = setup.solver(&model).unwrap();
        let mut x = setup.mesh.vertices.clone();
        let rep = setup.simulate(
            &mut solver,
            &mut model,
            &mut x,
            &f,
            &EquilibriumSettings::default(),
        );
        assert!(rep.converged(), "{load:?}: {rep:?}");
        let uz = |n: usize| x[n].z - setup.mesh.vertices[n].z;
        let rim_mean = rim.iter().map(|&n| uz(n)).sum::<f64>() / rim.len() as f64;
        assert!(uz(centre) < 0.0, "{load:?}: centre moved up");
        rim_mean / uz(centre)
    };
    let punch = ratio(FootprintLoad::FlatPunch);
    let uniform = ratio(FootprintLoad::Consistent);
    eprintln!("rim/centre displacement: flat punch {punch:.4}, uniform {uniform:.4}");
    assert!(
        (1.0 - punch).abs() < 0.5 * (1.0 - uniform).abs(),
        "flat punch {punch:.4} vs uniform {uniform:.4}"
    );
}

#[test]
fn marker_jacobian_matches_finite_differences() {
    let (setup, _) = block();
    let t = setup.num_elements();
    let params: Vec<LinearParams> = (0..t)
        .map(|e| {
            LinearParams::from_young_poisson(2e4 * (1.0 + 0.3 * ((e * 7) % 5) as f64), 0.3).unwrap()
        })
        .collect();
    let mut model = CorotationalModel::new(&setup.mesh, params.clone()).unwrap();
    let tip = Vector3::new(0.015, 0.015, 0.012);
    let probe = example(&setup, &setup.mesh.vertices, tip, -1.5);
    let tight = EquilibriumSettings {
        displacement_tol_rel: 1e-13,
        residual_tol_rel: 1e-12,
        max_iterations: 200,
        ..EquilibriumSettings::newton()
    };
    let x = simulate(&setup, &mut model, &probe, &tight);
    let mut solver = setup.solver(&model).unwrap();
    let rows = marker_jacobian(
        &setup,
        &mut solver,
        &model,
        &probe,
        &x,
        StiffnessKind::Consistent,
    )
    .unwrap();
    assert_eq!(rows.len(), 3 * probe.observed.len());
    // Central differences on a few parameters (λ and α of tets under and away from the probe).
    let mut worst: f64 = 0.0;
    let mut scale: f64 = 0.0;
    for &param in &[0usize, 1, 2 * (t / 2), 2 * (t / 2) + 1, 2 * (t - 1)] {
        let h = 1e-4 * params[param / 2].lambda;
        let mut pp = params.clone();
        let mut pm = params.clone();
        if param % 2 == 0 {
            pp[param / 2].lambda += h;
            pm[param / 2].lambda -= h;
        } else {
            pp[param / 2].alpha += h;
            pm[param / 2].alpha -= h;
        }
        let mut mp = CorotationalModel::new(&setup.mesh, pp).unwrap();
        let mut mm = CorotationalModel::new(&setup.mesh, pm).unwrap();
        let xp = setup.marker_positions(&simulate(&setup, &mut mp, &probe, &tight));
        let xm = setup.marker_positions(&simulate(&setup, &mut mm, &probe, &tight));
        for (k, o) in probe.observed.iter().enumerate() {
            for c in 0..3 {
                let fd = (xp[o.marker][c] - xm[o.marker][c]) / (2.0 * h);
                let adj = rows[3 * k + c][param];
                worst = worst.max((fd - adj).abs());
                scale = scale.max(fd.abs());
            }
        }
    }
    assert!(scale > 0.0);
    // Agreement to 1e-5 relative to the largest entry (FD truncation ~ h² ≈ 1e-8).
    assert!(
        worst <= 1e-5 * scale,
        "adjoint vs FD: worst {worst:e}, scale {scale:e}"
    );
}

#[test]
fn homogeneous_fit_recovers_a_known_material() {
    homogeneous_fit_recovers_from_start(HomogeneousFitSettings::default());
}

/// Regression guard: a start so soft that the examples have no equilibrium at it (NaN
/// residuals) used to be returned unchanged as the "fit"; the start is now stiffened until
/// every example converges, and the fit recovers the material as from the default start.
#[test]
fn homogeneous_fit_recovers_from_a_start_without_equilibrium() {
    let (setup, _) = block();
    let start = LinearParams::from_young_poisson(300.0, 0.4).unwrap();
    let mut soft = CorotationalModel::homogeneous(&setup.mesh, start).unwrap();
    let tip = Vector3::new(0.018, 0.012, 0.012);
    let probe = example(&setup, &setup.mesh.vertices, tip, -1.6);
    let f = setup.nodal_forces(&probe, &Default::default());
    let mut solver = setup.solver(&soft).unwrap();
    let mut x = setup.mesh.vertices.clone();
    let settings = HomogeneousFitSettings::default();
    let rep = setup.simulate(&mut solver, &mut soft, &mut x, &f, &settings.equilibrium);
    assert!(
        !rep.converged(),
        "the 300 Pa start must not converge: {rep:?}"
    );
    homogeneous_fit_recovers_from_start(HomogeneousFitSettings {
        initial_young_pa: 300.0,
        ..settings
    });
}

/// The two presses (tip at (x, y, 12 mm), axial force fz N) on `setup`'s block of the
/// homogeneous truth (E 40 kPa, ν 0.35), each simulated by `press(model, tip, fz, settings)`.
fn homogeneous_truth_examples(
    setup: &ProbingSetup,
    mut press: impl FnMut(
        &mut CorotationalModel,
        Vector3<f64>,
        f64,
        &EquilibriumSettings,
    ) -> ProbeExample,
) -> Vec<ProbeExample> {
    let truth = LinearParams::from_young_poisson(4.0e4, 0.35).unwrap();
    let mut model = CorotationalModel::homogeneous(&setup.mesh, truth).unwrap();
    let eq = EquilibriumSettings::default();
    [(0.012, 0.015, -0.8), (0.018, 0.012, -1.6)]
        .iter()
        .map(|&(x, y, fz)| press(&mut model, Vector3::new(x, y, 0.012), fz, &eq))
        .collect()
}

fn homogeneous_fit_recovers_from_start(settings: HomogeneousFitSettings) {
    let (setup, _) = block();
    let examples = homogeneous_truth_examples(&setup, |model, tip, fz, eq| {
        let probe = example(&setup, &setup.mesh.vertices, tip, fz);
        let xs = simulate(&setup, model, &probe, eq);
        example(&setup, &xs, tip, fz)
    });
    let fit = fit_homogeneous(&setup, &examples, &settings).unwrap();
    let (e, nu) = fit.params.to_young_poisson().unwrap();
    assert!((e / 4.0e4 - 1.0).abs() < 1e-3, "E = {e}");
    assert!((nu - 0.35).abs() < 5e-3, "nu = {nu}");
    assert!(fit.rms_m < 1e-7, "rms {}", fit.rms_m);
}

/// The fit on a support plane with tangential springs recovers the material of a block that
/// slides on such springs under oblique presses (1 N sideways per 1.6 N down, springs 300 N/m
/// in total), where the fit with the bottom fixed gives the slip to a softer material (checked:
/// its E is more than 10 % low). A support plane built with the truth's springs is the only
/// thing that differs between the two fits.
#[test]
fn homogeneous_fit_on_support_springs_recovers_a_sliding_block() {
    use softcap_fem::{NodalSolver, SupportPlane, SupportTangential};
    use softcap_probing::fit_homogeneous_on_support;
    let (setup, _) = block();
    let plane = || {
        SupportPlane::new(
            softcap_fem::nalgebra::Unit::new_normalize(Vector3::z()),
            0.0,
            setup.attached_nodes.clone(),
            &setup.mesh.vertices,
            &setup.mesh.boundary_faces(),
            SupportTangential::Springs {
                stiffness_n_per_m: 300.0,
            },
        )
        .unwrap()
    };
    let examples = homogeneous_truth_examples(&setup, |model, tip, fz, eq| {
        let mut probe = example(&setup, &setup.mesh.vertices, tip, fz);
        probe.force_n.x = -fz / 1.6;
        let f = setup.nodal_forces(&probe, &Default::default());
        let mut solver = NodalSolver::new(&*model, &[]).unwrap();
        let mut xs = setup.mesh.vertices.clone();
        let rep = solver.solve(model, &mut xs, &f, &mut [&mut plane()], eq);
        assert!(rep.converged(), "{rep:?}");
        let mut ex = example(&setup, &xs, tip, fz);
        ex.force_n = probe.force_n;
        ex
    });
    // 400 iterations: the corotational solve of a block free on its springs converges linearly
    // and stalls at residual 1.4e-7 N (update 2.5e-10 m) after the default 60 at the start
    // (E 30 kPa, nu 0.4), so that example never reaches equilibrium and the fit fails.
    let settings = HomogeneousFitSettings {
        equilibrium: softcap_fem::EquilibriumSettings {
            max_iterations: 400,
            ..HomogeneousFitSettings::default().equilibrium
        },
        ..HomogeneousFitSettings::default()
    };
    let fit = fit_homogeneous_on_support(&setup, &examples, &settings, plane()).unwrap();
    let (e, nu) = fit.params.to_young_poisson().unwrap();
    assert!((e / 4.0e4 - 1.0).abs() < 1e-3, "E = {e}");
    assert!((nu - 0.35).abs() < 5e-3, "nu = {nu}");
    assert!(fit.rms_m < 1e-6, "rms {}", fit.rms_m);
    let fixed = fit_homogeneous(&setup, &examples, &settings).unwrap();
    let (e_fixed, _) = fixed.params.to_young_poisson().unwrap();
    eprintln!("sliding block: E {e:.1} Pa, nu {nu:.4} on the springs; E {e_fixed:.1} Pa fixed");
    assert!(e_fixed < 0.9 * 4.0e4, "fixed-support fit E = {e_fixed}");
}

#[test]
fn per_example_fit_of_a_neohookean_truth_beats_the_homogeneous_model() {
    let (setup, _) = block();
    // Two-layer non-linear truth: stiffer bottom half.
    let params: Vec<NeoHookeanParams> = setup
        .mesh
        .tets
        .iter()
        .map(|t| {
            let zc = t.iter().map(|&i| setup.mesh.vertices[i].z).sum::<f64>() / 4.0;
            let e = if zc < 0.006 { 8e4 } else { 2.5e4 };
            NeoHookeanParams::from_young_poisson(e, 0.4).unwrap()
        })
        .collect();
    let mut truth = NeoHookeanModel::new(&setup.mesh, params).unwrap();
    let newton = EquilibriumSettings::newton();
    let tip = Vector3::new(0.015, 0.015, 0.012);
    let probe = example(&setup, &setup.mesh.vertices, tip, -2.0);
    let xt = simulate(&setup, &mut truth, &probe, &newton);
    let ex = example(&setup, &xt, tip, -2.0);
    let max_disp = setup
        .marker_positions(&xt)
        .iter()
        .zip(&setup.marker_positions(&setup.mesh.vertices))
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(max_disp > 5e-4, "max displacement {max_disp}");
    let homog = fit_homogeneous(
        &setup,
        std::slice::from_ref(&ex),
        &HomogeneousFitSettings::default(),
    )
    .unwrap();
    let t = setup.num_elements();
    let fit = ExampleFit::from(
        fit_examples(
            &setup,
            std::slice::from_ref(&ex),
            &vec![homog.params; t],
            FitStart::Reference,
            &ExampleFitSettings {
                relative_cost_tolerance: 1e-6,
                max_iterations: 30,
                ..Default::default()
            },
        )
        .unwrap(),
    );
    eprintln!(
        "homog {:e} E,nu {:?}; fit {:e} -> {:e} in {} it, costs {:?}",
        homog.rms_m,
        homog.params.to_young_poisson(),
        fit.initial_rms_m,
        fit.rms_m,
        fit.iterations,
        fit.cost_history
    );
    assert!(
        fit.rms_m < 0.5 * homog.rms_m,
        "fit {:e} vs homogeneous {:e}",
        fit.rms_m,
        homog.rms_m
    );
    assert!(fit.cost_history.windows(2).all(|w| w[1] < w[0]));
    for (e, p) in fit.params.iter().enumerate() {
        p.validate(e).unwrap();
    }
}

#[test]
fn strain_space_material_reproduces_its_samples_and_clamps() {
    // Two elements with λ growing linearly in ‖ε‖ (a stiffening material).
    let law = |s: f64| LinearParams {
        lambda: 1e4 * (1.0 + 10.0 * s),
        alpha: 3e3 * (1.0 + 10.0 * s),
    };
    let samples: Vec<Vec<StrainSample>> = (0..2)
        .map(|e| {
            (0..8)
                .map(|k| {
                    let s = 0.01 * k as f64 * (1.0 + e as f64);
                    StrainSample {
                        strain: [s, -0.4 * s, -0.4 * s, 0.0, 0.0, 0.0],
                        params: law(s),
                    }
                })
                .collect()
        })
        .collect();
    let (mat, curve) = StrainSpaceMaterial::fit(
        &samples,
        &StrainBasisSettings {
            relative_tolerance: 1e-3,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(!curve.is_empty());
    assert!(curve.last().unwrap().relative_rms_error <= curve[0].relative_rms_error);
    for (e, s) in samples.iter().enumerate() {
        for smp in s {
            let p = mat.evaluate(e, &Vector6::from_column_slice(&smp.strain));
            assert!(
                (p.lambda / smp.params.lambda - 1.0).abs() < 0.01,
                "{p:?} vs {:?}",
                smp.params
            );
        }
    }
    // Far outside the samples the clamp keeps the parameters physically valid.
    let p = mat.evaluate(0, &Vector6::new(-5.0, 5.0, 1.0, 2.0, 0.0, 0.0));
    p.validate(0).unwrap();
}

#[test]
fn contact_synthesis_reaches_the_requested_force() {
    let (setup, _) = block_with([10, 10, 3]);
    let model = CorotationalModel::homogeneous(
        &setup.mesh,
        LinearParams::from_young_poisson(3e4, 0.4).unwrap(),
    )
    .unwrap();
    let samples: Vec<Vec<StrainSample>> = (0..setup.num_elements())
        .map(|_| {
            vec![
                StrainSample {
                    strain: [0.0; 6],
                    params: model.params()[0],
                },
                StrainSample {
                    strain: [0.0, 0.0, -0.1, 0.0, 0.0, 0.0],
                    params: LinearParams {
                        lambda: 2.0 * model.params()[0].lambda,
                        alpha: 2.0 * model.params()[0].alpha,
                    },
                },
            ]
        })
        .collect();
    let (mat, _) = StrainSpaceMaterial::fit(&samples, &StrainBasisSettings::default()).unwrap();
    let mat = Arc::new(mat);
    let mut nonlinear = mat.model(&setup.mesh).unwrap();
    let pose = probe_pose(&Vector3::new(0.015, 0.015, 0.02), &-Vector3::z());
    let settings = ContactSynthesisSettings::default();
    let out = simulate_probe_contact(
        &setup,
        &mut nonlinear,
        TipShape::Sphere { radius_m: 0.008 },
        pose,
        1.0,
        &settings,
    )
    .unwrap();
    eprintln!(
        "contact: depth {} force {} it {} status {:?}",
        out.depth_m, out.axial_force_n, out.depth_iterations, out.status
    );
    assert_eq!(out.status, softcap_fem::SolveStatus::Converged);
    assert!(
        (out.axial_force_n - 1.0).abs() <= 0.011,
        "force {}",
        out.axial_force_n
    );
    assert_eq!(out.steps_m.len(), settings.steps);
    let mut linear = model.clone();
    let lin = simulate_probe_contact(
        &setup,
        &mut linear,
        TipShape::Sphere { radius_m: 0.008 },
        pose,
        1.0,
        &settings,
    )
    .unwrap();
    // The stiffening material needs less depth for the same force.
    assert!(
        out.depth_m < lin.depth_m,
        "{} vs {}",
        out.depth_m,
        lin.depth_m
    );
}

#[test]
fn probe_pose_maps_z_to_the_axis() {
    for axis in [
        -Vector3::z(),
        Vector3::z(),
        Vector3::new(1.0, 2.0, -2.0).normalize(),
    ] {
        let pose = probe_pose(&Vector3::new(1.0, 2.0, 3.0), &axis);
        let z = pose.rotation * Vector3::z();
        assert!((z - axis).norm() < 1e-12, "{z:?} vs {axis:?}");
    }
}

/// The constant term of Carr et al. 2001 (Σwᵢ = 0): constant data is reproduced exactly at any
/// strain (eq. 8 without it extrapolates like a cone, slope 2λ/d for two samples d apart), and
/// far outside the samples p stays within the measured range (bound |p − c| ≤ Σ|wᵢ|‖εᵢ‖, ceiling).
#[test]
fn constant_tail_reproduces_constants_and_bounds_extrapolation() {
    let p = LinearParams {
        lambda: 1e5,
        alpha: 4e4,
    };
    let strains = [
        [0.0; 6],
        [-0.01, 0.004, 0.004, 0.0, 0.0, 0.0],
        [-0.02, 0.008, 0.008, 0.001, 0.0, 0.0],
    ];
    let constant: Vec<Vec<StrainSample>> = vec![
        strains
            .iter()
            .map(|s| StrainSample {
                strain: *s,
                params: p,
            })
            .collect(),
    ];
    let far = Vector6::new(-0.5, 0.2, 0.2, 0.1, 0.0, 0.0);
    let (tail, _) = StrainSpaceMaterial::fit(&constant, &StrainBasisSettings::default()).unwrap();
    let q = tail.evaluate(0, &far);
    assert!((q.lambda - p.lambda).abs() < 1e-6 * p.lambda, "{q:?}");
    assert!((q.alpha - p.alpha).abs() < 1e-6 * p.alpha, "{q:?}");
    // Without the term (bickel2009 eq. 8 as printed) the same data interpolated exactly
    // (tolerance 0, no ceiling) gives a far value many times λ.
    let plain = StrainBasisSettings {
        tail: softcap_probing::StrainTail::None,
        relative_tolerance: 0.0,
        lambda_ceiling_fraction: 0.0,
        ..Default::default()
    };
    let (cone, _) = StrainSpaceMaterial::fit(&constant, &plain).unwrap();
    let raw = cone.elements[0].evaluate(&[-0.5, 0.2, 0.2, 0.1, 0.0, 0.0]);
    assert!(raw[0] > 5.0 * p.lambda, "{raw:?}");
    // Stiffening samples: the constant-tail material never leaves [½ min λ, max λ].
    let stiff: Vec<Vec<StrainSample>> = vec![
        strains
            .iter()
            .enumerate()
            .map(|(k, s)| StrainSample {
                strain: *s,
                params: LinearParams {
                    lambda: p.lambda * (1.0 + k as f64),
                    alpha: p.alpha * (1.0 + k as f64),
                },
            })
            .collect(),
    ];
    let (m, _) = StrainSpaceMaterial::fit(&stiff, &StrainBasisSettings::default()).unwrap();
    for s in &stiff[0] {
        let q = m.evaluate(0, &Vector6::from_column_slice(&s.strain));
        assert!((q.lambda / s.params.lambda - 1.0).abs() < 0.02, "{q:?}");
    }
    let q = m.evaluate(0, &far);
    assert!(
        q.lambda <= 3.0 * p.lambda + 1e-9 && q.lambda >= 0.5 * p.lambda,
        "{q:?}"
    );
    q.validate(0).unwrap();
    let w: f64 = m.elements[0].weights.iter().map(|w| w[0]).sum();
    assert!(w.abs() < 1e-9 * p.lambda, "Σw = {w}");
}

/// A material whose λ and α double between zero strain and ε_zz = −0.1 (a stiffening tissue
/// under a press), on every tet of `setup`.
fn stiffening_material(setup: &ProbingSetup, p: LinearParams) -> Arc<StrainSpaceMaterial> {
    let samples: Vec<Vec<StrainSample>> = (0..setup.num_elements())
        .map(|_| {
            vec![
                StrainSample {
                    strain: [0.0; 6],
                    params: p,
                },
                StrainSample {
                    strain: [0.0, 0.0, -0.1, 0.0, 0.0, 0.0],
                    params: LinearParams {
                        lambda: 2.0 * p.lambda,
                        alpha: 2.0 * p.alpha,
                    },
                },
            ]
        })
        .collect();
    Arc::new(
        StrainSpaceMaterial::fit(&samples, &StrainBasisSettings::default())
            .unwrap()
            .0,
    )
}

/// Regression guard of the diagnose stage's strain-space default model: the equilibrium of
/// `StrainSpaceModel::solve_continued` along a recording-like sequence of loads (a ramp at one
/// location, a jump to another, back) equals the equilibrium loaded from rest for every load to
/// the solver tolerance — the material is elastic, the previous equilibrium only starts the
/// iterations — the small steps of the ramp are continued (not reloaded from rest), and at
/// the equilibrium the parameters are the material's p(ε).
#[test]
fn strain_space_equilibrium_does_not_depend_on_the_load_path() {
    use softcap_probing::{StrainSpaceModel, StrainSpaceSolveSettings};
    let (setup, _) = block_with([10, 10, 3]);
    let p = LinearParams::from_young_poisson(3e4, 0.4).unwrap();
    let material = stiffening_material(&setup, p);
    let eq = EquilibriumSettings {
        displacement_tol_rel: 1e-8,
        residual_tol_rel: 1e-6,
        ..EquilibriumSettings::newton()
    };
    let settings = StrainSpaceSolveSettings::default();
    let rest = setup.mesh.vertices.clone();
    let forces_at = |tip: Vector3<f64>, f: f64| {
        setup.nodal_forces(&example(&setup, &rest, tip, -f), &PatchSettings::default())
    };
    let a = Vector3::new(0.015, 0.015, 0.012);
    let b = Vector3::new(0.009, 0.021, 0.012);
    let loads: Vec<(Vector3<f64>, f64)> = vec![
        (a, 0.4),
        (a, 0.8),
        (a, 1.2),
        (a, 1.5),
        (a, 1.5),
        (b, 1.5),
        (a, 1.2),
    ];
    let mut model = StrainSpaceModel::new(material.clone(), &setup.mesh, 0.5).unwrap();
    let mut solver = setup.solver(&model).unwrap();
    let mut x = rest.clone();
    let mut previous = vec![Vector3::zeros(); rest.len()];
    let mut continued = 0;
    let length = (Vector3::new(0.03, 0.03, 0.012)).norm();
    for (k, (tip, f)) in loads.iter().enumerate() {
        let forces = forces_at(*tip, *f);
        let s = model
            .solve_continued(
                &setup,
                &mut solver,
                &mut x,
                &previous,
                &forces,
                &eq,
                &settings,
            )
            .unwrap();
        assert!(s.converged(), "load {k}: {s:?}");
        continued += usize::from(s.from_rest_attempt.is_none());
        previous = forces.clone();
        // the same load from rest, fresh model
        let mut fresh = StrainSpaceModel::new(material.clone(), &setup.mesh, 0.5).unwrap();
        let mut fresh_solver = setup.solver(&fresh).unwrap();
        let mut y = rest.clone();
        let zero = vec![Vector3::zeros(); rest.len()];
        let r = fresh
            .solve_continued(
                &setup,
                &mut fresh_solver,
                &mut y,
                &zero,
                &forces,
                &eq,
                &settings,
            )
            .unwrap();
        assert!(r.converged(), "load {k} from rest: {r:?}");
        let diff = x
            .iter()
            .zip(&y)
            .map(|(u, v)| (u - v).norm())
            .fold(0.0, f64::max);
        let umax = x
            .iter()
            .zip(&rest)
            .map(|(u, v)| (u - v).norm())
            .fold(0.0, f64::max);
        eprintln!(
            "load {k}: {} it, continued {}, path difference {diff:.2e} m of {umax:.2e} m",
            s.iterations,
            s.from_rest_attempt.is_none()
        );
        assert!(
            umax > 1e-4,
            "load {k}: displacement {umax} too small to test"
        );
        // 100 × the displacement tolerance of one solve: the linear convergence of the relaxed
        // parameter iteration stops each path within a few tolerances of the fixed point.
        assert!(
            diff <= 100.0 * 1e-8 * length,
            "load {k}: paths differ by {diff} m"
        );
        // p = p(ε) at the equilibrium (to the parameters' share of the solver tolerance)
        let strains = softcap_fem::CorotationalModel::new(&setup.mesh, model.params().to_vec())
            .unwrap()
            .strains(&x);
        for (e, eps) in strains.iter().enumerate() {
            let want = material.evaluate(e, eps);
            let got = model.params()[e];
            assert!(
                (got.lambda / want.lambda - 1.0).abs() < 1e-4,
                "load {k}, tet {e}: λ {} vs p(ε) {}",
                got.lambda,
                want.lambda
            );
        }
    }
    // the ramp's second to fourth loads and the repeated load are continued
    assert!(continued >= 4, "only {continued} loads continued");
}

/// Non-convergence of the strain-space solve is a reported status, and the model and positions
/// are left at the last equilibrium so a later solve continues from there.
#[test]
fn strain_space_non_convergence_is_reported_and_keeps_the_last_equilibrium() {
    use softcap_probing::{StrainSpaceModel, StrainSpaceSolveSettings};
    let (setup, _) = block_with([10, 10, 3]);
    let p = LinearParams::from_young_poisson(3e4, 0.4).unwrap();
    let material = stiffening_material(&setup, p);
    let eq = EquilibriumSettings::newton();
    let rest = setup.mesh.vertices.clone();
    let forces = setup.nodal_forces(
        &example(&setup, &rest, Vector3::new(0.015, 0.015, 0.012), -1.5),
        &PatchSettings::default(),
    );
    let mut model = StrainSpaceModel::new(material, &setup.mesh, 0.5).unwrap();
    let mut solver = setup.solver(&model).unwrap();
    let mut x = rest.clone();
    let zero = vec![Vector3::zeros(); rest.len()];
    let starved = StrainSpaceSolveSettings {
        max_iterations: 2,
        ..StrainSpaceSolveSettings::default()
    };
    let params = model.params().to_vec();
    let s = model
        .solve_continued(&setup, &mut solver, &mut x, &zero, &forces, &eq, &starved)
        .unwrap();
    assert!(!s.converged(), "{s:?}");
    assert_eq!(s.from_rest_attempt, Some(starved.relaxation_retries));
    assert_eq!(x, rest);
    assert_eq!(model.params(), &params[..]);
    let ok = model
        .solve_continued(
            &setup,
            &mut solver,
            &mut x,
            &zero,
            &forces,
            &eq,
            &StrainSpaceSolveSettings::default(),
        )
        .unwrap();
    assert!(ok.converged(), "{ok:?}");
}
