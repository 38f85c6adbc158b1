//! Barycentric embedding of points in tet meshes and triangle surfaces.
//!
//! A point inside the mesh gets the tet containing it and its barycentric weights
//! `λ` (`Σλ = 1`, `Σ λ_k x_k = p`). A point outside gets the closest element and its distance;
//! for tets the weights are still the (extrapolated) barycentric coordinates of `p` in that tet,
//! so `Σ λ_k x_k = p` holds exactly and the point follows the tet's affine deformation, as
//! markers embedded in a simulation mesh do. For triangles the weights are those of the closest
//! surface point. Queries use an AABB tree ([`Bvh`]).

use crate::bvh::Bvh;
use crate::types::{TetMesh, TriMesh};
use nalgebra::{Matrix3, Vector3};

/// Where a point sits in a tet mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TetEmbedding {
    /// Index of the containing (or closest) tet.
    pub tet: usize,
    /// Barycentric coordinates of the point in that tet (sum to 1; negative entries when the
    /// point is outside the tet).
    pub weights: [f64; 4],
    /// Distance from the point to the tet (0 inside).
    pub distance: f64,
}

impl TetEmbedding {
    /// `Σ λ_k x_k` for (possibly deformed) vertex positions.
    pub fn position(&self, tets: &[[usize; 4]], vertices: &[Vector3<f64>]) -> Vector3<f64> {
        let t = tets[self.tet];
        (0..4).map(|k| vertices[t[k]] * self.weights[k]).sum()
    }
}

/// Where a point projects onto a triangle surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriEmbedding {
    /// Index of the closest triangle.
    pub triangle: usize,
    /// Barycentric coordinates (non-negative, sum 1) of the closest surface point.
    pub weights: [f64; 3],
    /// Distance from the point to the surface.
    pub distance: f64,
}

impl TriEmbedding {
    /// `Σ λ_k x_k`, the closest surface point for (possibly deformed) vertex positions.
    pub fn position(&self, triangles: &[[usize; 3]], vertices: &[Vector3<f64>]) -> Vector3<f64> {
        let t = triangles[self.triangle];
        (0..3).map(|k| vertices[t[k]] * self.weights[k]).sum()
    }
}

/// Barycentric coordinates of `p` in tet `x` (`None` for a degenerate tet):
/// `λ_{1..3} = [x1−x0, x2−x0, x3−x0]⁻¹ (p − x0)`, `λ_0 = 1 − λ_1 − λ_2 − λ_3`.
pub fn tet_barycentric(x: &[Vector3<f64>; 4], p: &Vector3<f64>) -> Option<[f64; 4]> {
    let m = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
    let l = m.lu().solve(&(p - x[0]))?;
    if !l.iter().all(|v| v.is_finite()) {
        return None;
    }
    Some([1.0 - l[0] - l[1] - l[2], l[0], l[1], l[2]])
}

/// Closest point on triangle `(a, b, c)` to `p`, as barycentric weights (Ericson, *Real-Time
/// Collision Detection*, §5.1.5, Voronoi-region tests).
pub fn closest_point_on_triangle(
    p: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
) -> [f64; 3] {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    [1.0 - v - w, v, w]
}

