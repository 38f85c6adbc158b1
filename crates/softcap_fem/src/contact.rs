//! Rigid probe contact (bickel2009 §3.4): a rigid tip placed by a pose, node-to-probe penetration
//! queries through parry3d, and a penalty "linear force field at each colliding point".
//!
//! **Formulation.** Every candidate node (by default: the boundary nodes) is tested against the
//! probe. A node x inside the probe gets the closest boundary point c and outward normal
//! n = (c − x)/‖c − x‖ (parry's `project_local_point`), and a linear spring acting along n only
//! (frictionless):
//!
//! f_c = k_c n nᵀ (c − x),  ∂f_c/∂x = −k_c n nᵀ,
//!
//! with (c, n) frozen within an equilibrium iteration and re-queried at the next one (active set
//! = penetrating nodes, re-evaluated each iteration). The penalty k_c is scale-free: it is
//! `penalty_factor` × the node's mean diagonal stiffness (taken once per equilibrium solve), so the
//! residual penetration is about 1/penalty_factor of the elastic displacement the contact force
//! alone would cause locally.
//!
//! These springs are the gradient and (Gauss–Newton) Hessian of the penalty potential
//! ½ Σ k_c depth(x)², depth = ‖c − x‖ inside the tip, 0 outside; it is C¹, so the equilibrium
//! solver minimises elastic energy − work + this potential with an Armijo line search
//! ([`crate::StaticSolver::solve`]) and the active set settles instead of cycling: a rim node that
//! an undamped step would throw out of the probe (and back in at the next iteration) is held by the
//! line search at the step that lowers the total energy.
//!
//! The probe is **displacement-controlled** along its axis in experiments: the load path moves the
//! pose, and the probe reaction (−Σ f_c) and its component along the axis are reported. A
//! force-controlled probe is obtained by searching the axial position (not in this crate).
//!
//! **Frames.** `world_from_probe` is a nalgebra `Isometry3`; the probe's local +z axis is its
//! approach direction and the tip's leading point is the probe-frame origin. parry3d works on glam
//! types: points are converted at the boundary (`to_parry` / `from_parry`).

use crate::FemError;
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d::math::Vector as PVec;
use parry3d::query::PointQuery;
use parry3d::shape::{Ball, Cylinder, TriMesh, TriMeshFlags};
use serde::{Deserialize, Serialize};

/// Tip geometry in the probe frame (+z = approach direction, leading point at the origin).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum TipShape {
    /// Sphere of radius r, centre at (0, 0, −r).
    Sphere {
        /// radius \[m\]
        radius_m: f64,
    },
    /// Flat disk (short cylinder) of radius r and thickness t, axis z, occupying z ∈ [−t, 0].
    Disk {
        /// radius \[m\]
        radius_m: f64,
        /// thickness \[m\]
        thickness_m: f64,
    },
    /// Cylinder lying across the approach direction (axis along probe x), radius r, centre
    /// (0, 0, −r) — the rolling/sliding cylinder of bickel2009 Fig. 4.
    Cylinder {
        /// radius \[m\]
        radius_m: f64,
        /// half of the length along probe x \[m\]
        half_length_m: f64,
    },
    /// Closed, consistently oriented triangle mesh in the probe frame.
    Mesh {
        /// vertices \[m\]
        vertices_m: Vec<Vector3<f64>>,
        /// triangles (outward-facing counter-clockwise)
        triangles: Vec<[u32; 3]>,
    },
}

enum ParryShape {
    Ball(Ball),
    Cylinder(Cylinder),
    Mesh(Box<TriMesh>),
}

/// A rigid probe: tip shape (compiled to a parry3d shape) and pose.
pub struct Probe {
    tip: TipShape,
    shape: ParryShape,
    /// shape frame → probe frame (parry's cylinder axis is y; ours are z or x).
    probe_from_shape: Isometry3<f64>,
    /// Pose of the probe in the world.
    pub world_from_probe: Isometry3<f64>,
    /// A disk tip resolves every penetration through its leading face (flat punch), see
    /// [`Probe::with_punch_face`].
    punch_face: bool,
}

