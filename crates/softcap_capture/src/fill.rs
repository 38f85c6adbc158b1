//! Fill-in of occluded markers with the linear shell of thesis §6.2.2 / eq. 3.3
//! (Botsch & Sorkine 2007): the displacement field `u` on the template surface minimises
//! stretching and bending, `−k_s Δu + k_b Δ²u = 0`, with the displacements of the visible markers
//! (and zero displacement of the vertices attached to the support) as boundary constraints; the
//! occluded markers take the field's value.
//!
//! The shell itself is `softcap_mesh::LinearShell` (cotangent Laplacian, Voronoi areas, sparse
//! Cholesky). Markers generally do not sit on template vertices, so each marker is first inserted
//! into the template surface (its closest point splits the closest triangle 1→3, or snaps to a
//! vertex within `snap_fraction` of the local edge length); marker vertices are then handles
//! whenever the marker is visible.

use nalgebra::{Point3, Vector3};
use softcap_mesh::{LinearShell, ShellSettings, TriMesh};

use crate::error::{CaptureError, Result};
use crate::session::Session;

/// Settings of the fill-in.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FillSettings {
    /// Stretching stiffness `k_s` (per m² of `k_b`; see `softcap_mesh::ShellSettings`).
    pub k_stretch: f64,
    /// Bending stiffness `k_b`, m².
    pub k_bend: f64,
    /// Snap a marker to an existing vertex closer than this fraction of the triangle's mean edge.
    pub snap_fraction: f64,
}

impl Default for FillSettings {
    fn default() -> Self {
        FillSettings {
            k_stretch: 0.0,
            k_bend: 1e-4,
            snap_fraction: 0.05,
        }
    }
}

/// A marker embedded in a surface triangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Embedding {
    /// Triangle vertex indices.
    pub vertices: [usize; 3],
    /// Barycentric weights.
    pub weights: [f64; 3],
}

/// Closest point on a triangle as barycentric weights: the one kernel in `softcap_mesh`.
pub use softcap_mesh::embed::closest_point_on_triangle as closest_barycentric;

/// Embeds points in their closest triangles.
pub fn embed(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    points: &[Point3<f64>],
) -> Vec<Embedding> {
    points
        .iter()
        .map(|p| {
            let mut best = (
                f64::INFINITY,
                Embedding {
                    vertices: [0; 3],
                    weights: [1.0, 0.0, 0.0],
                },
            );
            for t in triangles {
                let [a, b, c] = t.map(|i| vertices[i]);
                let w = closest_barycentric(&p.coords, &a, &b, &c);
                let q = a * w[0] + b * w[1] + c * w[2];
                let d = (q - p.coords).norm_squared();
                if d < best.0 {
                    best = (
                        d,
                        Embedding {
                            vertices: *t,
                            weights: w,
                        },
                    );
                }
            }
            best.1
        })
        .collect()
}

/// Inserts points into a triangle mesh: each point's closest point on the surface becomes a
/// vertex (1→3 split of its closest triangle, or snap to a vertex closer than `snap_fraction` of
/// that triangle's mean edge length). Returns the vertex index of each point.
pub fn insert_points(mesh: &mut TriMesh, points: &[Point3<f64>], snap_fraction: f64) -> Vec<usize> {
    let mut out = Vec::with_capacity(points.len());
    for p in points {
        let e = embed(&mesh.vertices, &mesh.triangles, std::slice::from_ref(p))[0];
        let t = mesh
            .triangles
            .iter()
            .position(|t| *t == e.vertices)
            .unwrap_or(0);
        let [a, b, c] = e.vertices.map(|i| mesh.vertices[i]);
        let q = a * e.weights[0] + b * e.weights[1] + c * e.weights[2];
        let mean_edge = ((b - a).norm() + (c - b).norm() + (a - c).norm()) / 3.0;
        let (k, dmin) = (0..3)
            .map(|k| (k, (mesh.vertices[e.vertices[k]] - q).norm()))
            .min_by(|x, y| x.1.total_cmp(&y.1))
            .unwrap_or((0, f64::INFINITY));
        if dmin <= snap_fraction * mean_edge && !out.contains(&e.vertices[k]) {
            out.push(e.vertices[k]);
            continue;
        }
        let v = mesh.vertices.len();
        mesh.vertices.push(q);
        let [i, j, k] = e.vertices;
        mesh.triangles[t] = [i, j, v];
        mesh.triangles.push([j, k, v]);
        mesh.triangles.push([k, i, v]);
        out.push(v);
    }
    out
}

