//! Frame time of the run-time synthesis (thesis §5.5.2, Table 5.1): ICT face (9.4k vertices) and a
//! midpoint-subdivided face (592k vertices), H = 89, F = 243, P = 6 (WPSD); and the three
//! run-time passes of the subdivided face timed separately (`psd_pass`).
//!
//! The subdivided face is benchmarked stored in a Morton locality order ([`permute_rig`], as an
//! asset would be stored for rendering; the headline row) and in the order the subdivision
//! emits its vertices (`mesh_order`). Bench ids end in `_t{threads}` (rayon's thread count,
//! `RAYON_NUM_THREADS`), so runs with 1 and 2 threads sit side by side in `scripts/bench`'s table.

use criterion::{Criterion, criterion_group, criterion_main};
use softcap_psd::runtime::{self, LANES};
use softcap_psd::{
    Animator, EvaluationSettings, FitMode, IctData, RigSettings, fit_wpsd, permute_rig, pose_sets,
    subdivide_rig,
};
use std::hint::black_box;
use std::path::PathBuf;

fn bench(c: &mut Criterion) {
    let threads = rayon::current_num_threads();
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/ict-face");
    let data = IctData::load(&dir).expect("ICT fixture");
    let settings = RigSettings::default();
    let rig = softcap_psd::FaceRig::new(&data.mesh, &settings).expect("rig");
    let (training, heldout) = pose_sets(&data, &EvaluationSettings::default());
    // P = 6: rest + five expressions with large deformations (thesis: 6 example poses)
    let names = [
        "jawOpen",
        "mouthSmile_L",
        "browInnerUp_R",
        "mouthPucker",
        "cheekPuff_L",
    ];
    let mut basis = vec![0];
    basis.extend(
        names
            .iter()
            .filter_map(|n| training.iter().position(|r| r.name == *n)),
    );
    let poses: Vec<_> = training.iter().map(|r| data.pose(r)).collect();
    let examples = rig.examples(&poses).expect("examples");
    let model = fit_wpsd(&examples, &basis, FitMode::Interpolate, &rig.edge_weights).expect("fit");
    let frames: Vec<Vec<_>> = heldout
        .iter()
        .map(|r| rig.handle_positions(&data.pose(r)))
        .collect();
    let tag = format!("H89_F{}_P{}_t{threads}", rig.graph.len(), basis.len());

    let mut group = c.benchmark_group("psd_frame");
    group.sample_size(20);
    let mut anim = Animator::new(&rig, &model).expect("animator");
    let mut k = 0;
    group.bench_function(format!("ict_{}v_{tag}", rig.num_vertices()), |b| {
        b.iter(|| {
            k = (k + 1) % frames.len();
            anim.frame(black_box(&frames[k])).expect("frame");
        })
    });
    let (mesh_rig, mesh_model) = subdivide_rig(&rig, &model, 3, &settings.edge_weights);
    let order = runtime::morton_order(&mesh_rig.rest_f32);
    let (fine_rig, fine_model) = permute_rig(&mesh_rig, &mesh_model, &order);
    let n = fine_rig.num_vertices();
    group.sample_size(10);
    {
        let mut anim = Animator::new(&mesh_rig, &mesh_model).expect("animator");
        group.bench_function(format!("subdivided_{n}v_mesh_order_{tag}"), |b| {
            b.iter(|| {
                k = (k + 1) % frames.len();
                anim.frame(black_box(&frames[k])).expect("frame");
            })
        });
    }
    drop((mesh_rig, mesh_model));
    let mut anim = Animator::new(&fine_rig, &fine_model).expect("animator");
    group.sample_size(20);
    group.bench_function(format!("subdivided_{n}v_{tag}"), |b| {
        b.iter(|| {
            k = (k + 1) % frames.len();
            anim.frame(black_box(&frames[k])).expect("frame");
        })
    });
    group.finish();

    // the passes of one frame on the (Morton-ordered) subdivided face, run separately
    let mut group = c.benchmark_group("psd_pass");
    group.sample_size(10);
    let layout = &anim.layout;
    let hp = &frames[0];
    let uh: Vec<[f32; 3]> = fine_rig
        .handles
        .iter()
        .zip(hp)
        .map(|(&v, p)| {
            let d = p - fine_rig.rest[v];
            [d.x as f32, d.y as f32, d.z as f32]
        })
        .collect();
    let mut large = vec![[0.0f32; 3]; n];
    let mut positions = vec![[0.0f32; 3]; n];
    let mut normals = vec![[0.0f32; 3]; n];
    let mut table: Vec<[f32; LANES]> = Vec::new();
    runtime::feature_table(&fine_model, &fine_rig.features(hp), &mut table);
    group.bench_function(format!("large_scale_t{threads}"), |b| {
        b.iter(|| runtime::large_scale_pass(layout, black_box(&uh), &mut large))
    });
    group.bench_function(format!("normal_frame_detail_t{threads}"), |b| {
        b.iter(|| runtime::detail_pass(layout, black_box(&large), &table, None, &mut positions))
    });
    group.bench_function(format!("normals_t{threads}"), |b| {
        b.iter(|| runtime::normal_pass(layout, black_box(&positions), &mut normals))
    });
    eprintln!(
        "subdivided face (Morton order): {n} vertices, low-rank basis mean rank {:.2} ({:.0} MB), \
         {:.0} MB ({:.0} B/vertex) streamed per frame",
        layout.basis.mean_rank(),
        layout.basis.bytes() as f64 / 1e6,
        layout.bytes_per_frame() as f64 / 1e6,
        layout.bytes_per_frame() as f64 / n as f64,
    );
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
