//! saito-barbic reshaping against known ground truth (paper Fig. 21).

use softcap_fem::nalgebra::Vector3;
use softcap_mesh::{TetLocator, TetMesh, box_tet_mesh};
use softcap_tissue::reshape::{
    Attachment, ConstraintKind, IcpMarker, Landmark, MaterialPoint, ReshapeProblem,
    ReshapeSettings, SurfaceProjector, reshape,
};

/// The known deformation: a compatible, smooth, anisotropic map with stretches from 1 to 2.
fn truth(p: &Vector3<f64>) -> Vector3<f64> {
    let xi = p.x / 0.1;
    Vector3::new(
        p.x * (1.0 + 0.5 * xi),
        p.y * (1.5 - 0.5 * xi),
        0.9 * p.z + 2.0 * (p.x - 0.05).powi(2),
    )
}

struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Random points on the template's boundary faces.
fn boundary_points(mesh: &TetMesh, n: usize, rng: &mut Lcg) -> Vec<Vector3<f64>> {
    let faces = mesh.boundary_faces();
    (0..n)
        .map(|_| {
            let f = faces[(rng.next() * faces.len() as f64) as usize % faces.len()];
            let (mut a, mut b) = (rng.next(), rng.next());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let [p, q, r] = f.map(|v| mesh.vertices[v]);
            p * (1.0 - a - b) + q * a + r * b
        })
        .collect()
}

fn problem(free_flying: bool) -> (ReshapeProblem, Vec<Vector3<f64>>) {
    let mesh = box_tet_mesh([0.0; 3], [0.1, 0.06, 0.04], [8, 5, 3]);
    let mut rng = Lcg(7);
    let locator = TetLocator::new(&mesh);
    let embed = |p: &Vector3<f64>| {
        let e = locator.locate(p).unwrap();
        MaterialPoint {
            nodes: mesh.tets[e.tet],
            weights: e.weights,
        }
    };
    let landmarks = boundary_points(&mesh, 12, &mut rng)
        .iter()
        .enumerate()
        .map(|(i, p)| Landmark {
            id: format!("l{i}"),
            point: embed(p),
            target_m: truth(p),
        })
        .collect();
    let icp_markers = boundary_points(&mesh, 150, &mut rng)
        .iter()
        .enumerate()
        .map(|(i, p)| IcpMarker {
            id: format!("m{i}"),
            position_m: truth(p),
        })
        .collect();
    let attachments = if free_flying {
        Vec::new()
    } else {
        mesh.vertices
            .iter()
            .enumerate()
            .filter(|(_, v)| v.x == 0.0)
            .map(|(i, v)| Attachment {
                id: i.to_string(),
                node: i,
                target_m: truth(v),
            })
            .collect()
    };
    let held_out = boundary_points(&mesh, 400, &mut rng);
    (
        ReshapeProblem {
            template: mesh,
            landmarks,
            icp_markers,
            attachments,
            free_flying,
        },
        held_out,
    )
}

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
#[test]
fn recovers_a_known_anisotropic_plastic_deformation() {
    let (p, held_out) = problem(false);
    let out = reshape(&p, &ReshapeSettings::default(), &mut |_, _, _, _| {}).unwrap();
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
    let mut icp: Vec<f64> = out
        .errors
        .iter()
        .filter(|e| e.kind == ConstraintKind::Icp)
        .map(|e| e.error_m)
        .collect();
    let (s, c, i) = (
        stats(&mut shape),
        stats(&mut correspondence),
        stats(&mut icp),
    );
    let mm =
        |t: (f64, f64, f64)| format!("{:.3} / {:.3} / {:.3} mm", t.0 * 1e3, t.1 * 1e3, t.2 * 1e3);
    eprintln!(
        "{:?}\nshape (mean / p95 / max) {}; correspondence {}; ICP markers {}; {:?}",
        out.stages,
        mm(s),
        mm(c),
        mm(i),
        out.reshaped_quality
    );
    assert!(s.0 < 0.3e-3 && s.1 < 1.0e-3, "shape error {}", mm(s));
    assert!(c.0 < 2.0e-3, "correspondence error {}", mm(c));
    assert!(i.0 < 0.3e-3 && i.2 < 2.0e-3, "ICP error {}", mm(i));
    assert_eq!(out.reshaped_quality.inverted_tets, 0);
}

/// Writes the attached problem as a TARGET folder in mm (+ the template .msh) under `dir`.
fn write_target(dir: &std::path::Path, p: &ReshapeProblem) {
    let mm = |v: &Vector3<f64>| format!("{},{},{}", v.x * 1e3, v.y * 1e3, v.z * 1e3);
    let mut template = p.template.clone();
    template.scale(1e3);
    softcap_mesh::write_msh(
        dir.join("template.msh"),
        &softcap_mesh::MshMesh::from_tet_mesh(&template, None),
    )
    .unwrap();
    let t = dir.join("target");
    std::fs::create_dir_all(&t).unwrap();
    std::fs::write(
        t.join("target.toml"),
        "length_unit = \"mm\"\nattachments = \"attachments.csv\"\n",
    )
    .unwrap();
    let mut s = String::from("id,template_x,template_y,template_z,x,y,z\n");
    for l in &p.landmarks {
        let x = l.point.at(&p.template.vertices);
        s += &format!("{},{},{}\n", l.id, mm(&x), mm(&l.target_m));
    }
    std::fs::write(t.join("landmarks.csv"), s).unwrap();
    let mut s = String::from("id,x,y,z\n");
    for m in &p.icp_markers {
        s += &format!("{},{}\n", m.id, mm(&m.position_m));
    }
    std::fs::write(t.join("icp_markers.csv"), s).unwrap();
    let mut s = String::from("node,x,y,z\n");
    for a in &p.attachments {
        s += &format!("{},{}\n", a.node, mm(&a.target_m));
    }
    std::fs::write(t.join("attachments.csv"), s).unwrap();
}

/// `softcap-tissue reshape` end to end with a two-iteration budget: exit 0, the iteration cap is
/// reported as status `max-iterations`, reshaped.mcap holds the mesh and every constraint; a
/// landmark outside the template is exit 2 naming landmarks.csv and its line, nothing written.
#[test]
fn cli_reshapes_a_target_folder_and_rejects_a_landmark_outside_the_template() {
    let (p, _) = problem(false);
    let dir = tempfile::tempdir().unwrap();
    write_target(dir.path(), &p);
    let settings = dir.path().join("reshape.toml");
    std::fs::write(&settings, "max_iterations = 2\nconstant_iterations = 2\n").unwrap();
    let out = dir.path().join("reshaped.mcap");
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
            .arg("--quiet")
            .output()
            .unwrap()
    };
    let ok = run("target", &out);
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    assert!(stdout.starts_with("max-iterations"), "{stdout}");
    let r = softcap_mcap::Recording::open(&out).unwrap();
    let volume = r
        .read_static(&softcap_mcap::topics::VOLUME_MESH)
        .unwrap();
    assert_eq!(volume.positions_m.len(), p.template.vertices.len());
    let constraints = r
        .read_static(&softcap_mcap::topics::RESHAPE_CONSTRAINTS)
        .unwrap();
    assert_eq!(
        constraints.constraints.len(),
        p.attachments.len() + p.landmarks.len() + p.icp_markers.len()
    );
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
