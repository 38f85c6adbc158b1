//! How finely a mesh resolves a tip: the surface node spacing near the tips, the frictional
//! replay's regularization slip and the refinements a tip needs.

use nalgebra::Vector3;

/// The radius of an analytic tip (`None` for a mesh tip).
pub(super) fn tip_radius_m(tip: &softcap_fem::TipShape) -> Option<f64> {
    use softcap_fem::TipShape;
    match tip {
        TipShape::Sphere { radius_m }
        | TipShape::Disk { radius_m, .. }
        | TipShape::Cylinder { radius_m, .. } => Some(*radius_m),
        TipShape::Mesh { .. } => None,
    }
}

/// Mean boundary edge length h of `mesh` over the boundary faces with a vertex within 2 r
/// (`radius_m`) of one of `tips_m` — over the whole surface when there is none (`None` without
/// boundary faces): the surface node spacing a tip of radius r meets.
pub fn surface_spacing_near(
    mesh: &softcap_mesh::TetMesh,
    radius_m: f64,
    tips_m: &[Vector3<f64>],
) -> Option<f64> {
    let faces = mesh.boundary_faces();
    let near = |f: &[usize; 3]| {
        f.iter().any(|&v| {
            tips_m
                .iter()
                .any(|t| (mesh.vertices[v] - t).norm() <= 2.0 * radius_m)
        })
    };
    let touched: Vec<[usize; 3]> = faces.iter().copied().filter(near).collect();
    let faces = if touched.is_empty() { faces } else { touched };
    let (mut sum, mut n) = (0.0, 0usize);
    for f in faces {
        for i in 0..3 {
            sum += (mesh.vertices[f[i]] - mesh.vertices[f[(i + 1) % 3]]).norm();
            n += 1;
        }
    }
    (n > 0).then(|| sum / n as f64)
}

/// The frictional replay's regularization slip ε (`softcap_fem::FrictionParams::slip_distance_m`)
/// on `mesh`: `fraction` × the surface node spacing h near the replayed tips
/// ([`surface_spacing_near`]; `FemSimSettings::friction_slip_fraction`, docs/diagnose.md session 15).
///
/// Why a fraction of h and not the truth's 10 µm: a contact node stands for its tributary patch
/// of width h, and under a tip whose footprint spans a few nodes the patch's partial slip
/// (Mindlin's slip annulus creeping inwards as the tip travels; Johnson, *Contact Mechanics*
/// §7.2) is below the mesh's resolution. With ε ≪ h every node switches from stick to slip at one
/// instant, and which nodes switch — and so the whole later stick history — forks with μ at the
/// percent level (session 12: the replay's error jumps between μ 0.7071 and 0.71). Spreading a
/// node's transition over ε = h / 10 keeps the stick stiff (2 μ f_n / ε is several times a node's
/// elastic stiffness ~E h at the suite's loads) while the replay becomes a continuous function of μ.
pub fn friction_slip_distance_m(
    mesh: &softcap_mesh::TetMesh,
    radius_m: f64,
    tips_m: &[Vector3<f64>],
    fraction: f64,
) -> f64 {
    let default = softcap_fem::FrictionParams::default().slip_distance_m;
    surface_spacing_near(mesh, radius_m, tips_m)
        .map(|h| (fraction * h).max(default))
        .unwrap_or(default)
}

/// Uniform 1 → 8 refinements (`FemProbeSimulator::refined`) of `mesh` for the frictional rigid-tip
/// replay of `tip`: the fewest (at most 2) that bring the mean boundary edge length h to ≤ 0.8 r
/// (r the tip radius; 0 for a mesh tip). Penalty contact and the stick anchors act at surface
/// nodes only, so the stuck patch that drags the surface must span several of them: a 6 mm
/// sphere pressed 2 mm deep (footprint radius ≈ 5 mm) between the nodes of a 6.7 mm fit mesh
/// touches none or one (the suite's probe-friction session: no displacement at 3 of 5 locations).
/// h is measured over the boundary faces with a vertex within 2 r of one of `tips_m` (the tip
/// positions of the replay; a locally refined mesh is fine only there), over the whole surface
/// when there is none.
pub fn friction_refinement(
    mesh: &softcap_mesh::TetMesh,
    tip: &softcap_fem::TipShape,
    tips_m: &[Vector3<f64>],
) -> u32 {
    let Some(r) = tip_radius_m(tip) else {
        return 0;
    };
    let Some(mut h) = surface_spacing_near(mesh, r, tips_m) else {
        return 0;
    };
    let mut levels = 0;
    while h > 0.8 * r && levels < 2 {
        h *= 0.5;
        levels += 1;
    }
    levels
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The surface spacing near a tip is the mean boundary edge of the faces within 2 r of it,
    /// and the frictional replay's slip is the fraction of it (never below the law's 10 µm).
    #[test]
    fn slip_distance_is_a_fraction_of_the_surface_spacing_near_the_tip() {
        // 40 × 40 × 20 mm box, 10 × 10 × 5 cells of 4 mm: boundary edges are 4 mm sides and
        // 4√2 mm face diagonals
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [10, 10, 5]);
        let tip = [Vector3::new(0.02, 0.02, 0.02)];
        let h = surface_spacing_near(&mesh, 0.006, &tip).unwrap();
        assert!(h > 0.004 && h < 0.004 * 2f64.sqrt(), "{h}");
        let eps = friction_slip_distance_m(&mesh, 0.006, &tip, 0.1);
        assert!((eps - 0.1 * h).abs() < 1e-15, "{eps} vs {h}");
        // a finer mesh halves the spacing and the slip
        let fine = softcap_mesh::box_tet_mesh([0.0; 3], [0.04, 0.04, 0.02], [20, 20, 10]);
        let h_fine = surface_spacing_near(&fine, 0.006, &tip).unwrap();
        assert!((h_fine / h - 0.5).abs() < 0.05, "{h_fine} vs {h}");
        // never below the regularized Coulomb law's default
        let floor = softcap_fem::FrictionParams::default().slip_distance_m;
        assert_eq!(friction_slip_distance_m(&mesh, 0.006, &tip, 0.0), floor);
    }
}
