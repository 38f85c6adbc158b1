//! CPU time (not wall time) per run-time pass on the ICT face and the 3× subdivided face, for a
//! loaded machine where criterion's wall-clock numbers measure the neighbours: user + system
//! time of this process from `/proc/self/stat` over many repetitions (Linux only).
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p softcap_psd --example pass_cpu_time`
//! (`PSD_LEVELS` subdivision levels, default 3; `PSD_FRAMES` frames of the subdivided face,
//! default 10; `PSD_ONLY_FRAMES=1` skips the per-pass timings, e.g. for `/usr/bin/time` over
//! two frame counts; `PSD_ONLY_PASS=large|detail|normal` times one pass alone, e.g. under
//! `perf record`; `PSD_REORDER=1` the Morton locality order inside the layout (outputs
//! un-permuted every frame); `PSD_PERMUTE=1` the rig itself stored in Morton order,
//! [`softcap_psd::permute_rig`]; `PSD_SPARSITY=1` prints the fraction of vertices whose
//! per-frame detail bound `Σ_j ‖w_vj‖ R_j` is below 1e-7 … 1e-3 cm). After the frame timing it
//! prints an FNV-1a hash of the output positions and normals: a change that must not alter
//! results prints the same hash.

use softcap_psd::runtime::{self, LANES};
use softcap_psd::{
    Animator, EvaluationSettings, FaceRig, FitMode, IctData, RigSettings, RuntimeSettings,
    fit_wpsd, permute_rig, pose_sets, subdivide_rig,
};
use std::path::PathBuf;
use std::time::Instant;

/// (user + system CPU seconds of the process, wall seconds)
fn clocks() -> (f64, Instant) {
    (
        softcap_app::process::cpu_seconds().unwrap_or(0.0),
        Instant::now(),
    )
}

fn time(label: &str, reps: usize, mut f: impl FnMut()) {
    f();
    let (c0, w0) = clocks();
    for _ in 0..reps {
        f();
    }
    let (c1, _) = clocks();
    println!(
        "{label:40} cpu {:8.2} ms   wall {:8.2} ms",
        1e3 * (c1 - c0) / reps as f64,
        1e3 * w0.elapsed().as_secs_f64() / reps as f64
    );
}

fn main() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/ict-face");
    let data = IctData::load(&dir).expect("ICT fixture");
    let settings = RigSettings::default();
    let rig = FaceRig::new(&data.mesh, &settings).expect("rig");
    let (training, heldout) = pose_sets(&data, &EvaluationSettings::default());
    let poses: Vec<_> = training.iter().map(|r| data.pose(r)).collect();
    let examples = rig.examples(&poses).expect("examples");
    let model = fit_wpsd(
        &examples,
        &[0, 3, 6, 9, 12, 15],
        FitMode::Interpolate,
        &rig.edge_weights,
    )
    .expect("fit");
    let hp = rig.handle_positions(&data.pose(&heldout[0]));
    let levels: usize = std::env::var("PSD_LEVELS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3);
    for level in [0, levels] {
        let (r, m) = if level == 0 {
            (rig.clone(), model.clone())
        } else {
            subdivide_rig(&rig, &model, level, &settings.edge_weights)
        };
        let (r, m) = if std::env::var("PSD_PERMUTE").is_ok_and(|v| v == "1") {
            permute_rig(&r, &m, &runtime::morton_order(&r.rest_f32))
        } else {
            (r, m)
        };
        let t = Instant::now();
        let settings = RuntimeSettings {
            reorder: std::env::var("PSD_REORDER").is_ok_and(|v| v == "1"),
            ..Default::default()
        };
        let mut anim = Animator::with_settings(&r, &m, &settings).expect("animator");
        let n = r.num_vertices();
        println!(
            "{n} vertices: layout built in {:.1} s, mean rank {:.2}, {:.0} MB streamed per frame \
             ({:.0} B/vertex), WPSD edges per 8-vertex batch {:.1}",
            t.elapsed().as_secs_f64(),
            anim.layout.basis.mean_rank(),
            anim.layout.bytes_per_frame() as f64 / 1e6,
            anim.layout.bytes_per_frame() as f64 / n as f64,
            anim.layout.details.mean_union()
        );
        if std::env::var_os("PSD_SPARSITY").is_some() {
            // per-frame bound of the detail: r_j ≤ R_j = sqrt(max_i g_ij) (α sums to 1), so
            // ‖d_v‖ ≤ Σ_j ‖w_vj‖ R_j
            let p = m.num_poses();
            let f = r.features(&hp);
            let rj: Vec<f64> = (0..p)
                .map(|j| {
                    (0..m.num_features)
                        .map(|i| (f[i] - m.centers[j * m.num_features + i]).powi(2))
                        .fold(0.0, f64::max)
                        .sqrt()
                })
                .collect();
            let bound: Vec<f64> = (0..n)
                .map(|v| {
                    (0..p)
                        .map(|j| {
                            let w = &m.weights[v * 3 * p + 3 * j..v * 3 * p + 3 * j + 3];
                            (w.iter().map(|&x| (x as f64).powi(2)).sum::<f64>()).sqrt() * rj[j]
                        })
                        .sum()
                })
                .collect();
            for tol in [1e-7, 1e-6, 1e-5, 1e-4, 1e-3] {
                let below = bound.iter().filter(|&&b| b <= tol).count();
                let batches = bound
                    .chunks(8)
                    .filter(|c| c.iter().all(|&b| b <= tol))
                    .count();
                println!(
                    "detail bound ≤ {tol:e} cm: {:.1} % of vertices, {:.1} % of 8-vertex batches",
                    100.0 * below as f64 / n as f64,
                    100.0 * batches as f64 / n.div_ceil(8) as f64
                );
            }
        }
        let reps = if n > 100_000 { 10 } else { 200 };
        let reps = std::env::var("PSD_FRAMES")
            .ok()
            .and_then(|s| s.parse::<usize>().ok())
            .map_or(reps, |f| if n > 100_000 { f } else { 20 * f });
        let only = std::env::var("PSD_ONLY_PASS").unwrap_or_default();
        if only.is_empty() {
            time("frame", reps, || anim.frame(&hp).expect("frame"));
            // FNV-1a of the output bits: kernels that must not change results print the same
            let mut hash = 0xcbf2_9ce4_8422_2325u64;
            for x in anim.positions.iter().chain(&anim.normals).flatten() {
                hash = (hash ^ x.to_bits() as u64).wrapping_mul(0x0100_0000_01b3);
            }
            println!("frame output bits: {hash:016x}");
        }
        if std::env::var_os("PSD_ONLY_FRAMES").is_some() {
            continue;
        }
        let layout = &anim.layout;
        let uh: Vec<[f32; 3]> = r
            .handles
            .iter()
            .zip(&hp)
            .map(|(&v, p)| {
                let d = p - r.rest[v];
                [d.x as f32, d.y as f32, d.z as f32]
            })
            .collect();
        let mut large = vec![[0.0f32; 3]; n];
        let mut pos = vec![[0.0f32; 3]; n];
        let mut nrm = vec![[0.0f32; 3]; n];
        let mut table: Vec<[f32; LANES]> = Vec::new();
        runtime::feature_table(&m, &r.features(&hp), &mut table);
        // PSD_ONLY_PASS=large|detail|normal times that pass alone (the earlier ones run once)
        let run = |name: &str| only.is_empty() || only == name;
        runtime::large_scale_pass(layout, &uh, &mut large);
        if run("large") {
            time("  large_scale_pass", reps, || {
                runtime::large_scale_pass(layout, &uh, &mut large)
            });
        }
        runtime::detail_pass(layout, &large, &table, None, &mut pos);
        if run("detail") {
            time("  detail_pass (normal, frame, WPSD)", reps, || {
                runtime::detail_pass(layout, &large, &table, None, &mut pos)
            });
        }
        if run("normal") {
            time("  normal_pass", reps, || {
                runtime::normal_pass(layout, &pos, &mut nrm)
            });
        }
    }
}
