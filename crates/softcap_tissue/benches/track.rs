//! Issue 29 bench: the tracker of wang2015 §5 (`softcap tissue track`'s loop) on a 2k-node mesh
//! with about 20,000 points per frame; the goal is ≥ 5 frames/s on 2 cores (wang2015 Table 4:
//! 7–38 minutes per 44–523-frame sequence on 8 cores, i.e. 0.1–0.3 frames/s).
//!
//! The scene is built here, in memory (no other stage), like `fixtures/scenarios/dynamic/bench-2k`:
//! a 200 × 30 × 30 mm bar of 40 × 6 × 6 cells (2,009 nodes, 8,640 tets) clamped at x = 0, its truth
//! simulated by softcap's own dynamics (`fit_dynamic::synthetic`: E 1 MPa, ν 0.45, ρ 1100 kg/m³,
//! Rayleigh α 0.8 1/s, β 1 ms, sagging at frame 0, pushed at the free end for 8 frames and
//! released; 15 frames at 30 Hz). Each frame's cloud samples the truth's boundary faces that face
//! one of two depth cameras (either side of the bar, above it), uniformly by area, about 10,300
//! points per camera, with 1 mm Gaussian noise (no holes or self-occlusion: this bench measures
//! speed; the accuracy rows are `scripts/track-table` on the virtual rig's depth images). The
//! tracker runs with its default settings and default material (E 100 kPa, its weight balanced,
//! what `softcap tissue track` does without `--material` on this bar).
//!
//! `scripts/bench softcap_tissue -- track` (= `cargo bench -p softcap_tissue --bench track`):
//! criterion, 10 samples of the 15-frame sequence, throughput in frames/s. Before criterion
//! starts one run is timed and printed with its process CPU time and the tracked error against
//! the truth; `SOFTCAP_TRACK_BENCH_ONCE=1` stops there.

use std::time::{Duration, Instant};

use criterion::{BatchSize, Criterion, SamplingMode, Throughput, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use softcap_fem::nalgebra::{Matrix3, Vector3};
use softcap_fem::{CorotationalModel, LinearParams, RayleighDamping, lumped_masses};
use softcap_mesh::TetMesh;
use softcap_tissue::TrackSettings;
use softcap_tissue::fit_dynamic::synthetic::{SyntheticSpec, clamped_box, synthesize};
use softcap_tissue::track::tracker::{Attachment, Tracker, ViewCamera};

const FRAMES: usize = 15;
const FRAME_RATE_HZ: f64 = 30.0;
const POINTS_PER_CAMERA: usize = 10_300;

/// The scene: frame-0 template, support, per-frame truth positions and clouds.
struct Scene {
    template: TetMesh,
    support: Vec<usize>,
    truth: Vec<Vec<Vector3<f64>>>,
    clouds: Vec<(Vec<Vector3<f64>>, Vec<Vector3<f64>>)>,
    cameras: Vec<ViewCamera>,
}

/// A 640 × 480 depth camera at `centre` looking at `target` (focal 930 px, depth 0.2–3 m).
fn camera(id: &str, centre: Vector3<f64>, target: Vector3<f64>) -> ViewCamera {
    let z = (target - centre).normalize();
    let x = z.cross(&Vector3::z()).normalize();
    let y = z.cross(&x);
    let r = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    let camera = softcap_core::Camera::new(
        id.into(),
        640,
        480,
        [930.0, 930.0, 320.0, 240.0],
        [0.0; 5],
        r,
        -(r * centre),
    )
    .expect("camera");
    ViewCamera {
        camera,
        min_depth_m: 0.2,
        max_depth_m: 3.0,
    }
}

fn scene() -> Scene {
    let (rest, support, push) = clamped_box([0.2, 0.03, 0.03], [40, 6, 6]);
    let spec = SyntheticSpec {
        young_pa: vec![1.0e6; rest.tets.len()],
        rest_mesh: rest,
        support_nodes: support.clone(),
        poisson: 0.45,
        density_kg_m3: 1100.0,
        damping: RayleighDamping {
            alpha_per_s: 0.8,
            beta_s: 1.0e-3,
        },
        gravity_m_s2: softcap_fem::STANDARD_GRAVITY_M_S2,
        push_nodes: push,
        push_force_n: Vector3::new(0.0, 0.5, -0.9),
        counter_push_nodes: Vec::new(),
        push_s: 8.0 / FRAME_RATE_HZ,
        frames: FRAMES,
        frame_rate_hz: FRAME_RATE_HZ,
        substeps: 4,
        refine: 0,
        elements: softcap_tissue::fit_dynamic::Elements::Linear,
        noise_m: 0.0,
        seed: 29,
    };
    let synthetic = synthesize(&spec).expect("truth");
    let target = Vector3::new(0.1, 0.0, -0.01);
    let cameras = vec![
        camera("left", Vector3::new(0.1, -0.55, 0.3), target),
        camera("right", Vector3::new(0.1, 0.55, 0.3), target),
    ];
    let faces = synthetic.template.boundary_faces();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(29);
    let noise = Normal::new(0.0, 1.0e-3).expect("noise");
    let clouds = synthetic
        .sequence
        .positions_m
        .iter()
        .map(|x| {
            let (mut points, mut normals) = (Vec::new(), Vec::new());
            for c in &cameras {
                let centre = c.camera.centre_world().coords;
                // faces turned towards this camera, with their areas
                let seen: Vec<([usize; 3], f64, Vector3<f64>)> = faces
                    .iter()
                    .filter_map(|t| {
                        let n = (x[t[1]] - x[t[0]]).cross(&(x[t[2]] - x[t[0]]));
                        let mid = (x[t[0]] + x[t[1]] + x[t[2]]) / 3.0;
                        (n.dot(&(centre - mid)) > 0.0).then(|| (*t, 0.5 * n.norm(), n.normalize()))
                    })
                    .collect();
                let total: f64 = seen.iter().map(|s| s.1).sum();
                for (t, area, n) in &seen {
                    let count = (POINTS_PER_CAMERA as f64 * area / total).round() as usize;
                    for _ in 0..count {
                        let (mut a, mut b): (f64, f64) = (rng.random(), rng.random());
                        if a + b > 1.0 {
                            (a, b) = (1.0 - a, 1.0 - b);
                        }
                        let p = x[t[0]] + (x[t[1]] - x[t[0]]) * a + (x[t[2]] - x[t[0]]) * b;
                        let e = Vector3::from_fn(|_, _| noise.sample(&mut rng));
                        points.push(p + e);
                        normals.push(*n);
                    }
                }
            }
            (points, normals)
        })
        .collect();
    Scene {
        template: synthetic.template,
        support,
        truth: synthetic.sequence.positions_m,
        clouds,
        cameras,
    }
}

/// A tracker of the scene's template with the default material, its weight balanced.
fn tracker<'a>(s: &'a Scene, settings: &TrackSettings) -> Tracker<'a> {
    let params =
        LinearParams::from_young_poisson(settings.young_pa, settings.poisson).expect("material");
    let model = CorotationalModel::homogeneous(&s.template, params).expect("model");
    let masses = lumped_masses(&model, 1100.0);
    let n = masses.len();
    Tracker::new(
        &s.template,
        model,
        masses,
        vec![Vector3::zeros(); n],
        Attachment {
            frame0_m: s.support.iter().map(|&i| s.template.vertices[i]).collect(),
            nodes: s.support.clone(),
        },
        s.cameras.clone(),
        RayleighDamping {
            alpha_per_s: settings.rayleigh_alpha_per_s,
            beta_s: settings.rayleigh_beta_s,
        },
        1.0 / FRAME_RATE_HZ,
        settings,
    )
    .expect("tracker")
}

