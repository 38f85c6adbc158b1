//! Local longest-edge refinement (`refine_near`): conformity, volume, shape, locality,
//! determinism, and the uniform limit.

use softcap_mesh::nalgebra::Vector3;
use softcap_mesh::{
    MeshError, RefineBall, TetMesh, TriMesh, ValidationSettings, box_tet_mesh, refine_near,
    refine_tets,
};
use std::collections::BTreeMap;

/// Smallest dihedral angle of any tet, degrees.
fn min_dihedral_deg(m: &TetMesh) -> f64 {
    let mut min = f64::INFINITY;
    for tet in &m.tets {
        let x = tet.map(|i| m.vertices[i]);
        for i in 0..4 {
            for j in i + 1..4 {
                // the edge (i, j); the other two corners k, l
                let o: Vec<usize> = (0..4).filter(|&v| v != i && v != j).collect();
                let e = (x[j] - x[i]).normalize();
                let project = |p: Vector3<f64>| {
                    let d = p - x[i];
                    (d - e * d.dot(&e)).normalize()
                };
                let (u, v) = (project(x[o[0]]), project(x[o[1]]));
                min = min.min(u.dot(&v).clamp(-1.0, 1.0).acos().to_degrees());
            }
        }
    }
    min
}

fn boundary_area(m: &TetMesh) -> f64 {
    TriMesh {
        vertices: m.vertices.clone(),
        triangles: m.boundary_faces(),
    }
    .area()
}

/// Every sorted face used by at most two tets, and the boundary's area the input's: with a hanging
/// node the coarse side's face would count as boundary and the area would grow.
fn assert_conforming(refined: &TetMesh, input: &TetMesh) {
    let mut count: BTreeMap<[usize; 3], u32> = BTreeMap::new();
    for t in &refined.tets {
        for skip in 0..4 {
            let mut f = [0; 3];
            let mut k = 0;
            for (i, &v) in t.iter().enumerate() {
                if i != skip {
                    f[k] = v;
                    k += 1;
                }
            }
            f.sort_unstable();
            *count.entry(f).or_default() += 1;
        }
    }
    assert!(count.values().all(|&c| c == 1 || c == 2));
    let (a, b) = (boundary_area(refined), boundary_area(input));
    assert!((a - b).abs() < 1e-12 * b, "boundary area {a} vs {b}");
    refined.validate(&ValidationSettings::default()).unwrap();
}

fn box_mesh() -> TetMesh {
    // the suite's fit-mesh layout: 6 × 6 × 3 Kuhn cells, 648 tets, 40 × 40 × 20 mm
    box_tet_mesh([0.0, 0.0, 0.0], [0.04, 0.04, 0.02], [6, 6, 3])
}

fn ball(x: f64, y: f64, z: f64, r: f64) -> RefineBall {
    RefineBall {
        centre_m: Vector3::new(x, y, z),
        radius_m: r,
    }
}

#[test]
fn local_refinement_is_conforming_volume_preserving_and_keeps_its_shape() {
    let mesh = box_mesh();
    let h_in = mesh.longest_edge();
    let balls = [
        ball(0.012, 0.02, 0.02, 0.006),
        ball(0.03, 0.025, 0.02, 0.004),
    ];
    let h = 0.25 * h_in;
    let r = refine_near(&mesh, &balls, h, 1_000_000).unwrap();
    let n = mesh.vertices.len();
    assert_eq!(r.parent_tet.len(), r.mesh.tets.len());
    assert_eq!(r.midpoint_of.len(), r.mesh.vertices.len() - n);
    assert_conforming(&r.mesh, &mesh);
    // volume per parent and in total, every child positive
    let mut per_parent = vec![0.0; mesh.tets.len()];
    for t in 0..r.mesh.tets.len() {
        let v = r.mesh.tet_volume(t);
        assert!(v > 0.0, "tet {t} volume {v}");
        per_parent[r.parent_tet[t]] += v;
    }
    for (t, v) in per_parent.iter().enumerate() {
        assert!((v - mesh.tet_volume(t)).abs() < 1e-12 * mesh.tet_volume(t));
    }
    assert!((r.mesh.volume() - mesh.volume()).abs() < 1e-12 * mesh.volume());
    // midpoints of earlier vertices, in creation order
    for (k, &[a, b]) in r.midpoint_of.iter().enumerate() {
        assert!(a < b && b < n + k);
        let mid = (r.mesh.vertices[a] + r.mesh.vertices[b]) * 0.5;
        assert!((r.mesh.vertices[n + k] - mid).norm() < 1e-15);
    }
    // every tet meeting a ball is refined to h
    let near = |t: usize| {
        let c = r.mesh.tets[t].map(|i| r.mesh.vertices[i]);
        let centroid = (c[0] + c[1] + c[2] + c[3]) / 4.0;
        balls
            .iter()
            .any(|b| (centroid - b.centre_m).norm() <= b.radius_m)
    };
    let mut refined_near = 0;
    for t in 0..r.mesh.tets.len() {
        if near(t) {
            assert!(r.mesh.tet_longest_edge(t) <= h * (1.0 + 1e-12));
            refined_near += 1;
        }
    }
    assert!(refined_near > 100, "{refined_near}");
    // Shape: longest-edge bisection of a Kuhn tet (minimum dihedral 45°) gives Kuhn tets again
    // (Freudenthal's subdivision in three bisections), so the minimum dihedral angle must not
    // drop at all (measured 45.0° in, 45.0° out; 3622 tets, 794 vertices).
    let (d_in, d_out) = (min_dihedral_deg(&mesh), min_dihedral_deg(&r.mesh));
    assert!((d_in - 45.0).abs() < 1e-9, "{d_in}");
    assert!(
        d_out >= d_in - 1e-9,
        "min dihedral {d_out}° vs input {d_in}°"
    );
    // fewer tets than uniform refinement to the same h (two uniform levels: 64 ×)
    assert!(
        r.mesh.tets.len() < 64 * mesh.tets.len() / 4,
        "{} tets",
        r.mesh.tets.len()
    );
}

