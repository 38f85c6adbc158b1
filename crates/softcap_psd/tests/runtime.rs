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

/// (RMS, max) position difference in mm (mesh in cm) and max normal angle in degrees.
fn compare(c: &Case, tol: f64) -> (f64, f64, f64, f64) {
    let mut anim = Animator::with_settings(
        &c.rig,
        &c.model,
        &RuntimeSettings {
            basis_tolerance: tol,
        },
    )
    .unwrap();
    let (mut sq, mut mx, mut ang, mut cnt) = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for hp in &c.frames {
        anim.frame(hp).unwrap();
        let (x, nrm) = reference_frame(&c.rig, &c.model, hp).unwrap();
        for v in 0..x.len() {
            let d2: f64 = (0..3)
                .map(|a| ((anim.positions[v][a] - x[v][a]) as f64).powi(2))
                .sum();
            sq += d2;
            mx = mx.max(d2.sqrt());
            let cs: f64 = (0..3)
                .map(|a| (anim.normals[v][a] * nrm[v][a]) as f64)
                .sum();
            ang = ang.max(cs.clamp(-1.0, 1.0).acos().to_degrees());
            cnt += 1;
        }
    }
    (
        10.0 * (sq / cnt as f64).sqrt(),
        10.0 * mx,
        ang,
        anim.layout.basis.mean_rank(),
    )
}

#[test]
fn runtime_layout_matches_dense_reference_and_low_rank_error_is_small() {
    let c = case();
    let dense = compare(&c, 0.0);
    eprintln!(
        "full rank ({:.1}): rms {:.2e} mm, max {:.2e} mm, normal {:.3}°",
        dense.3, dense.0, dense.1, dense.2
    );
    // full rank: every block keeps min(256, H) singular vectors
    assert!(dense.3 > 88.0 && dense.3 <= c.rig.handles.len() as f64);
    // f32 summation order only (max at a vertex whose face normals nearly cancel)
    assert!(dense.0 < 1e-4 && dense.1 < 1e-2, "{dense:?}");
    assert!(dense.2 < 1.0, "{dense:?}");
    let mut prev = 0.0;
    for tol in [1e-4, 1e-3, 1e-2] {
        let e = compare(&c, tol);
        eprintln!(
            "tolerance {tol:e} (mean rank {:.1}): rms {:.4} mm, max {:.4} mm, normal {:.3}°",
            e.3, e.0, e.1, e.2
        );
        assert!(e.0 >= prev * 0.999, "error grows as rank is dropped");
        prev = e.0;
        if tol == 1e-3 {
            // the default: far below the 0.57 mm WPSD error itself (docs/psd.md)
            assert!(e.0 < 0.05 && e.1 < 0.5, "{e:?}");
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
#[ignore = "builds the 592k-vertex face (≈1 min); run with --ignored --nocapture"]
fn subdivided_face_runtime_error() {
    let c = case();
    let (rig, model) = subdivide_rig(&c.rig, &c.model, 3, &RigSettings::default().edge_weights);
    let fine = Case {
        rig,
        model,
        frames: c.frames,
    };
    for tol in [1e-4, 1e-3, 1e-2] {
        let e = compare(&fine, tol);
        eprintln!(
            "{} vertices, tolerance {tol:e} (mean rank {:.2}): rms {:.4} mm, max {:.4} mm, normal {:.2}°",
            fine.rig.num_vertices(),
            e.3,
            e.0,
            e.1,
            e.2
        );
        if tol == 1e-3 {
            assert!(e.0 < 0.05 && e.1 < 0.5, "{e:?}");
        }
    }
}
