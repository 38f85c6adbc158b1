//! Robust polar decomposition of 3×3 matrices.
//!
//! F = R S with R a proper rotation (det R = +1) and S symmetric. For inverted or
//! near-inverted elements (det F ≤ 0) the rotation variant of Irving, Teran & Fedkiw
//! (2004, "Invertible finite elements") is used: the SVD F = U Σ Vᵀ is taken, and if
//! det(U Vᵀ) < 0 the column of U belonging to the smallest singular value is negated,
//! so that R = U Vᵀ stays a rotation and S = V Σ̂ Vᵀ carries the (negative) smallest
//! stretch. This is what stiffness warping (Müller & Gross 2004) needs: a continuous
//! rotation through element inversion instead of a reflection.
//!
//! nalgebra's SVD is used (hand-writing a 3×3 SVD buys nothing here); its result is
//! checked and a failed decomposition falls back to Gram–Schmidt of F, which is only
//! reachable for non-finite input.

use nalgebra::{Matrix3, Vector3};

/// Result of [`polar_decomposition`]: `F = rotation * stretch`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Polar {
    /// Proper rotation R (det R = +1).
    pub rotation: Matrix3<f64>,
    /// Symmetric stretch S = Rᵀ F (may be indefinite for inverted elements).
    pub stretch: Matrix3<f64>,
}

/// Polar decomposition F = R S with R ∈ SO(3), robust to inverted elements.
///
/// ```
/// use softcap_core::{nalgebra::{Matrix3, Rotation3, Vector3}, polar_decomposition};
/// let r = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.3).into_inner();
/// let s = Matrix3::new(1.2, 0.1, 0.0, 0.1, 0.9, 0.0, 0.0, 0.0, 1.0);
/// let p = polar_decomposition(&(r * s));
/// assert!((p.rotation - r).norm() < 1e-10);
/// assert!((p.stretch - s).norm() < 1e-10);
/// ```
pub fn polar_decomposition(f: &Matrix3<f64>) -> Polar {
    if !f.iter().all(|v| v.is_finite()) {
        return Polar {
            rotation: Matrix3::identity(),
            stretch: *f,
        };
    }
    let svd = f.svd(true, true);
    let (Some(mut u), Some(v_t)) = (svd.u, svd.v_t) else {
        return gram_schmidt_fallback(f);
    };
    let mut sigma: Vector3<f64> = svd.singular_values;
    if (u * v_t).determinant() < 0.0 {
        // Flip the direction of the smallest singular value (Irving et al. 2004 §5).
        let (imin, _) =
            sigma.iter().enumerate().fold(
                (0, f64::INFINITY),
                |acc, (i, &s)| if s < acc.1 { (i, s) } else { acc },
            );
        for r in 0..3 {
            u[(r, imin)] = -u[(r, imin)];
        }
        sigma[imin] = -sigma[imin];
    }
    let rotation = u * v_t;
    let v = v_t.transpose();
    let stretch = v * Matrix3::from_diagonal(&sigma) * v_t;
    Polar {
        rotation,
        stretch: 0.5 * (stretch + stretch.transpose()),
    }
}

fn gram_schmidt_fallback(f: &Matrix3<f64>) -> Polar {
    let c0 = f.column(0).normalize();
    let c1 = (f.column(1) - c0 * c0.dot(&f.column(1))).normalize();
    let c2 = c0.cross(&c1);
    let rotation = Matrix3::from_columns(&[c0, c1, c2]);
    Polar {
        rotation,
        stretch: rotation.transpose() * f,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;
    use proptest::prelude::*;

    fn check(f: &Matrix3<f64>) {
        let p = polar_decomposition(f);
        let r = p.rotation;
        assert!(
            (r.transpose() * r - Matrix3::identity()).norm() < 1e-10,
            "R not orthogonal"
        );
        assert!((r.determinant() - 1.0).abs() < 1e-10, "R not proper");
        assert!((p.stretch - p.stretch.transpose()).norm() < 1e-10 * (1.0 + f.norm()));
        assert!(
            (r * p.stretch - f).norm() < 1e-9 * (1.0 + f.norm()),
            "F != RS"
        );
    }

    #[test]
    fn identity_and_inverted() {
        check(&Matrix3::identity());
        // Fully inverted along z.
        let f = Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -0.2);
        check(&f);
        let p = polar_decomposition(&f);
        assert!(
            (p.rotation - Matrix3::identity()).norm() < 1e-12,
            "smallest stretch must carry the sign"
        );
        // Degenerate (flat) element.
        check(&Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0));
    }

    proptest! {
        #[test]
        fn decomposes_random(axis in prop::array::uniform3(-1.0f64..1.0), angle in -3.0f64..3.0,
                             s in prop::array::uniform9(-0.5f64..0.5), flip in any::<bool>()) {
            let ax = Vector3::from(axis);
            prop_assume!(ax.norm() > 1e-3);
            let r = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(ax), angle).into_inner();
            let mut m = Matrix3::identity() + Matrix3::from_row_slice(&s);
            if flip { m.column_mut(2).neg_mut(); }
            check(&(r * m));
        }
    }
}
