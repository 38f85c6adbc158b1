//! Barycentric embedding in tets and closest points on triangles.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use softcap_mesh::nalgebra::Vector3;
use softcap_mesh::*;

fn brute_tet_distance(mesh: &TetMesh, t: usize, p: &Vector3<f64>) -> f64 {
    let x = mesh.tets[t].map(|i| mesh.vertices[i]);
    let l = tet_barycentric(&x, p).unwrap();
    if l.iter().all(|v| *v >= 0.0) {
        return 0.0;
    }
    adjacency::TET_FACE_OPPOSITE
        .iter()
        .map(|f| {
            let w = closest_point_on_triangle(p, &x[f[0]], &x[f[1]], &x[f[2]]);
            (p - (x[f[0]] * w[0] + x[f[1]] * w[1] + x[f[2]] * w[2])).norm()
        })
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn points_inside_tets_are_reproduced_exactly() {
    let mut mesh = box_tet_mesh([-0.02, 0.0, 0.01], [0.02, 0.03, 0.03], [6, 5, 4]);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    // Jitter interior vertices so tets are irregular.
    for v in &mut mesh.vertices {
        *v += Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ) * 5e-4;
    }
    mesh.orient_positive();
    let loc = TetLocator::new(&mesh);
    for _ in 0..2000 {
        // Random point inside a random tet.
        let t = rng.random_range(0..mesh.tets.len());
        let mut w: [f64; 4] = std::array::from_fn(|_| rng.random_range(0.0..1.0));
        let s: f64 = w.iter().sum();
        w.iter_mut().for_each(|v| *v /= s);
        let p: Vector3<f64> = (0..4).map(|k| mesh.vertices[mesh.tets[t][k]] * w[k]).sum();
        let e = loc.locate(&p).unwrap();
        assert_eq!(e.distance, 0.0);
        assert!((e.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(e.weights.iter().all(|&v| v >= 0.0));
        let q = e.position(&mesh.tets, &mesh.vertices);
        assert!((q - p).norm() < 1e-12 * 0.04, "{:e}", (q - p).norm());
        if e.tet == t {
            for k in 0..4 {
                assert!((e.weights[k] - w[k]).abs() < 1e-9);
            }
        }
    }
}

#[test]
fn points_outside_get_the_closest_tet_and_its_distance() {
    let mesh = box_tet_mesh([0.0; 3], [1.0, 1.0, 0.5], [4, 4, 2]);
    let loc = TetLocator::new(&mesh);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for _ in 0..300 {
        let p = Vector3::new(
            rng.random_range(-0.5..1.5),
            rng.random_range(-0.5..1.5),
            rng.random_range(-0.5..1.0),
        );
        let e = loc.locate(&p).unwrap();
        // Distance to the box, analytically.
        let outside = Vector3::new(
            (-p.x).max(p.x - 1.0).max(0.0),
            (-p.y).max(p.y - 1.0).max(0.0),
            (-p.z).max(p.z - 0.5).max(0.0),
        )
        .norm();
        assert!(
            (e.distance - outside).abs() < 1e-12,
            "{} vs {outside}",
            e.distance
        );
        // Brute force agrees on the distance, and weights reproduce p (affine extension).
        let brute = (0..mesh.tets.len())
            .map(|t| brute_tet_distance(&mesh, t, &p))
            .fold(f64::INFINITY, f64::min);
        assert!((brute - e.distance).abs() < 1e-14);
        assert!((e.position(&mesh.tets, &mesh.vertices) - p).norm() < 1e-12);
    }
}

#[test]
fn closest_points_on_sphere_surface() {
    let sphere = icosphere(3);
    let loc = TriLocator::new(&sphere);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for _ in 0..300 {
        let dir = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if dir.norm() < 1e-3 {
            continue;
        }
        let p = dir.normalize() * rng.random_range(0.2..2.0);
        let e = loc.locate(&p).unwrap();
        let brute = sphere
            .triangles
            .iter()
            .map(|t| {
                let w = closest_point_on_triangle(
                    &p,
                    &sphere.vertices[t[0]],
                    &sphere.vertices[t[1]],
                    &sphere.vertices[t[2]],
                );
                (p - (0..3)
                    .map(|k| sphere.vertices[t[k]] * w[k])
                    .sum::<Vector3<f64>>())
                .norm()
            })
            .fold(f64::INFINITY, f64::min);
        assert!((e.distance - brute).abs() < 1e-14);
        assert!(
            e.weights.iter().all(|&w| w >= 0.0)
                && (e.weights.iter().sum::<f64>() - 1.0).abs() < 1e-14
        );
        let q = e.position(&sphere.triangles, &sphere.vertices);
        assert!(((p - q).norm() - e.distance).abs() < 1e-14);
        // Polyhedral sphere: distance within the chordal error of | |p| − 1 |.
        assert!((e.distance - (p.norm() - 1.0).abs()).abs() < 0.02);
    }
}

#[test]
fn line_triangle_hits_reproduce_the_point_and_misses_are_none() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let tri = [
        Vector3::new(0.1, -0.2, 0.3),
        Vector3::new(1.2, 0.1, -0.1),
        Vector3::new(-0.3, 0.9, 0.2),
    ];
    let d = Vector3::new(0.2, -0.3, 1.0).normalize();
    let (mut hits, mut misses) = (0, 0);
    for _ in 0..200 {
        // A random point of the triangle's plane, inside or outside.
        let (u, v): (f64, f64) = (rng.random_range(-0.5..1.5), rng.random_range(-0.5..1.5));
        let p = tri[0] * (1.0 - u - v) + tri[1] * u + tri[2] * v;
        let t0: f64 = rng.random_range(-2.0..2.0);
        let o = p - d * t0;
        match line_triangle(&o, &d, &tri) {
            Some((t, w)) => {
                hits += 1;
                assert!(u >= -1e-12 && v >= -1e-12 && u + v <= 1.0 + 1e-12);
                assert!((t - t0).abs() < 1e-12, "{t} vs {t0}");
                let q = tri[0] * w[0] + tri[1] * w[1] + tri[2] * w[2];
                assert!((q - p).norm() < 1e-12);
            }
            None => {
                misses += 1;
                assert!(u < 0.0 || v < 0.0 || u + v > 1.0, "({u}, {v}) missed");
            }
        }
    }
    assert!(hits > 20 && misses > 20, "{hits} hits, {misses} misses");
    // A line in the triangle's plane is parallel to it.
    assert!(line_triangle(&tri[0], &(tri[1] - tri[0]), &tri).is_none());
}
