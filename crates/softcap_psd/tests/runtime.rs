//! The run-time layout (thesis §5.5.2) against the dense reference synthesis on the ICT face:
//! exactness at full rank, measured error of the block low-rank basis, exact translations.

use softcap_psd::nalgebra::Vector3;
use softcap_psd::*;
use std::path::PathBuf;

struct Case {
    rig: FaceRig,
    model: DetailModel,
    frames: Vec<Vec<Vector3<f64>>>,
}

fn case() -> Case {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/ict-face");
    let data = IctData::load(&dir).expect("fixture loads");
    let rig = FaceRig::new(&data.mesh, &RigSettings::default()).expect("rig builds");
    let settings = EvaluationSettings {
        training_mixtures: 8,
        heldout_mixtures: 6,
        ..Default::default()
    };
    let (training, heldout) = pose_sets(&data, &settings);
    let poses: Vec<_> = training.iter().map(|r| data.pose(r)).collect();
    let examples = rig.examples(&poses).expect("examples");
    // P = 6: rest + five training poses
    let basis = [0, 3, 6, 9, 12, 15];
    let model = fit_wpsd(&examples, &basis, FitMode::Interpolate, &rig.edge_weights).expect("fit");
    let frames = heldout
        .iter()
        .map(|r| rig.handle_positions(&data.pose(r)))
        .collect();
    Case { rig, model, frames }
}

/// Run-time vs dense reference over the frames of a case.
#[derive(Debug)]
struct Errors {
    /// RMS final-position difference (mm; mesh in cm)
    rms: f64,
    /// 99.9th percentile of the per-vertex final-position difference (mm)
    p999: f64,
    /// max final-position difference (mm)
    max: f64,
    /// max large-scale (shell only) position difference (mm)
    large_max: f64,
    /// max over frames of ‖u_H − ū‖₂ (mm): the shell error bound is tolerance × this
    centred_norm: f64,
    /// max angle between final normals (degrees)
    angle: f64,
    /// mean rank of the low-rank basis
    rank: f64,
}

