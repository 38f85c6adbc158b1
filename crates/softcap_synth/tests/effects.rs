//! The physical effects of the diagnose-suite scenarios (fixtures/scenarios/suite/) are present in
//! the ground truth with the magnitudes the diagnosis needs to see them: force
//! relaxation in the holds, permanent set, surface drag by friction, support slip, inertial
//! overshoot, gravity sag. Each test simulates the committed suite scenario (no files written).

use softcap_synth::{Effect, Phase, Scenario, Truth, simulate, truth::stream};
use std::path::Path;

fn suite(name: &str) -> Scenario {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../fixtures/scenarios/suite")
        .join(format!("{name}.toml"));
    Scenario::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

fn run(s: &Scenario) -> Truth {
    let t0 = std::time::Instant::now();
    let t = simulate(s, &mut stream(s.seed, 1)).unwrap_or_else(|e| panic!("{}: {e}", s.name));
    println!(
        "{}: {} frames simulated in {:.1} s, max iterations {}",
        s.name,
        t.frames.len(),
        t0.elapsed().as_secs_f64(),
        t.max_iterations
    );
    t
}

/// Frames of location `l` in phase `phase`.
fn frames_of(t: &Truth, l: usize, phase: Phase) -> Vec<usize> {
    t.frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.spec.location == l && f.spec.phase == phase)
        .map(|(k, _)| k)
        .collect()
}

#[test]
fn viscoelastic_force_relaxes_during_every_hold() {
    let s = suite("viscoelasticity");
    assert!(s.has(Effect::Viscoelasticity));
    let t = run(&s);
    let mut worst: f64 = 0.0;
    for l in 0..t.locations_m.len() {
        let ramp = frames_of(&t, l, Phase::Loading);
        let hold = frames_of(&t, l, Phase::Hold);
        assert!(hold.len() >= 4);
        let peak = t.frames[*ramp.last().unwrap()].axial_force_n;
        let end = t.frames[*hold.last().unwrap()].axial_force_n;
        // Same commanded depth through the hold: the force falls monotonically.
        for w in hold.windows(2) {
            assert!(t.frames[w[1]].axial_force_n < t.frames[w[0]].axial_force_n);
        }
        let ratio = end / peak;
        println!("location {l}: peak {peak:.3} N, end of hold {end:.3} N, ratio {ratio:.3}");
        assert!(peak > 0.5, "peak {peak}");
        worst = worst.max(ratio);
    }
    // g = 0.5, τ = hold/2 = ramp/2: the ramp ends at 1 + g (τ/T)(1 − e^{−T/τ}) ≈ 1.22 F_∞ and the
    // excess decays by e^{−2} over the hold: ratio ≈ 1.03/1.22 = 0.85.
    assert!(worst < 0.9, "end/peak force ratio {worst:.3}");
    // Creep recovery: the first released frame has not fully recovered the rest shape.
    let rest = &t.frames[0].markers_m;
    let released = frames_of(&t, 1.min(t.locations_m.len() - 1), Phase::Released);
    let after = &t.frames[released[0]];
    assert_eq!(after.axial_force_n, 0.0);
    let lag = after
        .markers_m
        .iter()
        .zip(rest)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    println!(
        "residual displacement right after release: {:.3} mm",
        lag * 1e3
    );
}

#[test]
fn plasticity_leaves_a_permanent_set_after_release() {
    let s = suite("plasticity");
    let t = run(&s);
    assert!(t.yielded_elements > 0);
    let rest = &t.template_markers_m;
    let mut set_after: Vec<f64> = Vec::new();
    for l in 0..t.locations_m.len() {
        // The last frame before the probe touches the next location (or the session's end).
        let released: Vec<usize> = t
            .frames
            .iter()
            .enumerate()
            .filter(|(_, f)| f.spec.phase == Phase::Released && f.axial_force_n == 0.0)
            .map(|(k, _)| k)
            .filter(|&k| {
                let prev_loc = (0..k)
                    .rev()
                    .find(|&j| t.frames[j].spec.phase == Phase::Unloading)
                    .map(|j| t.frames[j].spec.location);
                prev_loc == Some(l)
            })
            .collect();
        let k = *released
            .last()
            .expect("released frames after each location");
        let set = t.frames[k]
            .markers_m
            .iter()
            .zip(rest)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        println!(
            "after location {l}: max permanent marker displacement {:.3} mm",
            set * 1e3
        );
        set_after.push(set);
    }
    println!("{} truth elements yielded", t.yielded_elements);
    // The same protocol with the yield stress out of reach: the elastic peak von Mises stress that
    // σ_y is compared with (diagnose asked for yield ≈ 30–40 % of the peak).
    let mut elastic = s.clone();
    elastic.effect_settings.plastic_yield_pa = 1e12;
    let te = run(&elastic);
    assert_eq!(te.yielded_elements, 0);
    let ratio = s.effect_settings.plastic_yield_pa / te.peak_von_mises_pa;
    println!(
        "elastic peak von Mises {:.0} Pa, plastic run peak {:.0} Pa; yield ratio σ_y / peak = {ratio:.3}",
        te.peak_von_mises_pa, t.peak_von_mises_pa
    );
    assert!(
        (0.1..0.5).contains(&ratio),
        "yield ratio {ratio:.3} (σ_y {} Pa, elastic peak {:.0} Pa)",
        s.effect_settings.plastic_yield_pa,
        te.peak_von_mises_pa
    );
    // With hardening H the returned stress stays at σ_y + H ᾱ ≪ the elastic peak.
    assert!(t.peak_von_mises_pa < te.peak_von_mises_pa);
    assert!(set_after[0] >= 0.5e-3, "set {:.3} mm", set_after[0] * 1e3);
    assert!(set_after.iter().all(|&v| v >= 0.5e-3));
}