/// Tracks every frame; returns the node RMS error against the truth over all frames (m), the EM
/// iterations and the factorizations per frame.
fn run(s: &Scene, mut t: Tracker<'_>) -> (f64, f64, f64) {
    let (mut sum, mut count, mut iterations) = (0.0, 0usize, 0usize);
    for (k, (points, normals)) in s.clouds.iter().enumerate() {
        let f = t.track(k as u64, k as f64 / FRAME_RATE_HZ, points, normals, None);
        iterations += f.em_iterations;
        for (a, b) in f.positions_m.iter().zip(&s.truth[k]) {
            sum += (a - b).norm_squared();
            count += 1;
        }
    }
    let frames = s.clouds.len().max(1) as f64;
    (
        (sum / count.max(1) as f64).sqrt(),
        iterations as f64 / frames,
        t.factorizations() as f64 / frames,
    )
}

fn process_cpu_s() -> f64 {
    softcap_app::process::cpu_seconds().unwrap_or(f64::NAN)
}

fn bench(c: &mut Criterion) {
    let t0 = Instant::now();
    let s = scene();
    let points: usize = s.clouds.iter().map(|c| c.0.len()).sum();
    eprintln!(
        "scene: {} nodes, {} tets, {FRAMES} frames, {:.0} points per frame (built in {:.1} s)",
        s.template.vertices.len(),
        s.template.tets.len(),
        points as f64 / FRAMES as f64,
        t0.elapsed().as_secs_f64()
    );
    let settings = TrackSettings {
        progress: false,
        ..TrackSettings::default()
    };
    let (cpu0, wall0) = (process_cpu_s(), Instant::now());
    let (rms, iterations, factorizations) = run(&s, tracker(&s, &settings));
    let (cpu, wall) = (process_cpu_s() - cpu0, wall0.elapsed().as_secs_f64());
    eprintln!(
        "single run: {:.2} frames/s ({wall:.2} s wall, {:.3} CPU-s per frame), {iterations:.2} EM iterations and {factorizations:.2} factorizations per frame, node RMS vs truth {:.3} mm, {} rayon threads",
        FRAMES as f64 / wall,
        cpu / FRAMES as f64,
        1e3 * rms,
        rayon::current_num_threads()
    );
    if std::env::var_os("SOFTCAP_TRACK_BENCH_ONCE").is_some() {
        eprintln!("SOFTCAP_TRACK_BENCH_ONCE set: single run only, no criterion samples");
        return;
    }
    let mut g = c.benchmark_group("track");
    g.sample_size(10);
    g.sampling_mode(SamplingMode::Flat);
    g.warm_up_time(Duration::from_millis(1));
    g.measurement_time(Duration::from_secs(1));
    g.throughput(Throughput::Elements(FRAMES as u64));
    g.bench_function("track_2009_nodes_20k_points", |b| {
        b.iter_batched(
            || tracker(&s, &settings),
            |t| run(&s, t),
            BatchSize::PerIteration,
        )
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