#[test]
fn tets_away_from_the_balls_are_untouched() {
    let mesh = box_mesh();
    let h_in = mesh.longest_edge();
    let balls = [ball(0.012, 0.02, 0.02, 0.006)];
    let r = refine_near(&mesh, &balls, 0.25 * h_in, 1_000_000).unwrap();
    // an input tet is untouched when its slot keeps its corners and no other tet descends from it
    let mut children = vec![0usize; mesh.tets.len()];
    for &p in &r.parent_tet {
        children[p] += 1;
    }
    let distance = |t: usize| {
        let x = mesh.tets[t].map(|i| mesh.vertices[i]);
        let c = (x[0] + x[1] + x[2] + x[3]) / 4.0;
        (c - balls[0].centre_m).norm()
    };
    let mut touched = 0;
    let mut farthest_touched: f64 = 0.0;
    for t in 0..mesh.tets.len() {
        if children[t] == 1 {
            assert_eq!(r.mesh.tets[t], mesh.tets[t]);
        } else {
            touched += 1;
            farthest_touched = farthest_touched.max(distance(t));
        }
    }
    // The propagation path only climbs to longer edges, so it stays within about one input edge
    // of the ball (measured: 168 of 648 input tets touched, the farthest centroid 17.8 mm from
    // the centre = radius + 1.02 × the longest input edge of 11.5 mm).
    assert!(
        farthest_touched <= balls[0].radius_m + 1.5 * h_in,
        "touched tets up to {farthest_touched} m from the centre (radius {}, edge {h_in})",
        balls[0].radius_m
    );
    assert!(
        touched < mesh.tets.len() / 2,
        "{touched} of {}",
        mesh.tets.len()
    );
}

#[test]
fn output_is_deterministic() {
    let mesh = box_mesh();
    let balls = [
        ball(0.01, 0.01, 0.02, 0.005),
        ball(0.025, 0.03, 0.02, 0.005),
    ];
    let a = refine_near(&mesh, &balls, 0.003, 1_000_000).unwrap();
    let b = refine_near(&mesh, &balls, 0.003, 1_000_000).unwrap();
    assert_eq!(a, b);
}

#[test]
fn a_ball_over_everything_with_half_the_edge_matches_uniform_refinement() {
    // 3 longest-edge bisections of a Kuhn tet give the 8 Kuhn tets of the halved cell: the same
    // vertices and tet count as the red refinement (cubic cells: every body diagonal the longest).
    let mesh = box_tet_mesh([0.0, 0.0, 0.0], [0.03, 0.02, 0.02], [3, 2, 2]);
    let h_in = mesh.longest_edge();
    let r = refine_near(
        &mesh,
        &[ball(0.02, 0.015, 0.01, 1.0)],
        0.5 * h_in,
        1_000_000,
    )
    .unwrap();
    let u = refine_tets(&mesh);
    assert_eq!(r.mesh.tets.len(), u.mesh.tets.len());
    assert_eq!(r.mesh.vertices.len(), u.mesh.vertices.len());
    assert!((r.mesh.longest_edge() - 0.5 * h_in).abs() < 1e-12);
    assert_conforming(&r.mesh, &mesh);
}

#[test]
fn impossible_targets_are_one_clear_error() {
    let mesh = box_mesh();
    let b = [ball(0.02, 0.02, 0.02, 0.005)];
    for h in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            refine_near(&mesh, &b, h, 1_000_000),
            Err(MeshError::Refinement { .. })
        ));
    }
    assert!(matches!(
        refine_near(&mesh, &[ball(f64::NAN, 0.0, 0.0, 0.01)], 0.003, 1_000_000),
        Err(MeshError::Refinement { .. })
    ));
    let e = refine_near(&mesh, &b, 1e-4, 5_000).unwrap_err();
    assert!(e.to_string().contains("5000"), "{e}");
    // no ball: nothing changes
    let r = refine_near(&mesh, &[], 1e-4, 5_000).unwrap();
    assert_eq!(r.mesh, mesh);
    assert!(r.midpoint_of.is_empty());
}
