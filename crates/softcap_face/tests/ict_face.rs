//! The AnimFace jaw take drives the ICT neutral face (thesis §3.2.1, §4.2.1), and the
//! face-side linear-shell checks: exact interpolation of the handle displacements and linear
//! precision of −k_s Δu + k_b Δ²u = 0 on a flat patch.

use std::path::PathBuf;

use softcap_face::nalgebra::Vector3;
use softcap_face::{
    FaceAnimator, derive_landmarks, factor_shell, parse_landmarks_csv, read_animface_csv,
};
use softcap_mesh::TriMesh;
use softcap_mesh::shell::ShellSettings;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
}

#[test]
fn jaw_take_animates_ict_face_and_interpolates_handles() {
    let take = read_animface_csv(&fixtures().join("animface-mocap/jaw_subset.csv")).unwrap();
    assert_eq!(take.names.len(), 41);
    let mesh = softcap_mesh::read_obj(fixtures().join("ict-face/neutral.obj"))
        .unwrap()
        .to_tri_mesh();
    let table_path = fixtures().join("animface-mocap/ict_landmarks.csv");
    let table =
        parse_landmarks_csv(&std::fs::read_to_string(&table_path).unwrap(), &table_path).unwrap();
    // The committed table is what the documented derivation produces.
    let nose = take.marker_index("NoseHead").unwrap();
    let derived =
        derive_landmarks(&take.names, &take.positions_cm[0], &mesh.vertices, nose, 30).unwrap();
    for (a, b) in derived.iter().zip(&table) {
        assert_eq!((&a.marker, a.vertex), (&b.marker, b.vertex));
    }
    let handles: Vec<usize> = take
        .names
        .iter()
        .map(|n| table.iter().find(|r| &r.marker == n).unwrap().vertex)
        .collect();
    let animator = FaceAnimator::new(
        mesh.clone(),
        handles.clone(),
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .unwrap();
    // The precomputed basis (thesis §5.3, f32) reproduces the factor's solution.
    let mut fast = FaceAnimator::new(
        mesh.clone(),
        handles.clone(),
        &take.positions_cm[0],
        &ShellSettings::default(),
    )
    .unwrap();
    fast.precompute_basis().unwrap();
    let t390 = take.frames.iter().position(|&f| f == 390).unwrap();
    let exact = animator.frame(&take.positions_cm[t390]).unwrap();
    let via_basis = fast.frame(&take.positions_cm[t390]).unwrap();
    let basis_err = exact
        .iter()
        .zip(&via_basis)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    let handle_err = handles
        .iter()
        .map(|&h| (exact[h] - via_basis[h]).norm())
        .fold(0.0, f64::max);
    println!("basis vs factor solve: max {basis_err:.2e} cm, handles {handle_err:.2e} cm");
    assert!(basis_err < 1e-5, "basis {basis_err}");
    assert!(handle_err < 1e-12, "handles {handle_err}");
    // Frame 0 is the correspondence frame: zero displacement everywhere.
    let rest = animator.frame(&take.positions_cm[0]).unwrap();
    let rest_err = rest
        .iter()
        .zip(&mesh.vertices)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(rest_err < 1e-8, "rest {rest_err}");
    // Jaw open (source frame 390): handles move by exactly u_{i,t}; the chin drops.
    let t = take.frames.iter().position(|&f| f == 390).unwrap();
    let verts = animator.frame(&take.positions_cm[t]).unwrap();
    let u = animator
        .correspondence
        .displacements(&take.positions_cm[t])
        .unwrap();
    let mut worst: f64 = 0.0;
    for (k, &h) in handles.iter().enumerate() {
        worst = worst.max((verts[h] - mesh.vertices[h] - u[k]).norm());
    }
    let chin = handles[take.marker_index("Chin").unwrap()];
    let drop_cm = mesh.vertices[chin].y - verts[chin].y;
    let max_disp = verts
        .iter()
        .zip(&mesh.vertices)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    eprintln!(
        "jaw frame 390: handle interpolation error {worst:.2e} cm, chin drop {drop_cm:.2} cm, max displacement {max_disp:.2} cm"
    );
    assert!(worst < 1e-9, "{worst}");
    assert!(drop_cm > 1.0, "chin drop {drop_cm}");
}

#[test]
fn shell_on_flat_patch_reproduces_linear_fields() {
    // Irregular 21×21 grid on the plane z = 0; any linear displacement field solves
    // −k_s Δu + k_b Δ²u = 0 exactly (cotangent Laplacian has linear precision), so
    // prescribing it at the handles must reproduce it everywhere.
    let n = 21;
    let mut mesh = TriMesh::default();
    for j in 0..n {
        for i in 0..n {
            mesh.vertices.push(Vector3::new(
                i as f64 * 0.5 + 0.05 * ((i * j) % 3) as f64,
                j as f64 * 0.5,
                0.0,
            ));
        }
    }
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let a = j * n + i;
            mesh.triangles.push([a, a + 1, a + n + 1]);
            mesh.triangles.push([a, a + n + 1, a + n]);
        }
    }
    // Handles: the two outer rings (the energy form has natural boundary conditions, so the
    // Dirichlet data of the bi-Laplacian needs two rings) plus two interior vertices.
    let mut handles: Vec<usize> = (0..n * n)
        .filter(|&v| {
            let (i, j) = (v % n, v / n);
            i < 2 || j < 2 || i >= n - 2 || j >= n - 2
        })
        .collect();
    handles.extend([n * (n / 2) + n / 2, 5 * n + 7]);
    let field = |p: &Vector3<f64>| {
        Vector3::new(
            0.3 * p.x - 0.1 * p.y + 1.0,
            0.05 * p.x + 0.2 * p.y,
            -0.4 * p.x + 0.7 * p.y - 2.0,
        )
    };
    let shell = factor_shell(&mesh, &handles, &ShellSettings::default()).unwrap();
    let u_h: Vec<Vector3<f64>> = handles.iter().map(|&h| field(&mesh.vertices[h])).collect();
    let u = shell.solve(&u_h).unwrap();
    let worst = u
        .iter()
        .zip(&mesh.vertices)
        .map(|(ui, p)| (ui - field(p)).norm())
        .fold(0.0, f64::max);
    eprintln!("flat patch linear field: max error {worst:.2e}");
    assert!(worst < 1e-8, "{worst}");
}
