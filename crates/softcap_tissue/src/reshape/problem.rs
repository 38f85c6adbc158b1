//! The inputs of a reshape in memory (SI units): the template, its landmarks, ICP markers and
//! attachments (saito-barbic §3.1), and the closest points of ICP markers on a deformed surface.

use nalgebra::Vector3;
use parry3d::math::Vector as PVector;
use parry3d::query::PointQueryWithLocation;
use parry3d::shape::TriMesh as ParryTriMesh;
use serde::{Deserialize, Serialize};
use softcap_mesh::TetMesh;

/// A material point of the mesh: a combination of up to four nodes (a tet's barycentric
/// coordinates, a surface triangle's, or one node).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaterialPoint {
    /// Nodes (unused slots repeat node 0 with weight 0).
    pub nodes: [usize; 4],
    /// Weights (sum 1).
    pub weights: [f64; 4],
}

impl MaterialPoint {
    /// The node itself.
    pub fn node(n: usize) -> Self {
        Self {
            nodes: [n; 4],
            weights: [1.0, 0.0, 0.0, 0.0],
        }
    }

    /// Position at node positions `x`.
    pub fn at(&self, x: &[Vector3<f64>]) -> Vector3<f64> {
        (0..4).map(|k| x[self.nodes[k]] * self.weights[k]).sum()
    }
}

/// Which input a constraint comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ConstraintKind {
    /// A template node tied by a stiff spring to another object (§3.1).
    Attachment,
    /// A template point with a known target (correspondence).
    Landmark,
    /// A target point that must lie on the surface (no correspondence).
    Icp,
}

impl ConstraintKind {
    /// Name in reports and MCAP.
    pub fn name(self) -> &'static str {
        match self {
            Self::Attachment => "attachment",
            Self::Landmark => "landmark",
            Self::Icp => "icp",
        }
    }
}

/// A landmark: the template point `point` must move to `target_m`.
#[derive(Clone, Debug, PartialEq)]
pub struct Landmark {
    /// Id from the input.
    pub id: String,
    /// Template point (embedded in its tet).
    pub point: MaterialPoint,
    /// Target position \[m\].
    pub target_m: Vector3<f64>,
}

/// An ICP marker: a point on the subject's boundary.
#[derive(Clone, Debug, PartialEq)]
pub struct IcpMarker {
    /// Id from the input.
    pub id: String,
    /// Position \[m\].
    pub position_m: Vector3<f64>,
}

/// An attachment: template node `node` tied to `target_m`.
#[derive(Clone, Debug, PartialEq)]
pub struct Attachment {
    /// Id from the input (the node index as written).
    pub id: String,
    /// Template node.
    pub node: usize,
    /// Target position \[m\].
    pub target_m: Vector3<f64>,
}

/// A reshape problem in SI units.
#[derive(Clone, Debug, PartialEq)]
pub struct ReshapeProblem {
    /// Template tet mesh \[m\], positively oriented.
    pub template: TetMesh,
    /// Landmarks.
    pub landmarks: Vec<Landmark>,
    /// ICP markers.
    pub icp_markers: Vec<IcpMarker>,
    /// Attachments (empty for a free-flying object).
    pub attachments: Vec<Attachment>,
    /// No attachments: solve with the rigid gauge of §3.6.
    pub free_flying: bool,
    /// The part of the template's boundary the ICP markers lie on (triangles of template nodes);
    /// `None`: the whole boundary (an organ seen all round, as in saito-barbic §3.1). A layer cut
    /// from a body (a skin layer) is seen on one side only: closest points on its inner or cut
    /// surfaces would tie those to the subject's skin.
    pub icp_surface: Option<Vec<[usize; 3]>>,
}

/// Closest points on the boundary of a deformed tet mesh (parry3d's triangle-mesh projection).
pub struct SurfaceProjector {
    shape: Option<ParryTriMesh>,
    faces: Vec<[usize; 3]>,
}

impl SurfaceProjector {
    /// Projector onto the boundary triangles `faces` (volume node indices) at positions `x`.
    pub fn new(faces: &[[usize; 3]], x: &[Vector3<f64>]) -> Self {
        let vertices: Vec<PVector> = x.iter().map(|p| PVector::new(p.x, p.y, p.z)).collect();
        let indices: Vec<[u32; 3]> = faces.iter().map(|f| f.map(|v| v as u32)).collect();
        Self {
            shape: ParryTriMesh::new(vertices, indices).ok(),
            faces: faces.to_vec(),
        }
    }

    /// The closest boundary point to `p` as a material point and its distance.
    pub fn project(&self, p: &Vector3<f64>) -> Option<(MaterialPoint, f64)> {
        let shape = self.shape.as_ref()?;
        let q = PVector::new(p.x, p.y, p.z);
        let (proj, (tri, location)) = shape.project_local_point_and_get_location(q, false);
        let bary = location.barycentric_coordinates()?;
        let face = *self.faces.get(tri as usize)?;
        let d = (proj.point - q).length();
        Some((
            MaterialPoint {
                nodes: [face[0], face[1], face[2], face[0]],
                weights: [bary[0], bary[1], bary[2], 0.0],
            },
            d,
        ))
    }
}
