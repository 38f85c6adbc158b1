//! Validity checks for meshes read from files, and small repairs (orientation, units).

use crate::error::{MeshError, Result};
use crate::types::{TetMesh, TriMesh};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Millimetres → metres.
pub const MM_TO_M: f64 = 1e-3;
/// Centimetres → metres.
pub const CM_TO_M: f64 = 1e-2;

/// What [`TetMesh::validate`] and [`TriMesh::validate`] accept.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValidationSettings {
    /// Accept vertices used by no element.
    pub allow_unused_vertices: bool,
    /// An element is degenerate when its measure is below `degenerate_rel_tol · ℓ^d`
    /// (`ℓ` its longest edge, `d` = 2 for triangles, 3 for tets; a regular tet has
    /// `6V/ℓ³ ≈ 0.71`).
    pub degenerate_rel_tol: f64,
}

impl Default for ValidationSettings {
    fn default() -> Self {
        ValidationSettings {
            allow_unused_vertices: false,
            degenerate_rel_tol: 1e-10,
        }
    }
}

fn check_vertices(vertices: &[Vector3<f64>]) -> Result<()> {
    for (v, p) in vertices.iter().enumerate() {
        for axis in 0..3 {
            if !p[axis].is_finite() {
                return Err(MeshError::NonFiniteVertex {
                    vertex: v,
                    axis,
                    value: p[axis],
                });
            }
        }
    }
    Ok(())
}

fn check_indices<const N: usize>(
    elements: &[[usize; N]],
    num_vertices: usize,
) -> Result<Vec<bool>> {
    let mut used = vec![false; num_vertices];
    for (e, el) in elements.iter().enumerate() {
        for (corner, &index) in el.iter().enumerate() {
            if index >= num_vertices {
                return Err(MeshError::IndexOutOfRange {
                    element: e,
                    corner,
                    index,
                    num_vertices,
                });
            }
            if el[..corner].contains(&index) {
                return Err(MeshError::RepeatedVertex { element: e, index });
            }
            used[index] = true;
        }
    }
    Ok(used)
}

fn check_unused(used: &[bool], settings: &ValidationSettings) -> Result<()> {
    if !settings.allow_unused_vertices
        && let Some(vertex) = used.iter().position(|u| !u)
    {
        return Err(MeshError::UnusedVertex { vertex });
    }
    Ok(())
}

pub(crate) fn longest_edge<const N: usize>(x: &[Vector3<f64>; N]) -> f64 {
    let mut l: f64 = 0.0;
    for a in 0..N {
        for b in a + 1..N {
            l = l.max((x[a] - x[b]).norm());
        }
    }
    l
}

impl TetMesh {
    /// Checks, in this order: finite coordinates, at least one tet, indices in range and
    /// distinct per tet, no degenerate tet (`|det| < tol·ℓ³`), no inverted tet (`det < 0`,
    /// `det = (x1−x0)·((x2−x0)×(x3−x0))`), no unused vertex. Returns the first problem found.
    pub fn validate(&self, settings: &ValidationSettings) -> Result<()> {
        check_vertices(&self.vertices)?;
        if self.tets.is_empty() {
            return Err(MeshError::Empty);
        }
        let used = check_indices(&self.tets, self.vertices.len())?;
        for (t, tet) in self.tets.iter().enumerate() {
            let x = tet.map(|i| self.vertices[i]);
            let det = (x[1] - x[0]).dot(&(x[2] - x[0]).cross(&(x[3] - x[0])));
            let tolerance = settings.degenerate_rel_tol * longest_edge(&x).powi(3);
            if det.abs() <= tolerance {
                return Err(MeshError::DegenerateElement {
                    element: t,
                    measure: det / 6.0,
                    tolerance: tolerance / 6.0,
                });
            }
            if det < 0.0 {
                return Err(MeshError::InvertedElement { tet: t, det });
            }
        }
        check_unused(&used, settings)
    }