impl std::fmt::Debug for Probe {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Probe")
            .field("tip", &self.tip)
            .field("world_from_probe", &self.world_from_probe)
            .finish()
    }
}

impl Clone for Probe {
    fn clone(&self) -> Self {
        // TipShape was validated when self was built; rebuilding cannot fail.
        let mut p =
            Probe::new(self.tip.clone(), self.world_from_probe).expect("validated tip shape");
        p.world_from_probe = self.world_from_probe;
        p.punch_face = self.punch_face;
        p
    }
}

fn to_parry(v: &Vector3<f64>) -> PVec {
    PVec::new(v.x, v.y, v.z)
}

fn from_parry(v: PVec) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

impl Probe {
    /// Builds the probe; errors on non-positive dimensions or an unusable mesh.
    pub fn new(tip: TipShape, world_from_probe: Isometry3<f64>) -> Result<Self, FemError> {
        let bad = |reason: &str| {
            Err(FemError::InvalidProbe {
                reason: reason.to_string(),
            })
        };
        let rot_y_to_z =
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2);
        let rot_y_to_x =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -std::f64::consts::FRAC_PI_2);
        let (shape, probe_from_shape) = match &tip {
            TipShape::Sphere { radius_m } => {
                if !(*radius_m > 0.0 && radius_m.is_finite()) {
                    return bad("sphere radius must be positive");
                }
                (
                    ParryShape::Ball(Ball::new(*radius_m)),
                    Isometry3::translation(0.0, 0.0, -radius_m),
                )
            }
            TipShape::Disk {
                radius_m,
                thickness_m,
            } => {
                if !(*radius_m > 0.0
                    && *thickness_m > 0.0
                    && radius_m.is_finite()
                    && thickness_m.is_finite())
                {
                    return bad("disk radius and thickness must be positive");
                }
                (
                    ParryShape::Cylinder(Cylinder::new(0.5 * thickness_m, *radius_m)),
                    Isometry3::from_parts(
                        Translation3::new(0.0, 0.0, -0.5 * thickness_m),
                        rot_y_to_z,
                    ),
                )
            }
            TipShape::Cylinder {
                radius_m,
                half_length_m,
            } => {
                if !(*radius_m > 0.0
                    && *half_length_m > 0.0
                    && radius_m.is_finite()
                    && half_length_m.is_finite())
                {
                    return bad("cylinder radius and half length must be positive");
                }
                (
                    ParryShape::Cylinder(Cylinder::new(*half_length_m, *radius_m)),
                    Isometry3::from_parts(Translation3::new(0.0, 0.0, -radius_m), rot_y_to_x),
                )
            }
            TipShape::Mesh {
                vertices_m,
                triangles,
            } => {
                if vertices_m.iter().any(|v| !v.iter().all(|c| c.is_finite())) {
                    return bad("non-finite mesh vertex");
                }
                let verts = vertices_m.iter().map(to_parry).collect();
                let mesh = TriMesh::with_flags(verts, triangles.clone(), TriMeshFlags::ORIENTED)
                    .map_err(|e| FemError::InvalidProbe {
                        reason: format!("{e:?}"),
                    })?;
                (ParryShape::Mesh(Box::new(mesh)), Isometry3::identity())
            }
        };
        Ok(Self {
            tip,
            shape,
            probe_from_shape,
            world_from_probe,
            punch_face: false,
        })
    }

    /// A disk tip as a flat punch: a point inside the disk is pushed out through the leading face
    /// (along the axis), never through the rim. The closest-feature projection pushes a point
    /// that a pressed punch has carried within `depth` of its rim out sideways instead — a
    /// lateral force the flat-ended indenter cannot exert on the material under it, which in a
    /// replay of measured poses drags the whole surface (and a node pushed past the rim stays
    /// there: a second equilibrium). No effect on other tip shapes.
    pub fn with_punch_face(mut self) -> Self {
        self.punch_face = true;
        self
    }

    /// The flat-punch projection of a point inside a disk tip ([`Self::with_punch_face`]):
    /// (depth behind the leading face, outward normal, point on the face), world frame.
    fn punch_projection(
        &self,
        point_world: &Vector3<f64>,
    ) -> Option<Option<(f64, Vector3<f64>, Vector3<f64>)>> {
        let TipShape::Disk {
            radius_m,
            thickness_m,
        } = &self.tip
        else {
            return None;
        };
        if !self.punch_face {
            return None;
        }
        let local = self
            .world_from_probe
            .inverse_transform_point(&Point3::from(*point_world));
        let inside = local.z <= 0.0
            && local.z >= -thickness_m
            && local.x * local.x + local.y * local.y <= radius_m * radius_m;
        if !inside || local.z == 0.0 {
            return Some(None);
        }
        let n = self.world_from_probe.rotation * Vector3::z();
        let c = self
            .world_from_probe
            .transform_point(&Point3::new(local.x, local.y, 0.0))
            .coords;
        Some(Some((-local.z, n, c)))
    }

    /// Where a contact point kept by the active set's hysteresis ([`ContactProblem`]'s
    /// `point_springs`) is re-linearized: with `on_face` and a flat punch
    /// ([`Self::with_punch_face`]) the face plane (outward normal along the axis, the point
    /// projected onto the plane; the signed distance is its height above the plane), also past
    /// the rim, where the face is what pressed the point; otherwise its closest feature
    /// ([`Self::closest`]). Frictional contact (μ > 0) keeps its points on the face
    /// ([`crate::FrictionalContact`]): a punch's closest feature past the rim is the rim edge,
    /// whose diagonal normal pushes a point that the stuck patch carried there out and up, so it
    /// leaves the set, falls back under the face and re-enters, and the set cycles (period 3)
    /// until it is frozen. Frictionless contact keeps the closest feature: there the surface
    /// slides outward under a pressed punch, and points kept on the face past the rim would
    /// widen it.
    pub(crate) fn kept_projection(
        &self,
        point_world: &Vector3<f64>,
        on_face: bool,
    ) -> Option<(f64, Vector3<f64>, Vector3<f64>)> {
        if !(on_face && self.punch_face && matches!(self.tip, TipShape::Disk { .. })) {
            return self.closest(point_world);
        }
        let local = self
            .world_from_probe
            .inverse_transform_point(&Point3::from(*point_world));
        let n = self.world_from_probe.rotation * Vector3::z();
        let c = self
            .world_from_probe
            .transform_point(&Point3::new(local.x, local.y, 0.0))
            .coords;
        Some((local.z, n, c))
    }

    /// The tip description.
    pub fn tip(&self) -> &TipShape {
        &self.tip
    }

    /// Approach direction (probe +z) in the world.
    pub fn axis_world(&self) -> Vector3<f64> {
        self.world_from_probe.rotation * Vector3::z()
    }

    /// The probe advanced by `distance_m` along its axis (displacement control).
    pub fn advanced(&self, distance_m: f64) -> Probe {
        let mut p = self.clone();
        p.world_from_probe.translation.vector += self.axis_world() * distance_m;
        p
    }

    /// If `point_world` lies inside the tip: (penetration depth \[m\], outward unit normal, closest
    /// surface point), all in the world frame.
    pub fn penetration(
        &self,
        point_world: &Vector3<f64>,
    ) -> Option<(f64, Vector3<f64>, Vector3<f64>)> {
        if let Some(p) = self.punch_projection(point_world) {
            return p;
        }
        let world_from_shape = self.world_from_probe * self.probe_from_shape;
        let local = world_from_shape.inverse_transform_point(&Point3::from(*point_world));
        let q = to_parry(&local.coords);
        let proj = match &self.shape {
            ParryShape::Ball(s) => s.project_local_point(q, false),
            ParryShape::Cylinder(s) => s.project_local_point(q, false),
            ParryShape::Mesh(s) => s.project_local_point(q, false),
        };
        if !proj.is_inside {
            return None;
        }
        let c_local = from_parry(proj.point);
        let d = c_local - local.coords;
        let depth = d.norm();
        if depth <= 0.0 || depth.is_nan() {
            return None;
        }
        let n_world = world_from_shape.rotation * (d / depth);
        let c_world = world_from_shape
            .transform_point(&Point3::from(c_local))
            .coords;
        Some((depth, n_world, c_world))
    }

    /// Signed distance to the tip surface (positive outside), outward unit normal and closest
    /// surface point, world frame; `None` on a degenerate query (point on the surface).
    pub(crate) fn closest(
        &self,
        point_world: &Vector3<f64>,
    ) -> Option<(f64, Vector3<f64>, Vector3<f64>)> {
        if let Some(Some((depth, n, c))) = self.punch_projection(point_world) {
            return Some((-depth, n, c));
        }
        let world_from_shape = self.world_from_probe * self.probe_from_shape;
        let local = world_from_shape.inverse_transform_point(&Point3::from(*point_world));
        let q = to_parry(&local.coords);
        let proj = match &self.shape {
            ParryShape::Ball(s) => s.project_local_point(q, false),
            ParryShape::Cylinder(s) => s.project_local_point(q, false),
            ParryShape::Mesh(s) => s.project_local_point(q, false),
        };
        let c_local = from_parry(proj.point);
        let d = local.coords - c_local;
        let dist = d.norm();
        if dist <= 0.0 || !dist.is_finite() {
            return None;
        }
        let sign = if proj.is_inside { -1.0 } else { 1.0 };
        let n_world = world_from_shape.rotation * (d * (sign / dist));
        let c_world = world_from_shape
            .transform_point(&Point3::from(c_local))
            .coords;
        Some((sign * dist, n_world, c_world))
    }
}

