//! Thesis §3.3.2 wrinkle removal: a curved skin patch (cm) with fine-scale detail carries a
//! known, compactly supported wrinkle; removal must bring it back to the wrinkle-free surface
//! (detail included) inside the region and leave everything outside untouched.

use softcap_face::nalgebra::Vector3;
use softcap_face::{RemovalSettings, remove_wrinkles, wrinkle_profile};
use softcap_mesh::TriMesh;

const H: f64 = 0.025;
const N: usize = 61;

/// Smooth cut-off: 1 for |t| ≤ a, 0 for |t| ≥ b, C¹ in between.
fn window(t: f64, a: f64, b: f64) -> f64 {
    let t = t.abs();
    if t <= a {
        1.0
    } else if t >= b {
        0.0
    } else {
        0.5 * (1.0 + (std::f64::consts::PI * (t - a) / (b - a)).cos())
    }
}

struct Outcome {
    max_in: f64,
    rms_in: f64,
    rms_wr: f64,
    max_out: f64,
    detail_gain: f64,
}

/// Remove a wrinkle of depth `d`, width `w` whose valley is rounded over `round_cm`
/// (S evaluated at √(p² + round²)); `round_cm = 0` is the sharp-kinked S of §4.3.2.
fn run(d: f64, w: f64, round_cm: f64) -> Outcome {
    let y0 = 0.0;
    let c = (N - 1) as f64 * H / 2.0;
    let base = |x: f64, y: f64| 0.15 * x * x - 0.08 * y * y + 0.05 * x * y;
    // pore-scale detail: ±10 µm checkerboard
    let detail = |i: usize, j: usize| {
        if (i + j).is_multiple_of(2) {
            0.001
        } else {
            -0.001
        }
    };
    let wrinkle = |x: f64, y: f64| {
        wrinkle_profile(w, d, ((y - y0).powi(2) + round_cm * round_cm).sqrt())
            * window(x, 0.25, 0.45)
            * window(y - y0, 0.3, 0.5)
    };
    let mut clean = Vec::new();
    let mut scan = Vec::new();
    let mut region = Vec::new();
    for j in 0..N {
        for i in 0..N {
            let (x, y) = (i as f64 * H - c, j as f64 * H - c);
            let z = base(x, y) + detail(i, j);
            clean.push(Vector3::new(x, y, z));
            scan.push(Vector3::new(x, y, z + wrinkle(x, y)));
            if x.abs() <= 0.55 && (y - y0).abs() <= 0.6 {
                region.push(j * N + i);
            }
        }
    }
    let mut triangles = Vec::new();
    for j in 0..N - 1 {
        for i in 0..N - 1 {
            let v = j * N + i;
            triangles.push([v, v + 1, v + N + 1]);
            triangles.push([v, v + N + 1, v + N]);
        }
    }
    let mesh = TriMesh {
        vertices: scan.clone(),
        triangles,
    };
    let out = remove_wrinkles(&mesh, &region, &RemovalSettings::default()).unwrap();
    let in_region: std::collections::BTreeSet<usize> = region.iter().copied().collect();
    let (mut max_in, mut sq_in, mut max_wr, mut sq_wr, mut max_out) =
        (0.0f64, 0.0, 0.0f64, 0.0, 0.0f64);
    let mut detail_dot = 0.0;
    let mut detail_sq = 0.0;
    for v in 0..N * N {
        let e = (out[v] - clean[v]).norm();
        let ew = (scan[v] - clean[v]).norm();
        if in_region.contains(&v) {
            max_in = max_in.max(e);
            sq_in += e * e;
            max_wr = max_wr.max(ew);
            sq_wr += ew * ew;
            // detail kept: correlate the result's residual over the smooth base with the detail
            let (i, j) = (v % N, v / N);
            let r = out[v].z - base(out[v].x, out[v].y);
            detail_dot += r * detail(i, j);
            detail_sq += detail(i, j) * detail(i, j);
        } else {
            max_out = max_out.max(e);
        }
    }
    let nr = region.len() as f64;
    Outcome {
        max_in,
        rms_in: (sq_in / nr).sqrt(),
        rms_wr: (sq_wr / nr).sqrt(),
        max_out,
        detail_gain: detail_dot / detail_sq,
    }
}

#[test]
fn removal_restores_wrinkle_free_surface_and_keeps_detail() {
    let d = 0.05;
    for (round_cm, label) in [(0.0, "sharp valley"), (2.0 * H, "valley rounded over 2h")] {
        let o = run(d, 0.15, round_cm);
        println!(
            "{label}: scan vs clean rms {:.4} cm; after removal max {:.5} cm ({:.1} % of d), \
             rms {:.5} cm; outside max {:.1e} cm; detail amplitude kept {:.1} %",
            o.rms_wr,
            o.max_in,
            100.0 * o.max_in / d,
            o.rms_in,
            o.max_out,
            100.0 * o.detail_gain
        );
        assert!(o.max_out < 1e-12, "outside must be untouched");
        assert!(o.rms_in < 0.25 * o.rms_wr);
        assert!(o.detail_gain > 0.8 && o.detail_gain < 1.2);
        if round_cm > 0.0 {
            assert!(
                o.max_in < 0.10 * d,
                "max error {} cm ≥ 10 % of d = {d}",
                o.max_in
            );
        }
    }
}