/// Intersection of the line `o + t·d` with triangle `tri` (Möller & Trumbore 1997,
/// two-sided): the line parameter t (any sign) and the barycentric weights of the hit
/// `[1 − u − v, u, v]`. Points up to 1e-12 (barycentric) outside an edge count as hits, so a
/// line through a shared edge is never lost between its two triangles (the weights can then
/// be off [0, 1] by that much). `None` when the line misses or is parallel to the plane.
pub fn line_triangle(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    tri: &[Vector3<f64>; 3],
) -> Option<(f64, [f64; 3])> {
    let e1 = tri[1] - tri[0];
    let e2 = tri[2] - tri[0];
    let p = d.cross(&e2);
    let det = e1.dot(&p);
    if det.abs() < 1e-14 * e1.norm() * e2.norm() {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - tri[0];
    let u = s.dot(&p) * inv;
    if !(-1e-12..=1.0 + 1e-12).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = d.dot(&q) * inv;
    if v < -1e-12 || u + v > 1.0 + 1e-12 {
        return None;
    }
    Some((e2.dot(&q) * inv, [1.0 - u - v, u, v]))
}

fn bounds<const N: usize>(x: [Vector3<f64>; N]) -> (Vector3<f64>, Vector3<f64>) {
    let mut lo = x[0];
    let mut hi = x[0];
    for p in &x[1..] {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    (lo, hi)
}

/// Point location in a tet mesh (build once, query many).
#[derive(Clone, Debug)]
pub struct TetLocator<'a> {
    mesh: &'a TetMesh,
    bvh: Bvh,
}

impl<'a> TetLocator<'a> {
    /// Builds the AABB tree over the tets of `mesh`.
    pub fn new(mesh: &'a TetMesh) -> Self {
        let boxes: Vec<_> = mesh
            .tets
            .iter()
            .map(|t| bounds(t.map(|i| mesh.vertices[i])))
            .collect();
        TetLocator {
            mesh,
            bvh: Bvh::new(&boxes),
        }
    }

    fn distance(&self, t: usize, p: &Vector3<f64>) -> (f64, Option<[f64; 4]>) {
        let x = self.mesh.tets[t].map(|i| self.mesh.vertices[i]);
        let Some(l) = tet_barycentric(&x, p) else {
            return (f64::INFINITY, None);
        };
        if l.iter().all(|&v| v >= 0.0) {
            return (0.0, Some(l));
        }
        let mut d2 = f64::INFINITY;
        for f in crate::adjacency::TET_FACE_OPPOSITE {
            let w = closest_point_on_triangle(p, &x[f[0]], &x[f[1]], &x[f[2]]);
            let q = x[f[0]] * w[0] + x[f[1]] * w[1] + x[f[2]] * w[2];
            d2 = d2.min((p - q).norm_squared());
        }
        (d2.sqrt(), Some(l))
    }

    /// Embeds `p`: the containing tet (distance 0) or the closest one. `None` only when the
    /// mesh has no non-degenerate tet.
    pub fn locate(&self, p: &Vector3<f64>) -> Option<TetEmbedding> {
        let (tet, distance) = self.bvh.closest(p, |t| self.distance(t, p).0)?;
        let weights = self.distance(tet, p).1?;
        Some(TetEmbedding {
            tet,
            weights,
            distance,
        })
    }
}

/// Closest-point queries on a triangle surface (build once, query many).
#[derive(Clone, Debug)]
pub struct TriLocator<'a> {
    mesh: &'a TriMesh,
    bvh: Bvh,
}

impl<'a> TriLocator<'a> {
    /// Builds the AABB tree over the triangles of `mesh`.
    pub fn new(mesh: &'a TriMesh) -> Self {
        let boxes: Vec<_> = mesh
            .triangles
            .iter()
            .map(|t| bounds(t.map(|i| mesh.vertices[i])))
            .collect();
        TriLocator {
            mesh,
            bvh: Bvh::new(&boxes),
        }
    }

    fn weights(&self, t: usize, p: &Vector3<f64>) -> ([f64; 3], f64) {
        let x = self.mesh.triangles[t].map(|i| self.mesh.vertices[i]);
        let w = closest_point_on_triangle(p, &x[0], &x[1], &x[2]);
        let q = x[0] * w[0] + x[1] * w[1] + x[2] * w[2];
        (w, (p - q).norm())
    }

    /// The closest surface point to `p`. `None` only for a mesh without triangles.
    pub fn locate(&self, p: &Vector3<f64>) -> Option<TriEmbedding> {
        let (triangle, distance) = self.bvh.closest(p, |t| self.weights(t, p).1)?;
        Some(TriEmbedding {
            triangle,
            weights: self.weights(triangle, p).0,
            distance,
        })
    }
}

/// Embeds every point in `mesh` (see [`TetLocator`]); `None` entries only for meshes without
/// valid tets.
pub fn embed_in_tets(mesh: &TetMesh, points: &[Vector3<f64>]) -> Vec<Option<TetEmbedding>> {
    let loc = TetLocator::new(mesh);
    points.iter().map(|p| loc.locate(p)).collect()
}

/// Projects every point onto `mesh` (see [`TriLocator`]).
pub fn embed_on_triangles(mesh: &TriMesh, points: &[Vector3<f64>]) -> Vec<Option<TriEmbedding>> {
    let loc = TriLocator::new(mesh);
    points.iter().map(|p| loc.locate(p)).collect()
}