/// Contact settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContactSettings {
    /// Penalty stiffness relative to the node's mean diagonal stiffness.
    pub penalty_factor: f64,
}

impl Default for ContactSettings {
    fn default() -> Self {
        Self {
            penalty_factor: 1.0e4,
        }
    }
}

/// One active contact spring.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactSpring {
    /// node index
    pub node: usize,
    /// outward normal (direction the probe pushes the node) [unit]
    pub normal: Vector3<f64>,
    /// closest probe-surface point \[m\]
    pub target_m: Vector3<f64>,
    /// penalty stiffness [N/m]
    pub stiffness_n_per_m: f64,
}

impl ContactSpring {
    /// f_c = k n nᵀ (c − x).
    pub fn force(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.normal * (self.stiffness_n_per_m * self.normal.dot(&(self.target_m - x)))
    }
    /// −∂f_c/∂x = k n nᵀ (added to the system matrix).
    pub fn matrix(&self) -> Matrix3<f64> {
        self.normal * self.normal.transpose() * self.stiffness_n_per_m
    }
}

/// Contact outcome at an equilibrium state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ContactReport {
    /// Contact patch: nodes in contact, increasing order.
    pub patch_nodes: Vec<usize>,
    /// Total contact force exerted by the probe on the body \[N\].
    pub contact_force_n: Vector3<f64>,
    /// Reaction on the probe = −contact force \[N\].
    pub probe_reaction_n: Vector3<f64>,
    /// Force the probe exerts along its approach axis \[N\] (positive when pushing).
    pub axial_force_n: f64,
    /// Largest penetration among patch nodes \[m\].
    pub max_penetration_m: f64,
}

