//! Ray casting against a (deformed) triangle surface through parry3d's BVH-accelerated
//! `TriMesh`: what a depth camera sees (the virtual rig renders depth images with it) and whether
//! a surface point is hidden from a viewpoint (the dynamic tracker's visibility test).
//!
//! The caster is rebuilt for every new set of vertex positions (building the tree of a few
//! thousand triangles takes well under a millisecond); queries are `&self` and can run in
//! parallel.

use nalgebra::Vector3;
use parry3d::math::Vector as PVec;
use parry3d::query::{Ray, RayCast};
use parry3d::shape::{TriMesh as ParryTriMesh, TriMeshFlags};

use crate::error::{MeshError, Result};

/// The first intersection of a ray with the surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayHit {
    /// Ray parameter t of the hit (distance along the ray for a unit direction).
    pub t: f64,
    /// Index of the triangle that was hit.
    pub triangle: usize,
    /// Unit normal of that triangle (counter-clockwise orientation: outward for a boundary
    /// surface), whichever side the ray came from.
    pub normal: Vector3<f64>,
}

/// A triangle surface prepared for ray queries.
pub struct SurfaceRayCaster {
    mesh: ParryTriMesh,
    normals: Vec<Vector3<f64>>,
}

impl std::fmt::Debug for SurfaceRayCaster {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SurfaceRayCaster")
            .field("triangles", &self.normals.len())
            .finish()
    }
}

fn to_parry(v: &Vector3<f64>) -> PVec {
    PVec::new(v.x, v.y, v.z)
}

impl SurfaceRayCaster {
    /// Builds the caster over `vertices` (m) and `triangles`. Degenerate triangles are kept (they
    /// are never hit); an empty or out-of-range triangle list is an error.
    pub fn new(vertices: &[Vector3<f64>], triangles: &[[usize; 3]]) -> Result<Self> {
        if triangles.is_empty() {
            return Err(MeshError::Empty);
        }
        for (element, t) in triangles.iter().enumerate() {
            if let Some(corner) = t.iter().position(|&i| i >= vertices.len()) {
                return Err(MeshError::IndexOutOfRange {
                    element,
                    corner,
                    index: t[corner],
                    num_vertices: vertices.len(),
                });
            }
        }
        let normals = triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| vertices[i]);
                let n = (b - a).cross(&(c - a));
                let l = n.norm();
                if l > 0.0 { n / l } else { Vector3::zeros() }
            })
            .collect();
        let mesh = ParryTriMesh::with_flags(
            vertices.iter().map(to_parry).collect(),
            triangles.iter().map(|t| t.map(|i| i as u32)).collect(),
            TriMeshFlags::empty(),
        )
        .map_err(|e| MeshError::format("ray caster", e.to_string()))?;
        Ok(Self { mesh, normals })
    }

    /// First hit of the ray `origin + t·direction`, 0 < t ≤ `max_t`, if any.
    pub fn cast(
        &self,
        origin: &Vector3<f64>,
        direction: &Vector3<f64>,
        max_t: f64,
    ) -> Option<RayHit> {
        let ray = Ray::new(to_parry(origin), to_parry(direction));
        let hit = self
            .mesh
            .cast_local_ray_and_get_normal(&ray, max_t, false)?;
        // parry 0.31: `subshape` is the triangle of the mesh, `feature` the triangle's own face.
        let triangle = hit.subshape as usize;
        Some(RayHit {
            t: hit.time_of_impact,
            triangle,
            normal: self.normals[triangle],
        })
    }

    /// True if the segment from `from` to `to` crosses the surface before reaching within
    /// `tolerance` (m) of `to`: `to` is hidden from `from`.
    pub fn occluded(&self, from: &Vector3<f64>, to: &Vector3<f64>, tolerance: f64) -> bool {
        let d = to - from;
        let len = d.norm();
        if len <= tolerance {
            return false;
        }
        self.cast(from, &(d / len), len - tolerance).is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::box_tet_mesh;

    fn unit_box() -> (Vec<Vector3<f64>>, Vec<[usize; 3]>) {
        let m = box_tet_mesh([0.0; 3], [1.0, 1.0, 1.0], [2, 2, 2]);
        let faces = m.boundary_faces();
        (m.vertices, faces)
    }

    #[test]
    fn ray_hits_the_near_face_with_its_outward_normal() {
        let (v, f) = unit_box();
        let rc = SurfaceRayCaster::new(&v, &f).unwrap();
        let o = Vector3::new(0.3, 0.4, 5.0);
        let hit = rc.cast(&o, &Vector3::new(0.0, 0.0, -1.0), 100.0).unwrap();
        assert!((hit.t - 4.0).abs() < 1e-12, "{hit:?}");
        assert!((hit.normal - Vector3::z()).norm() < 1e-12);
        // The far (bottom) face is occluded from above, the top face is not.
        assert!(rc.occluded(&o, &Vector3::new(0.3, 0.4, 0.0), 1e-6));
        assert!(!rc.occluded(&o, &Vector3::new(0.3, 0.4, 1.0), 1e-6));
        // A ray that misses.
        assert!(rc.cast(&o, &Vector3::new(1.0, 0.0, 0.0), 100.0).is_none());
    }
}