#[test]
fn support_slip_slides_the_block_on_its_mount() {
    let s = suite("support-slip");
    let t = run(&s);
    let slip = t
        .frames
        .iter()
        .map(|f| f.support_slip_m.norm())
        .fold(0.0, f64::max);
    let tangential = t
        .frames
        .iter()
        .map(|f| f.force_n.xy().norm())
        .fold(0.0, f64::max);
    println!(
        "max mean support slip {:.3} mm, max tangential probe force {tangential:.3} N",
        slip * 1e3
    );
    assert!(slip >= 0.5e-3, "slip {:.3} mm", slip * 1e3);
    // Back on the mount once the probe is lifted (elastic springs): no slip at rest frames.
    for f in t.frames.iter().filter(|f| f.axial_force_n == 0.0) {
        assert!(f.support_slip_m.norm() < 1e-9);
    }
}

#[test]
fn gravity_preload_sags_every_frame_below_the_unloaded_template() {
    let s = suite("gravity-preload");
    let t = run(&s);
    let sag: Vec<f64> = t.frames[0]
        .markers_m
        .iter()
        .zip(&t.template_markers_m)
        .map(|(a, b)| b.z - a.z)
        .collect();
    let min = sag.iter().copied().fold(f64::INFINITY, f64::min);
    let mean = sag.iter().sum::<f64>() / sag.len() as f64;
    println!(
        "frame-0 sag below the unloaded template: min {:.3} mm, mean {:.3} mm",
        min * 1e3,
        mean * 1e3
    );
    // Template = the unloaded box (top face at the block height).
    let top = s.object.size_mm[2] * 1e-3;
    assert!(
        t.template_markers_m
            .iter()
            .all(|m| (m.z - top).abs() < 1e-12)
    );
    assert!(min >= 0.5e-3, "min sag {:.3} mm", min * 1e3);
}

#[test]
fn probe_friction_drags_the_surface_beyond_the_frictionless_response() {
    // The first two locations of the suite scenario (keeps the test short), against the same path
    // with μ = 0: the difference at the markers is the surface drag friction causes.
    let mut s = suite("probe-friction");
    assert!(s.has(Effect::ProbeFriction));
    s.protocol.locations = 2;
    let t = run(&s);
    let mut frictionless = s.clone();
    frictionless.effect_settings.friction_mu = 0.0;
    let t0 = run(&frictionless);
    assert_eq!(t.frames.len(), t0.frames.len());
    println!(
        "largest lag mismatch of the friction normal forces: {:.3}",
        t.friction_lag_mismatch
    );
    assert!(t.friction_lag_mismatch < 0.2);
    for l in 0..t.locations_m.len() {
        let hold = frames_of(&t, l, Phase::Hold);
        let k = *hold.last().unwrap();
        let (f, f0) = (&t.frames[k], &t0.frames[k]);
        // Tangential probe travel is friction_path_ratio × depth.
        let travel = s.effect_settings.friction_path_ratio * f.spec.depth_m;
        let drag = f
            .markers_m
            .iter()
            .zip(&f0.markers_m)
            .map(|(a, b)| (a - b).xy().norm())
            .fold(0.0, f64::max);
        let ratio = f.friction_force_n.norm() / f.axial_force_n;
        println!(
            "location {l}: depth {:.2} mm, travel {:.2} mm, axial {:.3} N, friction {:.3} N (ratio {ratio:.2}), drag vs μ = 0 {:.3} mm",
            f.spec.depth_m * 1e3,
            travel * 1e3,
            f.axial_force_n,
            f.friction_force_n.norm(),
            drag * 1e3
        );
        assert!(travel >= 0.5 * f.spec.depth_m);
        // Coulomb: |f_t| ≤ μ Σ f_n (≈ μ × axial force for a near-vertical contact).
        assert!(
            ratio <= s.effect_settings.friction_mu * 1.05,
            "ratio {ratio}"
        );
        assert!(ratio > 0.1, "ratio {ratio}");
        assert!(drag >= 0.5e-3, "drag {:.3} mm", drag * 1e3);
        assert!(f0.friction_force_n.norm() < 1e-12);
    }
}