/// A probe with its candidate nodes and settings.
#[derive(Clone, Debug)]
pub struct ContactProblem {
    /// The probe.
    pub probe: Probe,
    /// Nodes tested for contact (e.g. boundary nodes), increasing order.
    pub candidate_nodes: Vec<usize>,
    /// Settings.
    pub settings: ContactSettings,
}

impl ContactProblem {
    /// Springs for all penetrating candidates at positions `x`; `node_stiffness(n)` is the node's
    /// mean diagonal stiffness.
    pub fn springs(
        &self,
        x: &[Vector3<f64>],
        node_stiffness: impl Fn(usize) -> f64,
    ) -> Vec<ContactSpring> {
        let points: Vec<(usize, Vector3<f64>)> =
            self.candidate_nodes.iter().map(|&n| (n, x[n])).collect();
        self.point_springs(
            &points,
            |n| self.settings.penalty_factor * node_stiffness(n),
            &[],
            false,
        )
    }

    /// Springs at `x` with hysteresis (the active-set update of the equilibrium iterations), see
    /// [`Self::point_springs`]. Sorted by node.
    pub(crate) fn springs_with_hysteresis(
        &self,
        x: &[Vector3<f64>],
        node_stiffness: impl Fn(usize) -> f64,
        previous: &[ContactSpring],
        keep_on_face: bool,
    ) -> Vec<ContactSpring> {
        let points: Vec<(usize, Vector3<f64>)> =
            self.candidate_nodes.iter().map(|&n| (n, x[n])).collect();
        self.point_springs(
            &points,
            |n| self.settings.penalty_factor * node_stiffness(n),
            previous,
            keep_on_face,
        )
    }

