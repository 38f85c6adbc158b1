//! Capture benches (issue 6): triangulation throughput (points/s) on a synthetic 4-camera ring and
//! on the real 12-camera aniposelib rig (fixtures/aniposelib), per-frame marker detection time for
//! 3 × 1920×1280 images, and `softcap capture calibrate`'s bundle adjustment of the real rig from
//! the 2,998 fixture points (issue 34; aniposelib's `bundle_adjust_iter` on the same points:
//! fixtures/aniposelib/bundle_adjust_reference.toml). Run:
//! `cargo bench -p softcap_capture --bench capture`.

use std::path::PathBuf;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use image::{Rgb, RgbImage};
use softcap_capture::nalgebra::{Matrix3, Point3, Rotation3, Vector2, Vector3};
use softcap_capture::{
    Camera, DetectionSettings, MarkerColor, PixelObservation, TriangulationSettings,
    detect_markers, read_aniposelib_calibration, read_labeled_points, triangulate,
};

fn ring(n: usize) -> Vec<Camera> {
    (0..n)
        .map(|i| {
            let a = i as f64 * std::f64::consts::TAU / n as f64;
            let centre = Vector3::new(0.3 * a.cos(), 0.3 * a.sin(), 0.25);
            let z = (-centre).normalize();
            let x = z.cross(&Vector3::z()).normalize();
            let y = z.cross(&x);
            let r = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
                x.transpose(),
                y.transpose(),
                z.transpose(),
            ]))
            .into_inner();
            Camera::new(
                format!("c{i}"),
                1920,
                1280,
                [2400.0, 2400.0, 959.5, 639.5],
                [-0.05, 0.008, 1e-4, -1e-4, 0.0],
                r,
                -(r * centre),
            )
            .expect("valid camera")
        })
        .collect()
}

/// Deterministic pseudo-random numbers in [−1, 1) (xorshift), so the benches need no RNG crate.
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

fn bench_triangulation(c: &mut Criterion) {
    let mut g = c.benchmark_group("triangulate");
    g.sample_size(10);
    let cams = ring(4);
    let mut noise = Noise(0x9e3779b97f4a7c15);
    let points: Vec<Vec<PixelObservation>> = (0..1000)
        .map(|_| {
            let p = Point3::new(
                0.02 * noise.next(),
                0.02 * noise.next(),
                0.01 * noise.next(),
            );
            (0..cams.len())
                .map(|k| PixelObservation {
                    camera: k,
                    uv: cams[k].project(&p).expect("in front")
                        + Vector2::new(0.3 * noise.next(), 0.3 * noise.next()),
                })
                .collect()
        })
        .collect();
    let fixtures = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/aniposelib");
    let anipose_cams = read_aniposelib_calibration(&fixtures.join("calibration.toml"), 1.0)
        .expect("fixture calibration");
    let anipose_points =
        read_labeled_points(&fixtures.join("points.csv"), &anipose_cams).expect("fixture points");
    for (name, cams, points) in [
        ("ring4_synthetic_1000pts", &cams, &points),
        ("aniposelib12_2998pts", &anipose_cams, &anipose_points),
    ] {
        g.throughput(Throughput::Elements(points.len() as u64));
        for refine in [false, true] {
            let settings = TriangulationSettings {
                refine,
                ..Default::default()
            };
            let label = if refine { "dlt_lm" } else { "dlt" };
            g.bench_function(BenchmarkId::new(label, name), |b| {
                b.iter(|| {
                    points
                        .iter()
                        .filter_map(|o| triangulate(cams, o, &settings))
                        .count()
                })
            });
        }
    }
    g.finish();
}

/// A 1920×1280 frame: textured light background, 60 filled discs (radius 7 px) in three colours.
fn frame(seed: u64) -> RgbImage {
    let (w, h) = (1920u32, 1280u32);
    let mut noise = Noise(seed);
    let mut img = RgbImage::from_fn(w, h, |x, y| {
        let t = (((x / 16) + (y / 16)) % 2) as u8 * 12;
        Rgb([200 - t, 195 - t, 185 - t])
    });
    let colors = [[30u8, 60, 220], [30, 180, 60], [220, 40, 40]];
    for k in 0..60 {
        let cx = (w as f64 / 2.0 + 900.0 * noise.next()) as i64;
        let cy = (h as f64 / 2.0 + 600.0 * noise.next()) as i64;
        for dy in -8i64..=8 {
            for dx in -8i64..=8 {
                if dx * dx + dy * dy <= 49 {
                    let (x, y) = ((cx + dx) as u32, (cy + dy) as u32);
                    if x < w && y < h {
                        img.put_pixel(x, y, Rgb(colors[k % 3]));
                    }
                }
            }
        }
    }
    img
}

fn bench_detection(c: &mut Criterion) {
    let mut g = c.benchmark_group("detect");
    g.sample_size(10);
    let images: Vec<RgbImage> = (1..=3).map(|s| frame(0x51_7cc1_b727_220a + s)).collect();
    let colors = [MarkerColor::Blue, MarkerColor::Green, MarkerColor::Red];
    let settings = DetectionSettings::default();
    let found: usize = images
        .iter()
        .map(|i| detect_markers(i, &colors, &settings).len())
        .sum();
    assert!(
        found >= 150,
        "the bench images must contain detectable markers ({found})"
    );
    g.throughput(Throughput::Elements(1));
    g.bench_function("frame_3x1920x1280", |b| {
        b.iter(|| {
            images
                .iter()
                .map(|i| detect_markers(i, &colors, &settings).len())
                .sum::<usize>()
        })
    });
    g.finish();
}

fn bench_calibration(c: &mut Criterion) {
    use softcap_capture::calibrate::{CalibrateSettings, calibrate, read_calibration_input};
    let mut g = c.benchmark_group("calibrate");
    g.sample_size(10);
    let fixtures = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/aniposelib");
    let input = read_calibration_input(
        &fixtures.join("points.csv"),
        Some(&fixtures.join("calibration.toml")),
    )
    .expect("fixture points and calibration");
    let settings = CalibrateSettings::default();
    g.bench_function("aniposelib12_2998pts", |b| {
        b.iter(|| {
            calibrate(&input, &settings, &mut |_| {})
                .expect("the fixture calibrates")
                .after
                .median_point_error_px
        })
    });
    g.finish();
}

criterion_group!(
    benches,
    bench_triangulation,
    bench_detection,
    bench_calibration
);
criterion_main!(benches);
