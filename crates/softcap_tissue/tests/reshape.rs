//! saito-barbic reshaping against known ground truth (paper Fig. 21).

use softcap_fem::nalgebra::{Isometry3, Vector3};
use softcap_mesh::TetLocator;
use softcap_tissue::reshape::gauge::best_rigid;
use softcap_tissue::reshape::known_truth::{self, moved, problem, truth};
use softcap_tissue::reshape::{
    ConstraintKind, CrossValidationSettings, HoldOut, Landmark, MaterialPoint, ReshapeOutcome,
    ReshapeProblem, ReshapeSettings, ReshapeStatus, Smoothness, StopReason, SurfaceProjector,
    reshape, write_target,
};

/// (mean, 95th percentile, max) of `v`.
fn stats(v: &mut [f64]) -> (f64, f64, f64) {
    v.sort_by(f64::total_cmp);
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    (
        mean,
        v[(0.95 * (v.len() - 1) as f64).round() as usize],
        v[v.len() - 1],
    )
}

/// saito-barbic Fig. 21: the template deformed by a known plastic field (the stretch of the
/// smooth map `truth`, 1×–2× and anisotropic, per tet: its stress-free equilibrium is the map)
/// is recovered from 12 landmarks, 150 ICP markers and the attachments of one face. Shape error:
/// distance from 400 held-out points of the true surface to the reshaped surface; correspondence
/// error: where each held-out template point went vs where the truth sends it.
/// (shape, correspondence, ICP-marker) error statistics of `out` against the map `truth`.
fn evaluate(
    p: &ReshapeProblem,
    out: &ReshapeOutcome,
    held_out: &[Vector3<f64>],
    truth: fn(&Vector3<f64>) -> Vector3<f64>,
) -> [(f64, f64, f64); 3] {
    let faces = p.template.boundary_faces();
    let surface = SurfaceProjector::new(&faces, &out.positions_m);
    let mut shape: Vec<f64> = held_out
        .iter()
        .map(|h| surface.project(&truth(h)).unwrap().1)
        .collect();
    let locator = TetLocator::new(&p.template);
    let mut correspondence: Vec<f64> = held_out
        .iter()
        .map(|h| {
            let e = locator.locate(h).unwrap();
            (e.position(&p.template.tets, &out.positions_m) - truth(h)).norm()
        })
        .collect();
    let mut icp = out.errors_of(ConstraintKind::Icp);
    let [s, c, i] = [
        stats(&mut shape),
        stats(&mut correspondence),
        stats(&mut icp),
    ];
    eprintln!(
        "{:?}\nshape (mean / p95 / max) {}; correspondence {}; ICP markers {}; {:?}",
        out.stages,
        mm(s),
        mm(c),
        mm(i),
        out.reshaped_quality
    );
    [s, c, i]
}

fn mm(t: (f64, f64, f64)) -> String {
    format!("{:.3} / {:.3} / {:.3} mm", t.0 * 1e3, t.1 * 1e3, t.2 * 1e3)
}

/// saito-barbic Fig. 21: the template deformed by a known plastic field (the stretch of the
/// smooth map `truth`, 1×–2× and anisotropic, per tet: its stress-free equilibrium is the map)
/// is recovered from 12 landmarks, 150 ICP markers and the attachments of one face. Shape error:
/// distance from 400 held-out points of the true surface to the reshaped surface; correspondence
/// error: where each held-out template point went vs where the truth sends it.
/// The bar: shape error ≤ 0.5 mm at the 95th percentile (measured 0.065 / 0.236 / 0.559
/// mm mean / p95 / max; the piecewise-linear interpolant of the truth itself is 0.030 / 0.091 /
/// 0.109 mm), every ICP marker and landmark met to ≤ 0.5 mm.
#[test]
fn recovers_a_known_anisotropic_plastic_deformation() {
    let (p, held_out) = problem(false);
    let out = reshape(&p, &ReshapeSettings::default(), &mut |_, _, _, _| {}).unwrap();
    let [s, c, i] = evaluate(&p, &out, &held_out, truth);
    assert!(s.1 <= 0.5e-3 && s.2 < 1.0e-3, "shape error {}", mm(s));
    assert!(c.0 < 1.0e-3, "correspondence error {}", mm(c));
    assert!(i.2 <= 0.5e-3, "ICP error {}", mm(i));
    let landmarks = stats(&mut out.errors_of(ConstraintKind::Landmark));
    assert!(landmarks.2 <= 0.5e-3, "landmark error {}", mm(landmarks));
    assert_eq!(out.reshaped_quality.inverted_tets, 0);
    assert_stopping_rules(&out, &ReshapeSettings::default());
}