    /// The one spring builder of the node and the quadrature-point contact
    /// ([`crate::ContactDiscretisation`]): `points` are contact points (key, current position),
    /// sorted by key; `stiffness(key)` is the point's penalty stiffness k_c [N/m]. Every point
    /// inside the tip gets a spring at its closest point. With hysteresis (`previous` non-empty):
    /// a point that had a spring in `previous` but is no longer inside stays in the set while it
    /// is still compressed against that spring's plane, n·(c − x) > 0, re-linearized at its
    /// current closest surface point (with `keep_on_face` a flat punch's face plane,
    /// [`Probe::kept_projection`]), so the next iteration pulls it back onto the tip. Without
    /// this, a rim point that the last iteration placed on the tangent plane of its closest point
    /// — outside a curved tip by ≈ s²/2R for a tangential slip s, more than the penalty
    /// penetration ≈ f/k_c — drops out, springs back in at the next iteration, and the active set
    /// cycles. A point whose contact is really tensile ends outside its plane and leaves at the
    /// next update. Result sorted by key (`ContactSpring::node` holds the key).
    pub(crate) fn point_springs(
        &self,
        points: &[(usize, Vector3<f64>)],
        stiffness: impl Fn(usize) -> f64,
        previous: &[ContactSpring],
        keep_on_face: bool,
    ) -> Vec<ContactSpring> {
        let mut springs: Vec<ContactSpring> = points
            .iter()
            .filter_map(|&(key, p)| {
                let (_, normal, target_m) = self.probe.penetration(&p)?;
                Some(ContactSpring {
                    node: key,
                    normal,
                    target_m,
                    stiffness_n_per_m: stiffness(key),
                })
            })
            .collect();
        if previous.is_empty() {
            return springs;
        }
        let fresh: std::collections::BTreeSet<usize> = springs.iter().map(|s| s.node).collect();
        let before = springs.len();
        for s in previous {
            if fresh.contains(&s.node) {
                continue;
            }
            // sorted keys (the documented order) by bisection, any other order by a scan
            let found = match points.binary_search_by_key(&s.node, |p| p.0) {
                Ok(k) => Some(points[k].1),
                Err(_) => points.iter().find(|p| p.0 == s.node).map(|p| p.1),
            };
            let Some(p) = found else {
                continue;
            };
            if s.normal.dot(&(s.target_m - p)) <= 0.0 {
                continue;
            }
            if let Some((_, normal, target_m)) = self.probe.kept_projection(&p, keep_on_face) {
                springs.push(ContactSpring {
                    node: s.node,
                    normal,
                    target_m,
                    stiffness_n_per_m: stiffness(s.node),
                });
            }
        }
        if springs.len() > before {
            springs.sort_by_key(|s| s.node);
        }
        springs
    }

