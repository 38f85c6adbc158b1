//! End-to-end checks on the ICT-FaceKit fixture (9,409 vertices, cm).

use softcap_psd::nalgebra::Vector3;
use softcap_psd::*;
use std::path::PathBuf;
use std::sync::OnceLock;

fn fixture() -> &'static (IctData, FaceRig) {
    static DATA: OnceLock<(IctData, FaceRig)> = OnceLock::new();
    DATA.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/ict-face");
        let data = IctData::load(&dir).expect("fixture loads");
        let rig = FaceRig::new(&data.mesh, &RigSettings::default()).expect("rig builds");
        (data, rig)
    })
}

#[test]
fn rig_has_thesis_sizes_and_shell_interpolates_handles() {
    let (data, rig) = fixture();
    assert_eq!(rig.num_vertices(), 9409);
    assert_eq!(rig.handles.len(), 89);
    assert_eq!(rig.graph.len(), 243);
    let pose = data.expressions.combine(
        &data.mesh.vertices,
        &[(
            data.expressions
                .names
                .iter()
                .position(|n| n == "jawOpen")
                .unwrap(),
            1.0,
        )],
    );
    let hp = rig.handle_positions(&pose);
    let (x, _) = rig.large_scale(&hp);
    for (&v, p) in rig.handles.iter().zip(&hp) {
        for k in 0..3 {
            assert!(
                (x[v][k] as f64 - p[k]).abs() < 1e-4,
                "handle {v} not interpolated"
            );
        }
    }
    // B reproduces rigid translations: rows sum to 1
    for v in (0..rig.num_vertices()).step_by(97) {
        let s: f32 = rig.basis.row(v).iter().sum();
        assert!((s - 1.0).abs() < 1e-4, "row {v} sums to {s}");
    }
}

#[test]
fn wpsd_beats_local_beats_global_blend_shapes_on_heldout_poses() {
    let (data, rig) = fixture();
    let settings = EvaluationSettings {
        training_mixtures: 20,
        heldout_mixtures: 10,
        max_poses: 6,
        blend_iterations: 150,
        ..Default::default()
    };
    let report = evaluate(data, rig, &settings).unwrap();
    let at = |m: &str, p: usize| {
        let c = report.curve(m).unwrap();
        c.heldout_rms_mm[c.basis_sizes.iter().position(|&s| s == p).unwrap()]
    };
    for c in &report.curves {
        eprintln!("{:20} {:?}", c.method, c.heldout_rms_mm);
    }
    eprintln!("large-scale only {:.3} mm", report.large_scale_only_rms_mm);
    let (w, l, g) = (
        at("WPSD LSq", 6),
        at("local blend shapes", 6),
        at("global blend shapes", 6),
    );
    assert!(
        w < l && l < g,
        "WPSD LSq {w:.3} mm, local {l:.3} mm, global {g:.3} mm"
    );
    // details help: WPSD below the shell alone
    assert!(at("WPSD", 6) < report.large_scale_only_rms_mm);
}

#[test]
fn transferred_details_reduce_error_on_other_identities() {
    let (data, rig) = fixture();
    let settings = EvaluationSettings {
        training_mixtures: 10,
        ..Default::default()
    };
    let (training, heldout) = pose_sets(data, &settings);
    let poses: Vec<_> = training.iter().map(|r| data.pose(r)).collect();
    let examples = rig.examples(&poses).unwrap();
    let method = Method::Wpsd(FitMode::LeastSquares, rig.edge_weights.clone());
    let steps = greedy_selection(&examples, &method, 0, 6, |_, _| Ok(())).unwrap();
    let model = method.fit(&examples, &steps.last().unwrap().basis).unwrap();
    let rms = |a: &[[f32; 3]], b: &[Vector3<f64>]| {
        let s: f64 = a
            .iter()
            .zip(b)
            .map(|(x, y)| (Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64) - y).norm_squared())
            .sum();
        (s / a.len() as f64).sqrt()
    };
    for k in 0..data.identities.names.len() {
        let rest = data.identities.combine(&data.mesh.vertices, &[(k, 1.0)]);
        let mesh = softcap_mesh::TriMesh {
            vertices: rest.clone(),
            triangles: data.mesh.triangles.clone(),
        };
        let target = FaceRig::with_handles(
            &mesh,
            rig.handles.clone(),
            Some(&rig.graph),
            &RigSettings::default(),
        )
        .unwrap();
        let tmodel =
            transfer_details(&model, &target, &identity_correspondence(rest.len())).unwrap();
        let mut anim = Animator::new(&target, &tmodel).unwrap();
        let (mut with, mut without) = (0.0, 0.0);
        for r in heldout.iter().take(5) {
            let truth = data.expressions.combine(&rest, &r.weights);
            let hp = target.handle_positions(&truth);
            anim.frame(&hp).unwrap();
            with += rms(&anim.positions, &truth);
            without += rms(&target.large_scale(&hp).0, &truth);
        }
        eprintln!(
            "{}: large-scale {without:.4}, transferred {with:.4} (cm, sum of 5)",
            data.identities.names[k]
        );
        assert!(
            with < 0.8 * without,
            "identity {k}: transferred {with} vs shell only {without}"
        );
    }
}