/// The schedule and stopping rules of §3.4 on a finished reshape: the stages in order (constant
/// guess → attachments → + landmarks → ICP), the history in the same order with one record per
/// iteration, and each stage's stop justified by its records — (i) the iteration cap reached,
/// (ii) the largest image-constraint error within the tolerance, (iii) the last iteration lowering
/// the objective by less than the relative threshold; the status converged.
fn assert_stopping_rules(out: &ReshapeOutcome, settings: &ReshapeSettings) {
    let names: Vec<&str> = out.stages.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["constant", "attachments", "landmarks", "icp"]);
    let mut history = out.history.iter();
    for stage in &out.stages {
        let records: Vec<_> = history.by_ref().take(stage.iterations).collect();
        assert!(
            records.len() == stage.iterations && records.iter().all(|r| r.stage == stage.name),
            "{stage:?}: history out of order"
        );
        let cap = if stage.name == "constant" {
            settings.constant_iterations
        } else {
            settings.max_iterations
        };
        match stage.stop {
            StopReason::MaxIterations => assert_eq!(stage.iterations, cap, "{stage:?}"),
            StopReason::ErrorTolerance => {
                assert!(stage.max_error_m <= settings.error_tolerance_m, "{stage:?}")
            }
            StopReason::SmallProgress => {
                let last = records.last().expect("an iteration").objective;
                let before = records
                    .len()
                    .checked_sub(2)
                    .map_or(stage.objective_start, |k| records[k].objective);
                let decrease = (before - last) / before;
                assert!(
                    decrease < settings.relative_progress && stage.iterations < cap,
                    "{stage:?}: last decrease {decrease}"
                );
            }
            StopReason::NoDescent => panic!("{stage:?}: no descent on the known truth"),
        }
    }
    assert!(history.next().is_none(), "history longer than the stages");
    assert_eq!(out.status, ReshapeStatus::Converged);
}

/// saito-barbic §3.6: the same targets moved rigidly (29°, 3 cm) and no attachments (free-flying:
/// rigid gauge, block-coordinate rigid steps, then joint shape-and-pose steps), default settings.
/// Compared with the attached case by the same two measures "up to a rigid motion": the held-out
/// points' distance to the surface after the rigid motion that minimizes it (`surface_aligned`)
/// and after the best rigid motion of all nodes onto the truth's (`node_aligned`, which also
/// charges material sliding along the surface).
///
/// (a) The free-flying problem with the same information — the attached face's 24 nodes as
/// landmarks at their (moved) targets instead of springs — converges to the attached case's shape:
/// measured p95 surface-aligned 0.225 vs 0.217 mm, node-aligned 0.511 vs 0.526 mm (bar 1.25×).
/// (b) Without them (12 landmarks, 150 markers; the x = 0 end known from markers alone) it
/// converges too (11 ICP iterations), measured world frame 0.104 / 0.420 / 1.022 mm, node-aligned
/// p95 0.668 mm (1.27× the attached case's), surface-aligned 0.375 mm: less data, a shape further
/// from the truth, asserted against the 0.5 mm.
#[test]
fn free_flying_reshape_recovers_the_shape_up_to_a_rigid_motion() {
    let settings = ReshapeSettings::default();
    let (attached_problem, held_out) = problem(false);
    let attached = reshape(&attached_problem, &settings, &mut |_, _, _, _| {}).unwrap();
    let attached_fit = up_to_a_rigid_motion(&attached_problem, &attached, &held_out, truth);
    eprintln!("attached: {attached_fit}");
    // (a) The same information without attachments.
    let (mut p, _) = problem(true);
    p.landmarks
        .extend(attached_problem.attachments.iter().map(|a| Landmark {
            id: format!("attachment {}", a.id),
            point: MaterialPoint::node(a.node),
            target_m: moved(&attached_problem.template.vertices[a.node]),
        }));
    let same = reshape(&p, &settings, &mut |_, _, _, _| {}).unwrap();
    let same_fit = up_to_a_rigid_motion(&p, &same, &held_out, moved);
    eprintln!(
        "free-flying, same information: {:?}, {same_fit}",
        same.status
    );
    assert_eq!(same.status, ReshapeStatus::Converged);
    assert!(
        same_fit.surface_aligned.1 <= 1.25 * attached_fit.surface_aligned.1
            && same_fit.node_aligned.1 <= 1.25 * attached_fit.node_aligned.1,
        "free-flying {same_fit} vs attached {attached_fit}"
    );
    assert_eq!(same.reshaped_quality.inverted_tets, 0);
    // (b) Landmarks and markers only.
    let (p, _) = problem(true);
    let out = reshape(&p, &settings, &mut |_, _, _, _| {}).unwrap();
    let [s, _, i] = evaluate(&p, &out, &held_out, moved);
    let fit = up_to_a_rigid_motion(&p, &out, &held_out, moved);
    eprintln!(
        "free-flying: {:?} ({} iterations), world frame {}, {fit}",
        out.status,
        out.history.len(),
        mm(s)
    );
    assert_eq!(out.status, ReshapeStatus::Converged);
    assert!(s.0 < 0.2e-3 && s.1 < 0.5e-3, "shape error {}", mm(s));
    assert!(i.2 <= 0.5e-3, "ICP error {}", mm(i));
    let landmarks = stats(&mut out.errors_of(ConstraintKind::Landmark));
    assert!(landmarks.2 <= 0.5e-3, "landmark error {}", mm(landmarks));
    assert_eq!(out.reshaped_quality.inverted_tets, 0);
}

