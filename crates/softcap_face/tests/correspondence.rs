//! Thesis §4.2.1: because of the quadratic tail, the r³ space warp reproduces affine motion exactly.

use softcap_face::Correspondence;
use softcap_face::nalgebra::{Matrix3, Vector3};

#[test]
fn space_warp_reproduces_affine_motion_exactly() {
    // 41 scattered "markers" (deterministic pseudo-random in a 15 cm box).
    let mut s = 12345u64;
    let mut rnd = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let markers: Vec<Vector3<f64>> = (0..41)
        .map(|_| Vector3::new(15.0 * rnd(), 15.0 * rnd(), 8.0 * rnd()))
        .collect();
    let a = Matrix3::new(0.9, 0.1, -0.05, -0.2, 1.1, 0.03, 0.07, 0.02, 0.95);
    let b = Vector3::new(-12.0, 4.0, 2.5);
    let affine = |x: &Vector3<f64>| a * x + b;
    let face: Vec<Vector3<f64>> = markers.iter().map(affine).collect();
    let c = Correspondence::fit(&markers, &face).unwrap();
    let mut worst: f64 = 0.0;
    for _ in 0..200 {
        let x = Vector3::new(20.0 * rnd() - 2.0, 20.0 * rnd() - 2.0, 10.0 * rnd() - 1.0);
        worst = worst.max((c.map(&x).unwrap() - affine(&x)).norm());
    }
    eprintln!("affine reproduction: max error {worst:.2e} cm");
    assert!(worst < 1e-9, "{worst}");
    // Displacements of a moved frame equal the affine image of the motion.
    let moved: Vec<Vector3<f64>> = markers
        .iter()
        .map(|m| m + Vector3::new(0.1, -0.3, 0.2))
        .collect();
    let u = c.displacements(&moved).unwrap();
    for (ui, m) in u.iter().zip(&markers) {
        let expect = affine(&(m + Vector3::new(0.1, -0.3, 0.2))) - affine(m);
        assert!((ui - expect).norm() < 1e-9);
    }
}