/// The template surface prepared for fill-in.
#[derive(Debug, Clone)]
pub struct FillShell {
    laplacian: faer::sparse::SparseColMat<usize, f64>,
    areas: Vec<f64>,
    marker_vertex: Vec<usize>,
    fixed: Vec<usize>,
    rest_m: Vec<Point3<f64>>,
    settings: ShellSettings,
}

impl FillShell {
    /// Prepares the shell on `surface_m` (metres) for markers at `markers_rest_m`; `fixed` lists
    /// surface vertices held at zero displacement (attached to the support).
    pub fn new(
        surface_m: &TriMesh,
        markers_rest_m: &[Point3<f64>],
        fixed: &[usize],
        settings: &FillSettings,
    ) -> Result<Self> {
        let mut mesh = surface_m.clone();
        let marker_vertex = insert_points(&mut mesh, markers_rest_m, settings.snap_fraction);
        let lap = softcap_mesh::CotanLaplacian::new(&mesh).map_err(|e| CaptureError::Format {
            path: "template surface".into(),
            message: format!("cotangent Laplacian: {e}"),
        })?;
        let mut fixed: Vec<usize> = fixed
            .iter()
            .copied()
            .filter(|v| !marker_vertex.contains(v))
            .collect();
        fixed.sort_unstable();
        fixed.dedup();
        Ok(FillShell {
            laplacian: lap.stiffness,
            areas: lap.areas,
            marker_vertex,
            fixed,
            rest_m: markers_rest_m.to_vec(),
            settings: ShellSettings {
                k_s: settings.k_stretch,
                k_b: settings.k_bend,
            },
        })
    }

    /// Builds the shell for a session from its template surface (`files.surface`), with the
    /// vertices on the support plane (`[support]`) held fixed. `None` without a surface.
    pub fn for_session(session: &Session, settings: &FillSettings) -> Result<Option<FillShell>> {
        let Some(path) = &session.surface else {
            return Ok(None);
        };
        let mut mesh = softcap_mesh::read_obj_tri_mesh(path).map_err(|e| CaptureError::Format {
            path: path.clone(),
            message: e.to_string(),
        })?;
        for v in mesh.vertices.iter_mut() {
            *v *= session.metres_per_unit;
        }
        let fixed: Vec<usize> = match &session.support {
            Some(s) => (0..mesh.vertices.len())
                .filter(|&i| {
                    s.plane_normal.dot(&mesh.vertices[i]) <= s.plane_offset_m + s.tolerance_m
                })
                .collect(),
            None => Vec::new(),
        };
        let rest: Vec<Point3<f64>> = session.markers.iter().map(|m| m.position_m).collect();
        Self::new(&mesh, &rest, &fixed, settings)
            .map(Some)
            .map_err(|e| match e {
                CaptureError::Format { message, .. } => CaptureError::Format {
                    path: path.clone(),
                    message,
                },
                e => e,
            })
    }

    /// Given the current positions of the visible markers (`None` for occluded ones), returns every
    /// marker's position: visible ones unchanged, occluded ones from the shell's displacement field.
    pub fn fill(&self, known_m: &[Option<Point3<f64>>]) -> Result<Vec<Point3<f64>>> {
        let mut handles = self.fixed.clone();
        let mut disp = vec![Vector3::zeros(); handles.len()];
        for (j, k) in known_m.iter().enumerate() {
            if let Some(p) = k {
                handles.push(self.marker_vertex[j]);
                disp.push(p - self.rest_m[j]);
            }
        }
        let shell = LinearShell::new(
            self.laplacian.as_ref(),
            &self.areas,
            &handles,
            &self.settings,
        )
        .map_err(|e| CaptureError::Format {
            path: "template surface".into(),
            message: format!("linear shell: {e}"),
        })?;
        let u = shell.solve(&disp).map_err(|e| CaptureError::Format {
            path: "template surface".into(),
            message: format!("linear shell: {e}"),
        })?;
        Ok(known_m
            .iter()
            .enumerate()
            .map(|(j, k)| k.unwrap_or(self.rest_m[j] + u[self.marker_vertex[j]]))
            .collect())
    }
}
