//! Weighted rigid registration by Horn's closed-form quaternion method (Horn 1987, "Closed-form
//! solution of absolute orientation using unit quaternions"): the capture stage's probe-frame
//! registration (thesis §6.2.2) and the rigid block of saito-barbic §3.6 both call it.

use nalgebra::{Isometry3, Matrix3, Matrix4, Point3, Quaternion, Translation3, UnitQuaternion};

/// The rigid transform `T` minimising `Σ wᵢ |T(srcᵢ) − dstᵢ|²` (Horn 1987 §4: the optimal rotation
/// is the unit eigenvector of the largest eigenvalue of the symmetric 4×4 matrix `N` built from the
/// weighted cross-covariance `S = Σ wᵢ (srcᵢ − s̄)(dstᵢ − d̄)ᵀ`). `None` with fewer than three
/// points of positive weight or a non-finite input.
pub fn horn_weighted(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    w: &[f64],
) -> Option<Isometry3<f64>> {
    let wsum: f64 = w.iter().filter(|&&x| x > 0.0).sum();
    if src.len() != dst.len()
        || src.len() != w.len()
        || w.iter().filter(|&&x| x > 0.0).count() < 3
        || wsum <= 0.0
    {
        return None;
    }
    let mut cs = nalgebra::Vector3::zeros();
    let mut cd = nalgebra::Vector3::zeros();
    for i in 0..src.len() {
        cs += src[i].coords * w[i];
        cd += dst[i].coords * w[i];
    }
    cs /= wsum;
    cd /= wsum;
    let mut s = Matrix3::zeros();
    for i in 0..src.len() {
        s += (src[i].coords - cs) * (dst[i].coords - cd).transpose() * w[i];
    }
    let (sxx, sxy, sxz, syx, syy, syz, szx, szy, szz) = (
        s[(0, 0)],
        s[(0, 1)],
        s[(0, 2)],
        s[(1, 0)],
        s[(1, 1)],
        s[(1, 2)],
        s[(2, 0)],
        s[(2, 1)],
        s[(2, 2)],
    );
    #[rustfmt::skip]
    let n = Matrix4::new(
        sxx + syy + szz, syz - szy,        szx - sxz,        sxy - syx,
        syz - szy,       sxx - syy - szz,  sxy + syx,        szx + sxz,
        szx - sxz,       sxy + syx,        -sxx + syy - szz, syz + szy,
        sxy - syx,       szx + sxz,        syz + szy,        -sxx - syy + szz,
    );
    if n.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let eig = n.symmetric_eigen();
    let k = eig.eigenvalues.imax();
    let q = eig.eigenvectors.column(k);
    let rot = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
    let t = cd - rot * cs;
    Some(Isometry3::from_parts(Translation3::from(t), rot))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn recovers_a_known_rigid_motion() {
        let src: Vec<Point3<f64>> = (0..10)
            .map(|i| {
                Point3::new(
                    (i as f64 * 0.7).sin(),
                    (i as f64 * 1.3).cos(),
                    i as f64 * 0.1,
                )
            })
            .collect();
        let t = Isometry3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.2, -0.4, 0.9));
        let dst: Vec<_> = src.iter().map(|p| t * p).collect();
        let w: Vec<f64> = (0..10).map(|i| 0.5 + i as f64).collect();
        let e = horn_weighted(&src, &dst, &w).unwrap();
        for (s, d) in src.iter().zip(&dst) {
            assert!((e * s - d).norm() < 1e-12);
        }
    }

    #[test]
    fn zero_weights_ignore_outliers() {
        let src: Vec<Point3<f64>> = (0..6)
            .map(|i| Point3::new(i as f64, (i * i) as f64 * 0.1, (i % 2) as f64))
            .collect();
        let mut dst = src.clone();
        dst[5].z += 10.0;
        let mut w = vec![1.0; 6];
        w[5] = 0.0;
        let e = horn_weighted(&src, &dst, &w).unwrap();
        assert!((e.translation.vector.norm() + e.rotation.angle()) < 1e-12);
    }
}
