//! A tet layer under a surface (a soft-tissue layer from a skin surface): the surface offset along
//! its smoothed inward vertex normals in equal steps, each triangle × step a prism, each prism split
//! into three tets.
//!
//! Prism split: with the triangle's corners sorted by global vertex index v₀ < v₁ < v₂, outer
//! corners P_i and inner corners Q_i, the tets are (P₀,P₁,P₂,Q₀), (P₁,P₂,Q₀,Q₁), (P₂,Q₀,Q₁,Q₂).
//! Every side quad (P_i, P_j, Q_j, Q_i), i < j, is then cut along P_j–Q_i — a rule that depends
//! only on the quad's own two surface vertices, so neighbouring prisms agree and the mesh is
//! conforming (the index-order rule of Dompierre et al. 1999, "How to subdivide pyramids, prisms
//! and hexahedra into tetrahedra").
//!
//! Vertex numbering: layer k (k = 0 the surface itself) holds vertices k·N .. (k+1)·N − 1 in the
//! surface's order, so surface vertex i is volume vertex i.

use crate::error::{MeshError, Result};
use crate::types::{TetMesh, TriMesh};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// How [`extrude_layer`] builds the layer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LayerSettings {
    /// Total thickness along the inward normal, in the surface's units (> 0).
    pub thickness: f64,
    /// Number of tet layers (≥ 1).
    pub layers: usize,
    /// Rounds of one-ring averaging of the vertex normals (smooths the offset direction so thin
    /// features such as lips and nostrils do not fold).
    pub normal_smoothing: usize,
}

impl Default for LayerSettings {
    fn default() -> Self {
        Self {
            thickness: 1.0,
            layers: 1,
            normal_smoothing: 4,
        }
    }
}

/// Unit outward vertex normals (area-weighted, counter-clockwise triangles), smoothed by
/// `rounds` of one-ring averaging.
pub fn smoothed_vertex_normals(surface: &TriMesh, rounds: usize) -> Vec<Vector3<f64>> {
    let mut n = vec![Vector3::zeros(); surface.vertices.len()];
    for t in &surface.triangles {
        let [a, b, c] = t.map(|i| surface.vertices[i]);
        let area_normal = (b - a).cross(&(c - a));
        for &v in t {
            n[v] += area_normal;
        }
    }
    let normalize = |n: &mut Vec<Vector3<f64>>| {
        for v in n.iter_mut() {
            let len = v.norm();
            if len > 0.0 {
                *v /= len;
            }
        }
    };
    normalize(&mut n);
    let rings = surface.one_rings();
    for _ in 0..rounds {
        let mut next = n.clone();
        for (v, ring) in rings.iter().enumerate() {
            for &w in ring {
                next[v] += n[w];
            }
        }
        n = next;
        normalize(&mut n);
    }
    n
}

/// The tet layer of `settings.thickness` under `surface` (see the module docs). Fails with
/// [`MeshError::InvertedElement`] naming the first tet of a prism that folds (the thickness exceeds
/// the local radius of curvature there), or [`MeshError::Empty`] for a surface without triangles.
pub fn extrude_layer(surface: &TriMesh, settings: &LayerSettings) -> Result<TetMesh> {
    if surface.triangles.is_empty() {
        return Err(MeshError::Empty);
    }
    if !(settings.thickness > 0.0 && settings.thickness.is_finite()) || settings.layers == 0 {
        return Err(MeshError::Refinement {
            message: format!(
                "layer thickness {} and count {} must be positive",
                settings.thickness, settings.layers
            ),
        });
    }
    let n = surface.vertices.len();
    let normals = smoothed_vertex_normals(surface, settings.normal_smoothing);
    let step = settings.thickness / settings.layers as f64;
    let mut vertices = Vec::with_capacity(n * (settings.layers + 1));
    for k in 0..=settings.layers {
        vertices.extend(
            surface
                .vertices
                .iter()
                .zip(&normals)
                .map(|(v, nv)| v - nv * (step * k as f64)),
        );
    }
    let mut tets = Vec::with_capacity(3 * surface.triangles.len() * settings.layers);
    for k in 0..settings.layers {
        for tri in &surface.triangles {
            let mut sorted = *tri;
            sorted.sort_unstable();
            // An odd permutation of a counter-clockwise triangle flips the prism's orientation.
            let even = (0..3).any(|r| [tri[r], tri[(r + 1) % 3], tri[(r + 2) % 3]] == sorted);
            let p = sorted.map(|v| v + k * n);
            let q = sorted.map(|v| v + (k + 1) * n);
            // Offsetting inward under a counter-clockwise (outward) triangle gives det < 0 for
            // the even ordering.
            let expected_negative = even;
            for mut tet in [
                [p[0], p[1], p[2], q[0]],
                [p[1], p[2], q[0], q[1]],
                [p[2], q[0], q[1], q[2]],
            ] {
                let x = tet.map(|i| vertices[i]);
                let det = (x[1] - x[0]).dot(&(x[2] - x[0]).cross(&(x[3] - x[0])));
                if det == 0.0 || (det < 0.0) != expected_negative {
                    return Err(MeshError::InvertedElement {
                        tet: tets.len(),
                        det,
                    });
                }
                if det < 0.0 {
                    tet.swap(2, 3);
                }
                tets.push(tet);
            }
        }
    }
    Ok(TetMesh { vertices, tets })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ValidationSettings;

    #[test]
    fn a_sphere_shell_layer_is_conforming_with_the_expected_volume() {
        let sphere = crate::icosphere(2);
        let mesh = extrude_layer(
            &sphere,
            &LayerSettings {
                thickness: 0.2,
                layers: 2,
                normal_smoothing: 0,
            },
        )
        .unwrap();
        mesh.validate(&ValidationSettings::default()).unwrap();
        assert_eq!(mesh.tets.len(), 3 * 2 * sphere.triangles.len());
        // Conforming: every interior face is shared by exactly two tets, so the boundary is the
        // outer and the inner sphere only.
        assert_eq!(mesh.boundary_faces().len(), 2 * sphere.triangles.len());
        // Volume of the polyhedral shell between radius 1 and 0.8 (inscribed, ≈ 4/3 π (1 − 0.8³)).
        let exact = 4.0 / 3.0 * std::f64::consts::PI * (1.0 - 0.8f64.powi(3));
        assert!(
            (mesh.volume() - exact).abs() < 0.05 * exact,
            "{}",
            mesh.volume()
        );
        for (i, v) in sphere.vertices.iter().enumerate() {
            assert_eq!(mesh.vertices[i], *v);
        }
    }

    #[test]
    fn a_thickness_beyond_the_curvature_radius_is_rejected() {
        let sphere = crate::icosphere(1);
        let err = extrude_layer(
            &sphere,
            &LayerSettings {
                thickness: 2.5,
                layers: 1,
                normal_smoothing: 0,
            },
        );
        assert!(
            matches!(err, Err(MeshError::InvertedElement { .. })),
            "{err:?}"
        );
    }
}