    /// Makes every tet positively oriented by swapping its last two vertices where the signed
    /// volume is negative; returns how many were flipped.
    pub fn orient_positive(&mut self) -> usize {
        let mut flipped = 0;
        for t in 0..self.tets.len() {
            if self.tet_volume(t) < 0.0 {
                self.tets[t].swap(2, 3);
                flipped += 1;
            }
        }
        flipped
    }

    /// Multiplies every coordinate by `factor` (e.g. [`MM_TO_M`]).
    pub fn scale(&mut self, factor: f64) {
        for v in &mut self.vertices {
            *v *= factor;
        }
    }
}

impl TriMesh {
    /// Checks finite coordinates, at least one triangle, indices in range and distinct,
    /// no degenerate triangle (`area < tol·ℓ²`), and no unused vertex.
    pub fn validate(&self, settings: &ValidationSettings) -> Result<()> {
        check_vertices(&self.vertices)?;
        if self.triangles.is_empty() {
            return Err(MeshError::Empty);
        }
        let used = check_indices(&self.triangles, self.vertices.len())?;
        for (t, tri) in self.triangles.iter().enumerate() {
            let x = tri.map(|i| self.vertices[i]);
            let area = 0.5 * (x[1] - x[0]).cross(&(x[2] - x[0])).norm();
            let tolerance = settings.degenerate_rel_tol * longest_edge(&x).powi(2);
            if area <= tolerance {
                return Err(MeshError::DegenerateElement {
                    element: t,
                    measure: area,
                    tolerance,
                });
            }
        }
        check_unused(&used, settings)
    }

    /// Multiplies every coordinate by `factor` (e.g. [`CM_TO_M`]).
    pub fn scale(&mut self, factor: f64) {
        for v in &mut self.vertices {
            *v *= factor;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::structured::box_tet_mesh;

    #[test]
    fn each_problem_is_named() {
        let s = ValidationSettings::default();
        let good = box_tet_mesh([0.0; 3], [1.0; 3], [2, 1, 1]);
        good.validate(&s).unwrap();

        let mut m = good.clone();
        m.vertices[3].y = f64::NAN;
        assert!(matches!(
            m.validate(&s),
            Err(MeshError::NonFiniteVertex {
                vertex: 3,
                axis: 1,
                ..
            })
        ));

        let mut m = good.clone();
        m.tets[4][2] = 99;
        assert!(matches!(
            m.validate(&s),
            Err(MeshError::IndexOutOfRange {
                element: 4,
                corner: 2,
                index: 99,
                ..
            })
        ));

        let mut m = good.clone();
        m.tets[1][3] = m.tets[1][0];
        assert!(matches!(
            m.validate(&s),
            Err(MeshError::RepeatedVertex { element: 1, .. })
        ));

        let mut m = good.clone();
        m.tets[7].swap(0, 1);
        match m.validate(&s) {
            Err(MeshError::InvertedElement { tet: 7, det }) => {
                assert!((det + 0.5).abs() < 1e-12, "{det}")
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(m.orient_positive(), 1);
        m.validate(&s).unwrap();

        let mut m = good.clone();
        let t = m.tets[2];
        // Put vertex 3 of tet 2 onto the plane of the other three: flat tet.
        let [a, b, c] = [t[0], t[1], t[2]].map(|i| m.vertices[i]);
        m.vertices.push((a + b + c) / 3.0);
        let n = m.vertices.len() - 1;
        m.tets[2][3] = n;
        assert!(matches!(
            m.validate(&s),
            Err(MeshError::DegenerateElement { element: 2, .. })
        ));

        let mut m = good.clone();
        m.vertices.push(Vector3::new(5.0, 5.0, 5.0));
        assert!(matches!(
            m.validate(&s),
            Err(MeshError::UnusedVertex { vertex: 12 })
        ));
        let lax = ValidationSettings {
            allow_unused_vertices: true,
            ..s.clone()
        };
        m.validate(&lax).unwrap();
    }
}
