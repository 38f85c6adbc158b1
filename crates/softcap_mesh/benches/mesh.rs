//! Mesh I/O, Laplacian assembly and point-location throughput.

use criterion::{Criterion, criterion_group, criterion_main};
use softcap_mesh::nalgebra::Vector3;
use softcap_mesh::*;
use std::hint::black_box;
use std::path::Path;

fn benches(c: &mut Criterion) {
    let face_path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/ict-face/neutral.obj");
    c.bench_function("read_obj ICT neutral (9,409 verts)", |b| {
        b.iter(|| read_obj(black_box(&face_path)).unwrap())
    });
    let face = read_obj_tri_mesh(&face_path).unwrap();
    c.bench_function("CotanLaplacian::new ICT neutral", |b| {
        b.iter(|| CotanLaplacian::new(black_box(&face)).unwrap())
    });
    let lap = CotanLaplacian::new(&face).unwrap();
    c.bench_function("bilaplacian ICT neutral", |b| b.iter(|| lap.bilaplacian()));

    let mesh = box_tet_mesh([0.0; 3], [1.0; 3], [20, 20, 20]); // 48,000 tets
    c.bench_function("TetLocator::new 48k tets", |b| {
        b.iter(|| TetLocator::new(black_box(&mesh)))
    });
    let loc = TetLocator::new(&mesh);
    let points: Vec<Vector3<f64>> = (0..1000)
        .map(|i| {
            let t = i as f64 * 0.618_033_988_749_895;
            Vector3::new(t.fract() * 1.2 - 0.1, (t * 1.7).fract(), (t * 2.3).fract())
        })
        .collect();
    c.bench_function("TetLocator::locate 1000 points, 48k tets", |b| {
        b.iter(|| {
            points
                .iter()
                .map(|p| loc.locate(p).unwrap().tet)
                .sum::<usize>()
        })
    });
}

criterion_group! {
    name = mesh;
    config = Criterion::default().sample_size(10).measurement_time(std::time::Duration::from_secs(2));
    targets = benches
}
criterion_main!(mesh);