    /// Line-search merit of one equilibrium iteration: the (bilateral) springs of the iteration,
    /// fixed, plus the true penetration of every other candidate,
    /// ½ Σ_springs k_c (n·(c − x))² + ½ Σ_others k_c depth(x)²; its gradient at any x is −Σ f_c of
    /// [`Self::springs_with`]. `springs` sorted by node.
    pub(crate) fn penalty_energy_with(
        &self,
        x: &[Vector3<f64>],
        node_stiffness: impl Fn(usize) -> f64,
        springs: &[ContactSpring],
    ) -> f64 {
        let mut e = 0.0;
        for s in springs {
            let g = s.normal.dot(&(s.target_m - x[s.node]));
            e += 0.5 * s.stiffness_n_per_m * g * g;
        }
        let mut k = 0;
        for &n in &self.candidate_nodes {
            while k < springs.len() && springs[k].node < n {
                k += 1;
            }
            if k < springs.len() && springs[k].node == n {
                continue;
            }
            if let Some((depth, _, _)) = self.probe.penetration(&x[n]) {
                e += 0.5 * self.settings.penalty_factor * node_stiffness(n) * depth * depth;
            }
        }
        e
    }

    /// Forces of [`Self::penalty_energy_with`] as springs: the fixed springs, and fresh springs of
    /// the other penetrating candidates. Sorted by node.
    pub(crate) fn springs_with(
        &self,
        x: &[Vector3<f64>],
        node_stiffness: impl Fn(usize) -> f64,
        springs: &[ContactSpring],
    ) -> Vec<ContactSpring> {
        let fixed: std::collections::BTreeSet<usize> = springs.iter().map(|s| s.node).collect();
        let mut out = springs.to_vec();
        out.extend(
            self.springs(x, node_stiffness)
                .into_iter()
                .filter(|s| !fixed.contains(&s.node)),
        );
        out.sort_by_key(|s| s.node);
        out
    }

    /// Report for a set of springs at positions `x`.
    pub fn report(&self, springs: &[ContactSpring], x: &[Vector3<f64>]) -> ContactReport {
        let mut r = ContactReport::default();
        for s in springs {
            r.patch_nodes.push(s.node);
            r.contact_force_n += s.force(&x[s.node]);
            r.max_penetration_m = r
                .max_penetration_m
                .max(s.normal.dot(&(s.target_m - x[s.node])));
        }
        r.probe_reaction_n = -r.contact_force_n;
        r.axial_force_n = r.contact_force_n.dot(&self.probe.axis_world());
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A node that was pressed by a flat punch's face and has been carried just past the rim (still
    /// below the face plane) is kept on the face plane, pushed along the axis; the plain disk keeps
    /// it on its closest feature, the side wall, pushed out sideways (the re-linearization whose
    /// diagonal rim normals made the probe-friction replay's set cycle until it was frozen).
    #[test]
    fn a_punch_keeps_a_node_past_its_rim_on_the_face_plane() {
        // probe +z (approach) ↦ world −z, leading face at world z = 0.3, r = 0.05 around (0.1, 0.2)
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
        );
        let disk = Probe::new(
            TipShape::Disk {
                radius_m: 0.05,
                thickness_m: 0.02,
            },
            pose,
        )
        .unwrap();
        let down = Vector3::new(0.0, 0.0, -1.0);
        let was = ContactSpring {
            node: 0,
            normal: down,
            target_m: Vector3::new(0.148, 0.2, 0.3),
            stiffness_n_per_m: 1.0,
        };
        // 1 mm past the rim, 0.5 mm behind the face plane: outside the disk, compressed
        let x = [Vector3::new(0.151, 0.2, 0.3005)];
        let kept = |probe: Probe, on_face: bool| {
            let problem = ContactProblem {
                probe,
                candidate_nodes: vec![0],
                settings: ContactSettings::default(),
            };
            let springs =
                problem.springs_with_hysteresis(&x, |_| 1.0, std::slice::from_ref(&was), on_face);
            assert_eq!(springs.len(), 1, "kept while compressed");
            springs[0].clone()
        };
        let punch = disk.clone().with_punch_face();
        let s = kept(punch.clone(), true);
        assert!((s.normal - down).norm() < 1e-12, "{}", s.normal);
        assert!((s.target_m - Vector3::new(0.151, 0.2, 0.3)).norm() < 1e-12);
        // frictionless (StaticSolver's hysteresis) and the plain disk: the side wall
        for (probe, on_face) in [(punch, false), (disk, true)] {
            let s = kept(probe, on_face);
            assert!((s.normal - Vector3::x()).norm() < 1e-12, "{}", s.normal);
        }
    }
}