/// Held-out shape error statistics up to a rigid motion (see the free-flying test).
struct RigidFit {
    surface_aligned: (f64, f64, f64),
    node_aligned: (f64, f64, f64),
    node_residual: (f64, f64, f64),
}

impl std::fmt::Display for RigidFit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "surface-aligned shape {}, node-aligned shape {} (node residual {})",
            mm(self.surface_aligned),
            mm(self.node_aligned),
            mm(self.node_residual)
        )
    }
}

/// The held-out points' distance to the reshaped surface (i) after the rigid motion minimizing
/// it (rigid ICP: Horn 1987 on the closest points, 40 rounds), (ii) after the best rigid motion
/// of the reshaped nodes onto the truth's (Horn), and the node residuals of (ii).
fn up_to_a_rigid_motion(
    p: &ReshapeProblem,
    out: &ReshapeOutcome,
    held_out: &[Vector3<f64>],
    map: fn(&Vector3<f64>) -> Vector3<f64>,
) -> RigidFit {
    let faces = p.template.boundary_faces();
    let targets: Vec<Vector3<f64>> = held_out.iter().map(map).collect();
    let moved_by = |t: &Isometry3<f64>| -> Vec<Vector3<f64>> {
        out.positions_m
            .iter()
            .map(|x| t.transform_point(&(*x).into()).coords)
            .collect()
    };
    let distances = |x: &[Vector3<f64>]| -> Vec<f64> {
        let surface = SurfaceProjector::new(&faces, x);
        targets
            .iter()
            .map(|h| surface.project(h).unwrap().1)
            .collect()
    };
    let mut motion = Isometry3::identity();
    for _ in 0..40 {
        let x = moved_by(&motion);
        let surface = SurfaceProjector::new(&faces, &x);
        let closest: Vec<Vector3<f64>> = targets
            .iter()
            .map(|h| surface.project(h).unwrap().0.at(&x))
            .collect();
        motion = best_rigid(&closest, &targets, &vec![1.0; targets.len()]).unwrap() * motion;
    }
    let truth_nodes: Vec<Vector3<f64>> = p.template.vertices.iter().map(map).collect();
    let align = best_rigid(
        &out.positions_m,
        &truth_nodes,
        &vec![1.0; truth_nodes.len()],
    )
    .unwrap();
    let aligned = moved_by(&align);
    let mut nodes: Vec<f64> = aligned
        .iter()
        .zip(&truth_nodes)
        .map(|(a, t)| (a - t).norm())
        .collect();
    RigidFit {
        surface_aligned: stats(&mut distances(&moved_by(&motion))),
        node_aligned: stats(&mut distances(&aligned)),
        node_residual: stats(&mut nodes),
    }
}

