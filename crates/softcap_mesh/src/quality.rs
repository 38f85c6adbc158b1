//! Tet-mesh quality: dihedral angles, inverted tets and the radius-ratio aspect (the measures of
//! saito-barbic Fig. 17 for a reshaped mesh).
//!
//! * Dihedral angle at the edge (i, j) of a tet with the other corners k, l: the angle between
//!   the components of x_k − x_i and x_l − x_i orthogonal to the edge (70.53° everywhere on a
//!   regular tet; → 0° or 180° as the tet flattens).
//! * Aspect ratio ρ = R / (3 r), circumradius over three times the inradius (Shewchuk 2002,
//!   "What is a good linear element?"): 1 for the regular tet, → ∞ for a degenerate one.
//! * Inverted: signed volume det[x₁−x₀, x₂−x₀, x₃−x₀] ≤ 0.

use crate::types::TetMesh;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Quality summary of a tet mesh at some vertex positions.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TetQuality {
    /// Smallest dihedral angle of any tet, degrees.
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle of any tet, degrees.
    pub max_dihedral_deg: f64,
    /// Tets with signed volume ≤ 0.
    pub inverted_tets: usize,
    /// Largest radius ratio R/(3r) (1 = regular).
    pub max_aspect_ratio: f64,
    /// Mean radius ratio over the tets.
    pub mean_aspect_ratio: f64,
}

/// The six dihedral angles of the tet `x` (radians), edges in the order 01, 02, 03, 12, 13, 23.
pub fn dihedral_angles(x: &[Vector3<f64>; 4]) -> [f64; 6] {
    const EDGES: [(usize, usize, usize, usize); 6] = [
        (0, 1, 2, 3),
        (0, 2, 1, 3),
        (0, 3, 1, 2),
        (1, 2, 0, 3),
        (1, 3, 0, 2),
        (2, 3, 0, 1),
    ];
    EDGES.map(|(i, j, k, l)| {
        let e = x[j] - x[i];
        let n1 = e.cross(&(x[k] - x[i]));
        let n2 = e.cross(&(x[l] - x[i]));
        let d = n1.norm() * n2.norm();
        if d > 0.0 {
            (n1.dot(&n2) / d).clamp(-1.0, 1.0).acos()
        } else {
            0.0
        }
    })
}

/// Radius ratio R / (3 r) of the tet `x` (1 for a regular tet, +∞ for a flat one).
pub fn aspect_ratio(x: &[Vector3<f64>; 4]) -> f64 {
    let (a, b, c) = (x[1] - x[0], x[2] - x[0], x[3] - x[0]);
    let det = a.dot(&b.cross(&c)).abs();
    if det == 0.0 {
        return f64::INFINITY;
    }
    let circum = (b.cross(&c) * a.norm_squared()
        + c.cross(&a) * b.norm_squared()
        + a.cross(&b) * c.norm_squared())
    .norm()
        / (2.0 * det);
    let faces = [(1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)];
    let area: f64 = faces
        .iter()
        .map(|&(i, j, k)| 0.5 * (x[j] - x[i]).cross(&(x[k] - x[i])).norm())
        .sum();
    // r = 3V / A with V = det / 6.
    let inradius = det / (2.0 * area);
    circum / (3.0 * inradius)
}

/// Quality of `mesh`'s tets at the positions `x` (one per mesh vertex; e.g. a deformed state).
pub fn tet_quality(mesh: &TetMesh, x: &[Vector3<f64>]) -> TetQuality {
    let mut q = TetQuality {
        min_dihedral_deg: f64::INFINITY,
        max_dihedral_deg: 0.0,
        inverted_tets: 0,
        max_aspect_ratio: 0.0,
        mean_aspect_ratio: 0.0,
    };
    for tet in &mesh.tets {
        let p = tet.map(|i| x[i]);
        if (p[1] - p[0]).dot(&(p[2] - p[0]).cross(&(p[3] - p[0]))) <= 0.0 {
            q.inverted_tets += 1;
        }
        for angle in dihedral_angles(&p) {
            q.min_dihedral_deg = q.min_dihedral_deg.min(angle.to_degrees());
            q.max_dihedral_deg = q.max_dihedral_deg.max(angle.to_degrees());
        }
        let rho = aspect_ratio(&p);
        q.max_aspect_ratio = q.max_aspect_ratio.max(rho);
        q.mean_aspect_ratio += rho;
    }
    if !mesh.tets.is_empty() {
        q.mean_aspect_ratio /= mesh.tets.len() as f64;
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;

    fn regular() -> [Vector3<f64>; 4] {
        [
            Vector3::new(1.0, 1.0, 1.0),
            Vector3::new(1.0, -1.0, -1.0),
            Vector3::new(-1.0, 1.0, -1.0),
            Vector3::new(-1.0, -1.0, 1.0),
        ]
    }

    #[test]
    fn regular_tet_has_the_textbook_measures() {
        let x = regular();
        for a in dihedral_angles(&x) {
            assert!((a.to_degrees() - 70.528_779_365_509_3).abs() < 1e-9);
        }
        assert!((aspect_ratio(&x) - 1.0).abs() < 1e-12);
        // The right-corner tet: three 90° dihedrals at the corner edges.
        let c = [Vector3::zeros(), Vector3::x(), Vector3::y(), Vector3::z()];
        let d = dihedral_angles(&c);
        for k in 0..3 {
            assert!((d[k].to_degrees() - 90.0).abs() < 1e-12);
        }
        assert!(aspect_ratio(&c) > 1.0);
    }

    #[test]
    fn quality_counts_inverted_tets() {
        let mesh = crate::box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [1, 1, 1]);
        let q = tet_quality(&mesh, &mesh.vertices);
        assert_eq!(q.inverted_tets, 0);
        assert!(q.min_dihedral_deg > 0.0 && q.max_dihedral_deg < 180.0);
        let mirrored: Vec<Vector3<f64>> = mesh
            .vertices
            .iter()
            .map(|v| Vector3::new(-v.x, v.y, v.z))
            .collect();
        assert_eq!(tet_quality(&mesh, &mirrored).inverted_tets, mesh.tets.len());
    }
}
