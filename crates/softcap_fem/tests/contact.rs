//! Rigid-probe contact (bickel2009 §3.4): penetration queries of every tip shape against analytic
//! geometry, and a frictionless flat punch covering the whole top face, which must reproduce the
//! equivalent Dirichlet problem (top nodes' z prescribed, x and y free) — force, patch and
//! positions — up to the penalty penetration (k_c = 10⁴ × local stiffness ⇒ ~1e-4 relative).

use softcap_fem::nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use softcap_fem::*;

fn down_at(p: Vector3<f64>) -> Isometry3<f64> {
    // Probe +z (approach) ↦ world −z, leading point at p.
    Isometry3::from_parts(
        Translation3::from(p),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    )
}

#[test]
fn penetration_of_each_tip_matches_geometry() {
    let pose = down_at(Vector3::new(0.1, 0.2, 0.3));
    let tol = 1e-12;
    // Sphere r = 0.05: centre at the leading point + r along the approach axis reversed (world +z).
    let sphere = Probe::new(TipShape::Sphere { radius_m: 0.05 }, pose).unwrap();
    let (d, n, c) = sphere.penetration(&Vector3::new(0.1, 0.2, 0.31)).unwrap();
    assert!((d - 0.01).abs() < tol, "{d}");
    assert!((n - Vector3::new(0.0, 0.0, -1.0)).norm() < tol);
    assert!((c - Vector3::new(0.1, 0.2, 0.3)).norm() < tol);
    assert!(sphere.penetration(&Vector3::new(0.1, 0.2, 0.29)).is_none());
    // Disk r = 0.05, thickness 0.02: slab z ∈ [0.3, 0.32] in the world, |xy − (0.1, 0.2)| < r.
    let disk = Probe::new(
        TipShape::Disk {
            radius_m: 0.05,
            thickness_m: 0.02,
        },
        pose,
    )
    .unwrap();
    let (d, n, _) = disk.penetration(&Vector3::new(0.13, 0.2, 0.303)).unwrap();
    assert!((d - 0.003).abs() < tol && (n - Vector3::new(0.0, 0.0, -1.0)).norm() < tol);
    // Near the rim the side wins: 0.002 from the cylinder wall, outward radial.
    let (d, n, _) = disk.penetration(&Vector3::new(0.148, 0.2, 0.31)).unwrap();
    assert!(
        (d - 0.002).abs() < tol && (n - Vector3::x()).norm() < tol,
        "{d} {n}"
    );
    assert!(disk.penetration(&Vector3::new(0.16, 0.2, 0.31)).is_none());
    // As a flat punch the same rim point leaves through the leading face: 0.01 behind it, along
    // the approach normal (world −z), its closest point straight below it on the face.
    let punch = disk.clone().with_punch_face();
    let (d, n, c) = punch.penetration(&Vector3::new(0.148, 0.2, 0.31)).unwrap();
    assert!((d - 0.01).abs() < tol && (n - Vector3::new(0.0, 0.0, -1.0)).norm() < tol);
    assert!((c - Vector3::new(0.148, 0.2, 0.3)).norm() < tol, "{c}");
    // the clone keeps the punch, the face points are untouched, outside stays outside
    let (d, ..) = punch
        .clone()
        .penetration(&Vector3::new(0.13, 0.2, 0.303))
        .unwrap();
    assert!((d - 0.003).abs() < tol);
    for outside in [[0.16, 0.2, 0.31], [0.13, 0.2, 0.299], [0.13, 0.2, 0.321]] {
        assert!(
            punch.penetration(&Vector3::from(outside)).is_none(),
            "{outside:?}"
        );
    }
    // Cylinder r = 0.05 lying along probe x (world x), axis at world z = 0.35.
    let cyl = Probe::new(
        TipShape::Cylinder {
            radius_m: 0.05,
            half_length_m: 0.5,
        },
        pose,
    )
    .unwrap();
    let (d, n, _) = cyl.penetration(&Vector3::new(0.4, 0.2, 0.302)).unwrap();
    assert!((d - 0.002).abs() < tol && (n - Vector3::new(0.0, 0.0, -1.0)).norm() < tol);
    let p = Vector3::new(0.0, 0.2 + 0.03, 0.35 - 0.03); // 0.0424 from the axis
    let (d, n, _) = cyl.penetration(&p).unwrap();
    assert!((d - (0.05 - 0.03 * 2f64.sqrt())).abs() < tol);
    assert!((n - Vector3::new(0.0, 1.0, -1.0).normalize()).norm() < 1e-9);
    // Mesh: the unit-less cube [−0.05, 0.05]² × [−0.1, 0] in the probe frame (outward CCW faces).
    let v = |x: f64, y: f64, z: f64| Vector3::new(x, y, z);
    let (h, t) = (0.05, -0.1);
    let vertices_m = vec![
        v(-h, -h, t),
        v(h, -h, t),
        v(h, h, t),
        v(-h, h, t),
        v(-h, -h, 0.0),
        v(h, -h, 0.0),
        v(h, h, 0.0),
        v(-h, h, 0.0),
    ];
    let triangles = vec![
        [0, 2, 1],
        [0, 3, 2],
        [4, 5, 6],
        [4, 6, 7],
        [0, 1, 5],
        [0, 5, 4],
        [1, 2, 6],
        [1, 6, 5],
        [2, 3, 7],
        [2, 7, 6],
        [3, 0, 4],
        [3, 4, 7],
    ];
    let mesh = Probe::new(
        TipShape::Mesh {
            vertices_m,
            triangles,
        },
        pose,
    )
    .unwrap();
    // World: probe z ↦ −world z, so the block spans world z ∈ [0.3, 0.4], leading face z = 0.3.
    let (d, n, _) = mesh.penetration(&Vector3::new(0.11, 0.19, 0.304)).unwrap();
    assert!((d - 0.004).abs() < 1e-12 && (n - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
    assert!(mesh.penetration(&Vector3::new(0.11, 0.19, 0.299)).is_none());
    // Bad tips are errors, not panics.
    assert!(Probe::new(TipShape::Sphere { radius_m: -1.0 }, pose).is_err());
    assert!(
        Probe::new(
            TipShape::Disk {
                radius_m: 0.1,
                thickness_m: f64::NAN
            },
            pose
        )
        .is_err()
    );
}

#[test]
fn flat_punch_matches_the_equivalent_dirichlet_problem() {
    let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [4, 4, 3]);
    let mut model = CorotationalModel::homogeneous(
        &mesh,
        LinearParams::from_young_poisson(5.0e4, 0.4).unwrap(),
    )
    .unwrap();
    let mut bc = DirichletBc::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.z.abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
    }
    let top: Vec<usize> = (0..mesh.vertices.len())
        .filter(|&i| (mesh.vertices[i].z - 0.02).abs() < 1e-12)
        .collect();
    let d = 0.002;
    // A disk much wider than the block, its face 2 mm below the top.
    let probe = Probe::new(
        TipShape::Disk {
            radius_m: 0.2,
            thickness_m: 0.05,
        },
        down_at(Vector3::new(0.02, 0.02, 0.02 - d)),
    )
    .unwrap();
    let contact = ContactProblem {
        probe,
        candidate_nodes: top.clone(),
        settings: ContactSettings::default(),
    };
    let mut solver = StaticSolver::with_bc(&model, &bc).unwrap();
    let mut x = mesh.vertices.clone();
    let zero = vec![Vector3::zeros(); x.len()];
    let rep = solver.solve(
        &mut model,
        &mut x,
        &zero,
        Some(&contact),
        &EquilibriumSettings::default(),
    );
    assert!(rep.converged(), "{rep:?}");
    assert_eq!(rep.contact.patch_nodes, top);
    // Reference: the same top displacement prescribed (frictionless ⇒ x, y free).
    let mut bc_ref = bc.clone();
    for &n in &top {
        bc_ref.fix_dof(3 * n + 2, 0.02 - d);
    }
    let mut solver_ref = StaticSolver::with_bc(&model, &bc_ref).unwrap();
    let mut x_ref = mesh.vertices.clone();
    bc_ref.apply(&mut x_ref);
    let rep_ref = solver_ref.solve(
        &mut model,
        &mut x_ref,
        &zero,
        None,
        &EquilibriumSettings::default(),
    );
    assert!(rep_ref.converged());
    let f_int = model.internal_forces(&x_ref);
    // Force the prescribed top needs, pushing down (−z): −Σ f_int,z of the top nodes.
    let push_n: f64 = -top.iter().map(|&n| f_int[n].z).sum::<f64>();
    // The probe pushes along its axis (world −z) with the same force.
    let rel = (rep.contact.axial_force_n - push_n).abs() / push_n;
    println!(
        "flat punch: contact {:.6e} N, Dirichlet {:.6e} N, rel. diff {rel:.2e}, max penetration {:.2e} m",
        rep.contact.axial_force_n, push_n, rep.contact.max_penetration_m
    );
    assert!(rep.contact.axial_force_n > 0.0 && rel < 1e-3);
    assert!(rep.contact.max_penetration_m < 1e-3 * d);
    let dx = x
        .iter()
        .zip(&x_ref)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(dx < 1e-3 * d, "positions differ by {dx}");
    assert!((rep.contact.probe_reaction_n + rep.contact.contact_force_n).norm() < 1e-15);
}