/// `softcap-tissue reshape` end to end with a two-iteration budget and α̂ cross-validated (two
/// folds of the attachments and landmarks, the one-standard-error rule): exit 0, the iteration cap
/// is reported as status `max-iterations`; reshaped.mcap holds the mesh, every constraint, the
/// plastic strains, the mesh quality and the report (status, how α̂ was chosen); `--report`
/// writes report.md and its three figures (the Fig. 16 error histogram, the Fig. 9 convergence,
/// the before/after renders). A landmark outside the template is exit 2 naming landmarks.csv and
/// its line, nothing written.
#[test]
fn cli_reshapes_a_target_folder_with_its_report_and_rejects_a_landmark_outside_the_template() {
    let (p, _) = problem(false);
    let dir = tempfile::tempdir().unwrap();
    write_target(dir.path(), &p, "mm").unwrap();
    let settings = dir.path().join("reshape.toml");
    std::fs::write(
        &settings,
        "max_iterations = 2\nconstant_iterations = 2\nsmoothness = \"cv\"\n\
         cross_validation = { folds = 2, grid = [3e-4, 3e-2], hold_out = \"correspondence\", \
         rule = \"one-standard-error\" }\n",
    )
    .unwrap();
    let out = dir.path().join("reshaped.mcap");
    let report = dir.path().join("report");
    let bin = env!("CARGO_BIN_EXE_softcap-tissue");
    let run = |target: &str, output: &std::path::Path| {
        std::process::Command::new(bin)
            .arg("reshape")
            .arg("--template")
            .arg(dir.path().join("template.msh"))
            .arg("--target")
            .arg(dir.path().join(target))
            .arg("-o")
            .arg(output)
            .arg("--settings")
            .arg(&settings)
            .arg("--report")
            .arg(&report)
            .arg("--quiet")
            .output()
            .unwrap()
    };
    let ok = run("target", &out);
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    assert!(stdout.starts_with("max-iterations"), "{stdout}");
    let r = softcap_mcap::Recording::open(&out).unwrap();
    let volume = r.read_static(&softcap_mcap::topics::VOLUME_MESH).unwrap();
    assert_eq!(volume.positions_m.len(), 3 * p.template.vertices.len());
    let constraints = r
        .read_static(&softcap_mcap::topics::RESHAPE_CONSTRAINTS)
        .unwrap();
    assert_eq!(
        constraints.constraints.len(),
        p.attachments.len() + p.landmarks.len() + p.icp_markers.len()
    );
    let strains = r
        .read_static(&softcap_mcap::topics::PLASTIC_STRAINS)
        .unwrap();
    assert_eq!(strains.strains.len(), 6 * p.template.tets.len());
    let quality = r
        .read_static(&softcap_mcap::topics::RESHAPE_QUALITY)
        .unwrap();
    let reshaped = quality.reshaped.unwrap();
    assert!(reshaped.min_dihedral_deg > 0.0 && reshaped.max_dihedral_deg < 180.0);
    assert!(quality.template.unwrap().max_aspect_ratio >= 1.0);
    let entries = r
        .read_static(&softcap_mcap::topics::RESHAPE_REPORT)
        .unwrap()
        .entries;
    let text_of = |key: &str| {
        entries
            .iter()
            .find(|e| e.key == key)
            .and_then(|e| match &e.value {
                Some(softcap_mcap::proto::key_value::Value::Text(t)) => Some(t.clone()),
                _ => None,
            })
            .unwrap_or_else(|| panic!("no text entry {key}"))
    };
    assert_eq!(text_of("status"), "max-iterations");
    assert_eq!(text_of("cv.hold_out"), "correspondence");
    assert_eq!(text_of("cv.rule"), "one-standard-error");
    let md = std::fs::read_to_string(report.join("report.md")).unwrap();
    for needle in [
        "Status **max-iterations**",
        "2-fold cross-validation holding out the attachments and landmarks",
        "one-standard-error rule",
        "| landmark | 12 |",
        "| icp | 150 |",
        "| reshaped |",
        "![constraint errors](constraint_errors.png)",
        "![before and after](before_after.png)",
    ] {
        assert!(md.contains(needle), "`{needle}` not in report.md:\n{md}");
    }
    // The figures are PNG files of their drawing sizes (IHDR width and height).
    for (file, width) in [
        ("constraint_errors.png", 800),
        ("convergence.png", 800),
        ("before_after.png", 0),
    ] {
        let png = std::fs::read(report.join(file)).unwrap();
        assert!(
            png.starts_with(b"\x89PNG\r\n\x1a\n") && &png[12..16] == b"IHDR",
            "{file}"
        );
        let w = u32::from_be_bytes(png[16..20].try_into().unwrap());
        let h = u32::from_be_bytes(png[20..24].try_into().unwrap());
        assert!(
            w > 0 && h > 0 && (width == 0 || w == width),
            "{file}: {w} × {h}"
        );
    }
    // A landmark 1 m outside the template on line 3.
    let bad = dir.path().join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    for f in ["target.toml", "icp_markers.csv", "attachments.csv"] {
        std::fs::copy(dir.path().join("target").join(f), bad.join(f)).unwrap();
    }
    let text = std::fs::read_to_string(dir.path().join("target/landmarks.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    lines[2] = "far,1000,0,0,0,0,0".into();
    std::fs::write(bad.join("landmarks.csv"), lines.join("\n") + "\n").unwrap();
    let bad_out = dir.path().join("bad.mcap");
    let failed = run("bad", &bad_out);
    let stderr = String::from_utf8_lossy(&failed.stderr);
    assert_eq!(failed.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("landmarks.csv:3"), "{stderr}");
    assert!(!bad_out.exists());
}

/// target.toml may only name files inside TARGET: an absolute path, a `..` escape and a symlink
/// out of the folder are each a bad-input error naming target.toml and the key.
#[test]
fn target_files_outside_the_folder_are_refused() {
    let (p, _) = problem(false);
    let dir = tempfile::tempdir().unwrap();
    write_target(dir.path(), &p, "mm").unwrap();
    let target = dir.path().join("target");
    let toml = target.join("target.toml");
    let original = std::fs::read_to_string(&toml).unwrap();
    let outside = dir.path().join("landmarks.csv");
    std::fs::copy(target.join("landmarks.csv"), &outside).unwrap();
    let template = dir.path().join("template.msh");
    let refused = |name: &str, needle: &str| {
        std::fs::write(&toml, format!("{original}landmarks = {name:?}\n")).unwrap();
        let e = softcap_tissue::reshape::load_target(&template, &target).unwrap_err();
        let m = e.to_string();
        assert!(e.is_bad_input(), "{m}");
        for n in ["target.toml", "landmarks", needle] {
            assert!(m.contains(n), "`{n}` not in: {m}");
        }
    };
    refused(&outside.display().to_string(), "absolute");
    refused("../landmarks.csv", "leaves the folder");
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(dir.path(), target.join("up")).unwrap();
        refused("up/landmarks.csv", "symlink");
    }
    std::fs::write(
        &toml,
        format!("{original}landmarks = \"./landmarks.csv\"\n"),
    )
    .unwrap();
    softcap_tissue::reshape::load_target(&template, &target).unwrap();
}

/// Bad input names the file and the line: a non-manifold `surface.obj` (an edge shared by three
/// faces) and a template whose unit disagrees with TARGET's (`template_length_unit = "m"` for a
/// template written in mm: the targets span 1/1000 of the template) are each a bad-input error.
#[test]
fn a_non_manifold_surface_and_inconsistent_units_are_refused_naming_file_and_line() {
    let (p, _) = problem(false);
    let dir = tempfile::tempdir().unwrap();
    write_target(dir.path(), &p, "mm").unwrap();
    let target = dir.path().join("target");
    let template = dir.path().join("template.msh");
    let toml = target.join("target.toml");
    let original = std::fs::read_to_string(&toml).unwrap();
    let expect = |needles: &[&str]| {
        let e = softcap_tissue::reshape::load_target(&template, &target).unwrap_err();
        let m = e.to_string();
        assert!(e.is_bad_input(), "{m}");
        for n in needles {
            assert!(m.contains(n), "`{n}` not in: {m}");
        }
    };
    // Three triangles on the edge (1, 2): the third face, on line 9, makes it non-manifold.
    std::fs::write(
        target.join("surface.obj"),
        "# fan\nv 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 -10 0\nv 0 0 10\nf 1 2 3\nf 2 1 4\nf 1 2 5\n",
    )
    .unwrap();
    std::fs::write(&toml, format!("{original}surface = \"surface.obj\"\n")).unwrap();
    expect(&["surface.obj:9", "non-manifold"]);
    std::fs::write(&toml, format!("{original}template_length_unit = \"m\"\n")).unwrap();
    expect(&["target.toml:1", "inconsistent units"]);
}

/// `icp_surface` names the part of the boundary the markers lie on; a triangle with a node the
/// template does not have is refused before any solve.
#[test]
fn an_icp_surface_outside_the_template_is_refused() {
    let (mut p, _) = problem(false);
    let n = p.template.vertices.len();
    p.icp_surface = Some(vec![[0, 1, n]]);
    let err = reshape(&p, &ReshapeSettings::default(), &mut |_, _, _, _| {}).expect_err("refused");
    assert!(err.to_string().contains("icp_surface"), "{err}");
}

/// `icp_surface = "icp_surface.csv"` in target.toml gives the problem the same ICP surface that
/// was written (the template's z = 0.04 face, oriented as its boundary); a triangle inside the
/// template (not on its boundary) and a node the template does not have are each refused naming
/// icp_surface.csv and the line.
#[test]
fn icp_surface_is_read_from_the_target_folder() {
    let (mut p, _) = problem(false);
    let top: Vec<[usize; 3]> = p
        .template
        .boundary_faces()
        .into_iter()
        .filter(|f| {
            f.iter()
                .all(|&v| (p.template.vertices[v].z - 0.04).abs() < 1e-12)
        })
        .collect();
    assert!(top.len() > 10);
    p.icp_surface = Some(top.clone());
    let dir = tempfile::tempdir().unwrap();
    write_target(dir.path(), &p, "mm").unwrap();
    let template = dir.path().join("template.msh");
    let target = dir.path().join("target");
    let loaded = softcap_tissue::reshape::load_target(&template, &target).unwrap();
    assert_eq!(loaded.problem.icp_surface, Some(top));
    let csv = target.join("icp_surface.csv");
    let expect = |row: &str, needle: &str| {
        std::fs::write(&csv, format!("a,b,c\n{row}\n")).unwrap();
        let e = softcap_tissue::reshape::load_target(&template, &target).unwrap_err();
        let m = e.to_string();
        assert!(e.is_bad_input(), "{m}");
        for n in ["icp_surface.csv:2", needle] {
            assert!(m.contains(n), "`{n}` not in: {m}");
        }
    };
    // A face of a tet that is not on the boundary.
    let boundary: std::collections::BTreeSet<[usize; 3]> = p
        .template
        .boundary_faces()
        .into_iter()
        .map(|mut f| {
            f.sort_unstable();
            f
        })
        .collect();
    let inner = p
        .template
        .tets
        .iter()
        .flat_map(|t| [[t[0], t[1], t[2]], [t[1], t[2], t[3]]])
        .find(|f| {
            let mut k = *f;
            k.sort_unstable();
            !boundary.contains(&k)
        })
        .unwrap();
    expect(
        &format!("{},{},{}", inner[0], inner[1], inner[2]),
        "not a boundary triangle",
    );
    expect("0,1,99999", "not a node");
}

/// The cross-validation case: the known-truth box on 288 tets, its ICP markers 0.3 mm off the
/// surface (deterministic pseudo-random directions), the grid 3e-6, 3e-4, 3e-2 and 3-fold
/// cross-validation holding out `hold_out`.
fn noisy_box(hold_out: HoldOut) -> (ReshapeProblem, Vec<Vector3<f64>>, Vec<f64>, ReshapeSettings) {
    let (mut p, held_out) = known_truth::problem_with_cells(false, [6, 4, 2]);
    for (i, m) in p.icp_markers.iter_mut().enumerate() {
        let u = |k: usize| ((((3 * i + k) as f64) * 12.9898).sin() * 43758.5453).fract();
        m.position_m += Vector3::new(u(0), u(1), u(2)).normalize() * 0.3e-3;
    }
    let grid = vec![3e-6, 3e-4, 3e-2];
    let settings = ReshapeSettings {
        smoothness: Smoothness::CrossValidated,
        cross_validation: CrossValidationSettings {
            folds: 3,
            grid: grid.clone(),
            hold_out,
            ..CrossValidationSettings::default()
        },
        ..ReshapeSettings::default()
    };
    (p, held_out, grid, settings)
}

/// The truth's error of the reshape at each fixed α̂ of `grid` (what cross-validation must match).
fn errors_at_fixed_smoothness(
    p: &ReshapeProblem,
    grid: &[f64],
    error: impl Fn(&[Vector3<f64>]) -> f64,
) -> Vec<f64> {
    grid.iter()
        .map(|&a| {
            let fixed = ReshapeSettings {
                smoothness: Smoothness::Fixed(a),
                ..ReshapeSettings::default()
            };
            error(
                &reshape(p, &fixed, &mut |_, _, _, _| {})
                    .unwrap()
                    .positions_m,
            )
        })
        .collect()
}

/// Index of the smallest value.
fn argmin(v: &[f64]) -> usize {
    (0..v.len()).min_by(|&a, &b| v[a].total_cmp(&v[b])).unwrap()
}

/// Cross-validation chooses α̂ without the truth (`smoothness = "cv"`): on the known-truth box
/// (288 tets) with ICP markers 0.3 mm off the surface, 3-fold cross-validation on held-out
/// markers over the grid 3e-6, 3e-4, 3e-2 picks the α̂ whose true shape error (p95 distance from
/// 400 held-out points of the true surface to the reshaped surface) is the lowest — which only
/// the truth can tell. Measured: held-out marker RMS 0.464 / 0.312 / 0.485 mm, true shape p95
/// 0.831 / 0.499 / 1.943 mm.
#[test]
fn cross_validation_picks_the_smoothness_the_truth_prefers() {
    let (p, held_out, grid, settings) = noisy_box(HoldOut::IcpMarkers);
    let out = reshape(&p, &settings, &mut |_, _, _, _| {}).unwrap();
    let cv = out.cross_validation.clone().unwrap();
    let faces = p.template.boundary_faces();
    let shape_p95 = |x: &[Vector3<f64>]| {
        let surface = SurfaceProjector::new(&faces, x);
        let mut d: Vec<f64> = held_out
            .iter()
            .map(|h| surface.project(&truth(h)).unwrap().1)
            .collect();
        stats(&mut d).1
    };
    let truth_errors = errors_at_fixed_smoothness(&p, &grid, shape_p95);
    let rms: Vec<f64> = cv.scores.iter().map(|s| s.rms_m * 1e3).collect();
    let mm: Vec<f64> = truth_errors.iter().map(|e| e * 1e3).collect();
    eprintln!("held-out RMS {rms:.3?} mm; true shape p95 {mm:.3?} mm");
    let best = argmin(&truth_errors);
    assert_eq!(
        cv.chosen, grid[best],
        "CV chose {}, the truth {}",
        cv.chosen, grid[best]
    );
    assert_eq!(out.smoothness, cv.chosen);
    // The refit with every marker is the fixed-α̂ reshape at the chosen α̂.
    assert!((shape_p95(&out.positions_m) - truth_errors[best]).abs() < 1e-9);
}

/// `hold_out = "correspondence"`: the attachments and landmarks are held out (every fold a whole
/// reshape), scored by where their template points went. On the noisy known-truth box it picks
/// an α̂ of the grid whose correspondence error (where 400 held-out template points went vs the
/// truth) is the lowest of the grid.
#[test]
fn correspondence_cross_validation_picks_the_smoothness_the_truth_prefers() {
    let (p, held_out, grid, settings) = noisy_box(HoldOut::Correspondence);
    let out = reshape(&p, &settings, &mut |_, _, _, _| {}).unwrap();
    let cv = out.cross_validation.clone().unwrap();
    let locator = TetLocator::new(&p.template);
    let correspondence = |x: &[Vector3<f64>]| {
        let mut d: Vec<f64> = held_out
            .iter()
            .map(|h| {
                let e = locator.locate(h).unwrap();
                (e.position(&p.template.tets, x) - truth(h)).norm()
            })
            .collect();
        stats(&mut d).0
    };
    let truth_errors = errors_at_fixed_smoothness(&p, &grid, |x| correspondence(x) * 1e3);
    let rms: Vec<f64> = cv.scores.iter().map(|s| s.rms_m * 1e3).collect();
    eprintln!("held-out RMS {rms:.3?} mm; true correspondence mean {truth_errors:.3?} mm");
    let best = argmin(&truth_errors);
    assert_eq!(
        cv.chosen, grid[best],
        "CV chose {}, the truth {}",
        cv.chosen, grid[best]
    );
}
