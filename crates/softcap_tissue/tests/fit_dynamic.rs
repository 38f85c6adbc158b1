//! wang2015 §6 dynamic parameter estimation on known-truth sequences (Table 1 / Table 2 style).

use nalgebra::Vector3;
use softcap_fem::RayleighDamping;
use softcap_tissue::Progress;
use softcap_tissue::fit_dynamic::synthetic::{SyntheticSpec, clamped_box, synthesize};
use softcap_tissue::fit_dynamic::{FitDynamicSettings, Optimizer, fit_sequence};

fn bar_spec(young: Vec<f64>, noise_m: f64) -> SyntheticSpec {
    let (mesh, support, push) = clamped_box([0.2, 0.03, 0.02], [12, 2, 2]);
    let young = if young.len() == 1 { vec![young[0]; mesh.tets.len()] } else { young };
    SyntheticSpec {
        rest_mesh: mesh,
        support_nodes: support,
        young_pa: young,
        poisson: 0.45,
        density_kg_m3: 1100.0,
        damping: RayleighDamping { alpha_per_s: 0.8, beta_s: std::env::var("BETA").map(|v| v.parse().unwrap()).unwrap_or(1.0e-3) },
        gravity_m_s2: Vector3::new(0.0, 0.0, -9.80665),
        push_nodes: push,
        push_force_n: Vector3::new(0.0, 0.5, -0.3),
        push_s: 0.2,
        frames: 45,
        frame_rate_hz: 30.0,
        substeps: 4,
        refine: 0,
        noise_m,
        seed: 7,
    }
}

#[test]
fn homogeneous_bar_e_alpha_beta_from_noisy_trajectories() {
    let truth = synthesize(&bar_spec(vec![5.0e5], 5.0e-4)).unwrap();
    for optimizer in [Optimizer::LevenbergMarquardt] {
        let settings = FitDynamicSettings { optimizer, progress: false, ..FitDynamicSettings::default() };
        let t = std::time::Instant::now();
        let fit = fit_sequence(&truth.template, &truth.sequence, &settings, &Progress::hidden()).unwrap();
        println!(
            "{optimizer:?}: E {:.4e} alpha {:.4} beta {:.4e} warm E {:.4e} a {:.3} b {:.2e} rms {:.2e}/{:.2e}/{:.2e} sims {} hist {:?} {} sigma {:?} modes {:?} {:.1}s",
            fit.young_pa[0], fit.damping.alpha_per_s, fit.damping.beta_s, fit.warm_young_pa,
            fit.warm_damping.alpha_per_s, fit.warm_damping.beta_s, fit.rms_initial_m, fit.rms_warm_m, fit.rms_m,
            fit.simulations, fit.history, fit.status, fit.relative_sigma, fit.measured_modes, t.elapsed().as_secs_f64()
        );
    }
}

#[test]
fn debug_forward_at_truth() {
    use softcap_tissue::fit_dynamic::{DynamicParams, Forward, ForwardSettings};
    let spec = bar_spec(vec![5.0e5], std::env::var("NOISE").map(|v| v.parse().unwrap()).unwrap_or(0.0));
    let truth = synthesize(&spec).unwrap();
    let hw0: usize = std::env::var("HW").map(|v| v.parse().unwrap()).unwrap_or(2);
    let segs = truth.sequence.segments(30, 4, hw0);
    println!("segments {segs:?}");
    let n = truth.template.vertices.len();
    let hw: usize = std::env::var("HW").map(|v| v.parse().unwrap()).unwrap_or(2); let it: usize = std::env::var("IT").map(|v| v.parse().unwrap()).unwrap_or(6);
    let fw = Forward::new(&truth.template, &truth.sequence, segs, vec![true; n], &ForwardSettings { velocity_half_window: hw, newton_iterations: it, velocity_degree: std::env::var("DEG").map(|v| v.parse().unwrap()).unwrap_or(4), initial_state_smoothing: std::env::var("SM").map(|v| v.parse().unwrap()).unwrap_or(1.0), ..ForwardSettings::default() }).unwrap();
    let p = DynamicParams { young_pa: spec.young_pa.clone(), poisson: 0.45, damping: spec.damping };
    let t = std::time::Instant::now();
    let runs = fw.simulate(&p, &truth.rest_m).unwrap();
    println!("rms at truth {:.3e} in {:.2}s maxit {:?} fail {:?}", fw.rms_m(&runs), t.elapsed().as_secs_f64(),
        runs.iter().map(|r| r.max_iteration_steps).collect::<Vec<_>>(), runs.iter().map(|r| r.failure.clone()).collect::<Vec<_>>());
    let r = fw.residuals(&runs);
    let per_frame: Vec<f64> = r.chunks(r.len() / 10).map(|c| (c.iter().map(|v| v*v).sum::<f64>() / c.len() as f64 * 3.0).sqrt()).collect();
    println!("per chunk rms {per_frame:?}");
}

#[test]
fn debug_noise_level() {
    let a = synthesize(&bar_spec(vec![5.0e5], 0.0)).unwrap();
    let b = synthesize(&bar_spec(vec![5.0e5], 5e-4)).unwrap();
    let mut ss = 0.0; let mut n = 0;
    let mut mx: f64 = 0.0;
    for (fa, fb) in a.sequence.positions_m.iter().zip(&b.sequence.positions_m) {
        for (p, q) in fa.iter().zip(fb) { ss += (p - q).norm_squared(); n += 3; mx = mx.max((p-q).norm()); }
    }
    println!("noise rms {:.3e} max {:.3e}", (ss / n as f64).sqrt(), mx);
}

#[test]
fn debug_truth_tip() {
    let a = synthesize(&bar_spec(vec![5.0e5], 0.0)).unwrap();
    let tip = a.template.vertices.iter().enumerate().max_by(|x, y| x.1.x.total_cmp(&y.1.x)).unwrap().0;
    let z: Vec<String> = a.sequence.positions_m.iter().map(|f| format!("{:.1}", (f[tip].z - a.template.vertices[tip].z) * 1e3)).collect();
    let y: Vec<String> = a.sequence.positions_m.iter().map(|f| format!("{:.1}", (f[tip].y - a.template.vertices[tip].y) * 1e3)).collect();
    println!("sag tip z {:.2} mm\nz {}\ny {}", (a.template.vertices[tip].z - a.rest_m[tip].z) * 1e3, z.join(" "), y.join(" "));
}