fn compare(c: &Case, tol: f64, reorder: bool) -> Errors {
    let mut anim = Animator::with_settings(
        &c.rig,
        &c.model,
        &RuntimeSettings {
            basis_tolerance: tol,
            reorder,
        },
    )
    .unwrap();
    let (mut sq, mut ang, mut large_max, mut centred_norm) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut all = Vec::new();
    let dist = |a: &[f32; 3], b: &[f32; 3]| -> f64 {
        (0..3)
            .map(|k| ((a[k] - b[k]) as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    for hp in &c.frames {
        anim.frame(hp).unwrap();
        let u: Vec<Vector3<f64>> = c
            .rig
            .handles
            .iter()
            .zip(hp)
            .map(|(&v, p)| p - c.rig.rest[v])
            .collect();
        let mean = u.iter().sum::<Vector3<f64>>() / u.len() as f64;
        let norm2: f64 = u.iter().map(|x| (x - mean).norm_squared()).sum();
        centred_norm = centred_norm.max(10.0 * norm2.sqrt());
        let (x, nrm) = reference_frame(&c.rig, &c.model, hp).unwrap();
        let (large, _) = c.rig.large_scale(hp);
        let fast_large = anim.large_scale_positions();
        for v in 0..x.len() {
            let d = dist(&anim.positions[v], &x[v]);
            sq += d * d;
            all.push(d);
            large_max = large_max.max(dist(&fast_large[v], &large[v]));
            let cs: f64 = (0..3)
                .map(|a| (anim.normals[v][a] * nrm[v][a]) as f64)
                .sum();
            ang = ang.max(cs.clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    all.sort_by(f64::total_cmp);
    let n = all.len();
    Errors {
        rms: 10.0 * (sq / n as f64).sqrt(),
        p999: 10.0 * all[(n * 999 / 1000).min(n - 1)],
        max: 10.0 * all[n - 1],
        large_max: 10.0 * large_max,
        centred_norm,
        angle: ang,
        rank: anim.layout.basis.mean_rank(),
    }
}

fn report(n: usize, tol: f64, e: &Errors) {
    eprintln!(
        "{n} vertices, tolerance {tol:e} (mean rank {:.2}): final rms {:.5} mm, p99.9 {:.4} mm, \
         max {:.4} mm; shell max {:.5} mm (bound {:.5}); normal max {:.2}°",
        e.rank,
        e.rms,
        e.p999,
        e.max,
        e.large_max,
        tol * e.centred_norm,
        e.angle
    );
}

#[test]
fn runtime_layout_matches_dense_reference_and_low_rank_error_is_small() {
    let c = case();
    let n = c.rig.num_vertices();
    let full = compare(&c, 0.0, true);
    report(n, 0.0, &full);
    // full rank: every block keeps min(256, H) singular vectors
    assert!(full.rank > 88.0 && full.rank <= c.rig.handles.len() as f64);
    // f32 summation order only (max at a vertex whose face normals nearly cancel)
    assert!(full.rms < 1e-4 && full.max < 1e-2, "{full:?}");
    assert!(full.angle < 1.0, "{full:?}");
    let mut prev = 0.0;
    for tol in [1e-5, 1e-4, 1e-3] {
        let e = compare(&c, tol, true);
        report(n, tol, &e);
        assert!(e.rms >= prev * 0.999, "error grows as rank is dropped");
        prev = e.rms;
        // the shell error is bounded by tolerance · ‖ũ‖₂ (+ f32 rounding)
        assert!(e.large_max <= tol * e.centred_norm + 1e-3, "{e:?}");
        if tol == 1e-5 {
            // the default: at the f32 level, far below the 0.57 mm WPSD error (docs/psd.md)
            assert!(e.rms < 0.001 && e.max < 0.01, "{e:?}");
        }
    }
}

#[test]
fn low_rank_basis_translates_rigidly() {
    let c = case();
    let t = Vector3::new(0.7, -1.3, 2.1);
    let hp: Vec<_> = c.rig.handles.iter().map(|&v| c.rig.rest[v] + t).collect();
    for tol in [1e-3, 0.2] {
        let settings = RuntimeSettings {
            basis_tolerance: tol,
            ..Default::default()
        };
        let mut anim = Animator::with_settings(&c.rig, &c.model, &settings).unwrap();
        anim.frame(&hp).unwrap();
        for (x, r) in anim.large_scale_positions().iter().zip(&c.rig.rest) {
            for a in 0..3 {
                assert!(
                    (x[a] as f64 - (r[a] + t[a])).abs() < 1e-4,
                    "tolerance {tol}: {x:?} vs {r:?}"
                );
            }
        }
    }
}

/// The ≈592k-vertex benchmark face (ICT 3× midpoint-subdivided): run time vs dense reference.
#[test]
#[ignore = "builds the 592k-vertex face (several minutes); run with --ignored --nocapture"]
fn subdivided_face_runtime_error() {
    let c = case();
    let (rig, model) = subdivide_rig(&c.rig, &c.model, 3, &RigSettings::default().edge_weights);
    let fine = Case {
        rig,
        model,
        frames: c.frames,
    };
    let n = fine.rig.num_vertices();
    for tol in [0.0, 1e-5, 1e-4] {
        let e = compare(&fine, tol, true);
        report(n, tol, &e);
        if tol == 1e-5 {
            // the default
            assert!(e.rms < 0.001 && e.p999 < 0.01 && e.max < 0.1, "{e:?}");
        }
    }
}

/// The locality order (Morton) and the mesh order give the same frame: at full rank up to f32
/// summation order, at the default tolerance within the same bound as the reference.
#[test]
fn locality_order_matches_mesh_order() {
    let c = case();
    for tol in [0.0, 1e-5] {
        let ordered = compare(&c, tol, true);
        let plain = compare(&c, tol, false);
        report(c.rig.num_vertices(), tol, &plain);
        assert!(plain.rms < 1e-3 && plain.max < 1e-2, "{plain:?}");
        assert!(ordered.rms < 1e-3 && ordered.max < 1e-2, "{ordered:?}");
        // Morton blocks are compact patches: the rank does not grow
        assert!(
            ordered.rank <= plain.rank + 1.0,
            "{} vs {}",
            ordered.rank,
            plain.rank
        );
    }
}

/// f64 evaluation of the same stored rig and model (thesis §5.5.2 with eq. 5.3–5.5; dense basis
/// rows, face → vertex normals, local frames, details, final normals), the accuracy yardstick of
/// the f32 paths. Returns positions and unit normals.
fn reference_f64(
    rig: &FaceRig,
    model: &DetailModel,
    hp: &[Vector3<f64>],
) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let n = rig.num_vertices();
    let uh: Vec<Vector3<f64>> = rig
        .handles
        .iter()
        .zip(hp)
        .map(|(&v, p)| p - rig.rest[v])
        .collect();
    let large: Vec<Vector3<f64>> = (0..n)
        .map(|v| {
            let row = rig.basis.row(v);
            rig.rest[v]
                + row
                    .iter()
                    .zip(&uh)
                    .map(|(&w, u)| w as f64 * u)
                    .sum::<Vector3<f64>>()
        })
        .collect();
    let normals = |x: &[Vector3<f64>]| -> Vec<Vector3<f64>> {
        let mut acc = vec![Vector3::zeros(); n];
        for t in &rig.topology.triangles {
            let [a, b, c] = t.map(|v| v as usize);
            let f = (x[b] - x[a]).cross(&(x[c] - x[a]));
            for v in [a, b, c] {
                acc[v] += f;
            }
        }
        acc.into_iter().map(|s| s.normalize()).collect()
    };
    let large_n = normals(&large);
    let f = rig.features(hp);
    let p = model.num_poses();
    let nf = model.num_features;
    let Metric::Weighted(ew) = &model.metric else {
        panic!("WPSD model")
    };
    let x: Vec<Vector3<f64>> = (0..n)
        .map(|v| {
            let nv = large_n[v];
            let e = large[rig.topology.reference_neighbour[v] as usize] - large[v];
            let t = (e - e.dot(&nv) * nv).normalize();
            let b = nv.cross(&t);
            let (ids, al) = ew.row(v);
            let mut d = Vector3::zeros();
            for j in 0..p {
                let c = &model.centers[j * nf..(j + 1) * nf];
                let r2: f64 = ids
                    .iter()
                    .zip(al)
                    .map(|(&i, &a)| a as f64 * (f[i as usize] - c[i as usize]).powi(2))
                    .sum();
                let w = &model.weights[(v * p + j) * 3..(v * p + j) * 3 + 3];
                d += Vector3::new(w[0] as f64, w[1] as f64, w[2] as f64) * r2.sqrt();
            }
            large[v] + d.x * t + d.y * b + d.z * nv
        })
        .collect();
    let nrm = normals(&x);
    (x, nrm)
}

/// (RMS, max) position difference in mm (mesh in cm) and max normal angle in degrees of
/// `got` (in the order `rank`: mesh vertex `v` at `got[rank[v]]`) against the f64 reference.
fn against_f64(
    got: &[[f32; 3]],
    got_n: &[[f32; 3]],
    rank: Option<&[u32]>,
    want: &[Vector3<f64>],
    want_n: &[Vector3<f64>],
    acc: &mut (f64, f64, f64, usize),
) {
    for v in 0..want.len() {
        let k = rank.map_or(v, |r| r[v] as usize);
        let x = Vector3::new(got[k][0] as f64, got[k][1] as f64, got[k][2] as f64);
        let nn = Vector3::new(got_n[k][0] as f64, got_n[k][1] as f64, got_n[k][2] as f64);
        let d = 10.0 * (x - want[v]).norm();
        acc.0 += d * d;
        acc.1 = acc.1.max(d);
        acc.2 = acc
            .2
            .max(nn.dot(&want_n[v]).clamp(-1.0, 1.0).acos().to_degrees());
        acc.3 += 1;
    }
}

/// The f32 run-time path (three passes, block low-rank basis, u8/u16/i16 quantized WPSD data) and
/// the f32 dense reference against an f64 evaluation of the same model, in mesh order and with
/// the rig stored in Morton order (`permute_rig`).
#[test]
fn fast_path_matches_f64_reference() {
    let c = case();
    let order = runtime::morton_order(&c.rig.rest_f32);
    let (prig, pmodel) = permute_rig(&c.rig, &c.model, &order);
    let mut rank = vec![0u32; order.len()];
    for (k, &v) in order.iter().enumerate() {
        rank[v as usize] = k as u32;
    }
    let full = RuntimeSettings {
        basis_tolerance: 0.0,
        ..Default::default()
    };
    let mut fast = Animator::new(&c.rig, &c.model).unwrap();
    let mut fast_full = Animator::with_settings(&c.rig, &c.model, &full).unwrap();
    let mut fast_morton = Animator::new(&prig, &pmodel).unwrap();
    let mut stats = [(0.0, 0.0, 0.0, 0usize); 4];
    for hp in &c.frames {
        let (want, want_n) = reference_f64(&c.rig, &c.model, hp);
        let (x32, n32) = reference_frame(&c.rig, &c.model, hp).unwrap();
        against_f64(&x32, &n32, None, &want, &want_n, &mut stats[0]);
        fast_full.frame(hp).unwrap();
        against_f64(
            &fast_full.positions,
            &fast_full.normals,
            None,
            &want,
            &want_n,
            &mut stats[1],
        );
        fast.frame(hp).unwrap();
        against_f64(
            &fast.positions,
            &fast.normals,
            None,
            &want,
            &want_n,
            &mut stats[2],
        );
        fast_morton.frame(hp).unwrap();
        against_f64(
            &fast_morton.positions,
            &fast_morton.normals,
            Some(&rank),
            &want,
            &want_n,
            &mut stats[3],
        );
    }
    let names = [
        "f32 dense reference",
        "fast path, full rank",
        "fast path, default (mesh order)",
        "fast path, default (Morton-stored rig)",
    ];
    for (name, s) in names.iter().zip(&stats) {
        eprintln!(
            "{name:40} vs f64: rms {:.6} mm, max {:.5} mm, normal max {:.3}°",
            (s.0 / s.3 as f64).sqrt(),
            s.1,
            s.2
        );
    }
    eprintln!(
        "mean rank: mesh order {:.1}, Morton {:.1}",
        fast.layout.basis.mean_rank(),
        fast_morton.layout.basis.mean_rank()
    );
    // stated tolerances (docs/psd.md): f32 rounding and the 1e-5 low-rank tolerance stay
    // ≥ 500× below the 0.57 mm WPSD model error in RMS
    for s in &stats {
        let rms = (s.0 / s.3 as f64).sqrt();
        assert!(rms < 0.001 && s.1 < 0.01, "rms {rms} max {}", s.1);
    }
}
