//! Support slip: the attached face rests on a rigid plane instead of being fixed.
//!
//! The plane is {x : ν·x = d} with unit normal ν pointing into the body. Every support node keeps
//! the **normal constraint** through a bilateral penalty spring
//!
//! f_n = k_n ν (d − ν·x),  −∂f_n/∂x = k_n ννᵀ,  k_n = `normal_penalty_factor` × node stiffness,
//!
//! (residual normal gap ≈ 1/penalty of the local elastic compliance) and moves **tangentially**
//! with one of ([`SupportTangential`]):
//! * `Springs`: tangential springs f_t,i = −w_i k_t P (x_i − a_i), P = I − ννᵀ, a_i = the node's
//!   position when the support was built, k_t [N/m] the stiffness of the WHOLE base (a
//!   viscoelastic/compliant mount, a traction k_t/A per unit area) and w_i node i's share of the
//!   attached face's area A (lumped area: a third of every attached triangle to each of its
//!   nodes, Σ w_i = 1). A base under a total tangential load F translates by exactly F/k_t in the
//!   area-weighted mean, Σ w_i u_i = F/k_t (Σ f_t = −F), plus its elastic shear;
//! * `Friction`: the regularized Coulomb law of [`crate::friction`] with the compressive part of
//!   the normal spring force, f_n = max(0, k_n (d − ν·x)), and stick anchors on the plane. A
//!   tangential floor stiffness 1e-9 k_n P keeps an unloaded node from being singular;
//! * `Frictionless`: normal constraint only (rigid modes in the plane must be removed otherwise).
//!
//! Parameters for a fitter: k_t (∂f_t/∂k_t = f_t/k_t exactly) or μ (∂f_t/∂μ = f_t/μ).

use crate::FemError;
use crate::friction::{FrictionParams, regularized_coulomb};
use crate::nodal::NodalTerm;
use nalgebra::{Matrix3, Unit, Vector3};
use serde::{Deserialize, Serialize};

/// Tangential behaviour of the support nodes.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum SupportTangential {
    /// Linear tangential springs of total stiffness k_t over the whole base [N/m], node i's
    /// spring w_i k_t with w_i its share of the attached face's area.
    Springs {
        /// k_t [N/m], the whole base
        stiffness_n_per_m: f64,
    },
    /// Regularized Coulomb friction.
    Friction(FrictionParams),
    /// No tangential force.
    Frictionless,
}

/// Outcome of a support state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SupportReport {
    /// Total normal reaction of the plane on the body \[N\] (along ν).
    pub normal_force_n: f64,
    /// Total tangential force of the plane on the body \[N\].
    pub tangential_force_n: Vector3<f64>,
    /// Area-weighted mean tangential displacement of the support nodes from their anchors at
    /// build time, Σ w_i u_i \[m\] (the nodes' shares w_i of the attached face's area).
    pub mean_slip_m: Vector3<f64>,
    /// Largest |ν·x − d| over the support nodes \[m\].
    pub max_normal_gap_m: f64,
}

/// A rigid support plane carrying the attached face; a [`NodalTerm`].
#[derive(Clone, Debug)]
pub struct SupportPlane {
    /// Unit normal ν (into the body).
    pub normal: Unit<Vector3<f64>>,
    /// Plane offset d \[m\] (ν·x = d on the plane).
    pub offset_m: f64,
    /// Support nodes, increasing.
    pub nodes: Vec<usize>,
    /// Normal penalty relative to the node's mean diagonal stiffness.
    pub normal_penalty_factor: f64,
    /// Tangential law.
    pub tangential: SupportTangential,
    area_shares: Vec<f64>,
    initial: Vec<Vector3<f64>>,
    anchors: Vec<Vector3<f64>>,
    normal_stiffness: Vec<f64>,
    normal_forces_n: Vec<f64>,
}

impl SupportPlane {
    /// Support of `nodes` (taken at `positions`, e.g. the rest positions) on the plane ν·x = d.
    /// `faces` are boundary triangles of the mesh (e.g. `TetMesh::boundary_faces`): those whose
    /// three nodes are all support nodes make the attached face whose lumped area shares weight
    /// the tangential springs and the mean slip. Springs need an attached face of positive area
    /// (`InvalidSetting` otherwise); the other laws weight equally without one.
    pub fn new(
        normal: Unit<Vector3<f64>>,
        offset_m: f64,
        mut nodes: Vec<usize>,
        positions: &[Vector3<f64>],
        faces: &[[usize; 3]],
        tangential: SupportTangential,
    ) -> Result<Self, FemError> {
        nodes.sort_unstable();
        nodes.dedup();
        if let Some(&bad) = nodes.iter().find(|&&n| n >= positions.len()) {
            return Err(FemError::DofOutOfRange {
                dof: 3 * bad,
                num_dofs: 3 * positions.len(),
            });
        }
        match tangential {
            SupportTangential::Springs { stiffness_n_per_m } => {
                if !(stiffness_n_per_m.is_finite() && stiffness_n_per_m >= 0.0) {
                    return Err(FemError::NonFinite {
                        what: "support tangential stiffness",
                    });
                }
            }
            SupportTangential::Friction(f) => f.validate()?,
            SupportTangential::Frictionless => {}
        }
        if !offset_m.is_finite() || !normal.iter().all(|c| c.is_finite()) {
            return Err(FemError::NonFinite {
                what: "support plane",
            });
        }
        let area_shares = match lumped_area_shares(&nodes, positions, faces) {
            Some(w) => w,
            None if matches!(tangential, SupportTangential::Springs { .. }) => {
                return Err(FemError::InvalidSetting {
                    what: "support springs: attached-face area (no boundary triangle joins three support nodes)",
                    value: 0.0,
                });
            }
            None => vec![1.0 / nodes.len().max(1) as f64; nodes.len()],
        };
        let nu = normal.into_inner();
        let anchors: Vec<Vector3<f64>> = nodes
            .iter()
            .map(|&n| positions[n] - nu * (nu.dot(&positions[n]) - offset_m))
            .collect();
        Ok(Self {
            normal,
            offset_m,
            initial: anchors.clone(),
            anchors,
            normal_penalty_factor: 1.0e6,
            tangential,
            area_shares,
            normal_stiffness: vec![0.0; nodes.len()],
            normal_forces_n: vec![0.0; nodes.len()],
            nodes,
        })
    }

    /// Each support node's share w_i of the attached face's area (lumped; Σ w_i = 1), in the
    /// order of [`Self::nodes`].
    pub fn area_shares(&self) -> &[f64] {
        &self.area_shares
    }

    fn projector(&self) -> Matrix3<f64> {
        Matrix3::identity() - self.normal.into_inner() * self.normal.transpose()
    }

    fn tangential_at(&self, i: usize, x: &[Vector3<f64>]) -> (Vector3<f64>, Matrix3<f64>) {
        let p = self.projector();
        let delta = p * (x[self.nodes[i]] - self.anchors[i]);
        match self.tangential {
            SupportTangential::Springs { stiffness_n_per_m } => {
                let k = stiffness_n_per_m * self.area_shares[i];
                (-delta * k, p * k)
            }
            SupportTangential::Friction(fp) => {
                let (f, k) = regularized_coulomb(&fp, self.normal_forces_n[i], &delta, &p);
                (f, k + p * (1e-9 * self.normal_stiffness[i]))
            }
            SupportTangential::Frictionless => (Vector3::zeros(), Matrix3::zeros()),
        }
    }

    fn normal_force(&self, i: usize, x: &[Vector3<f64>]) -> f64 {
        let nu = self.normal.into_inner();
        self.normal_stiffness[i] * (self.offset_m - nu.dot(&x[self.nodes[i]]))
    }

    /// Report at positions `x`.
    pub fn report(&self, x: &[Vector3<f64>]) -> SupportReport {
        let mut r = SupportReport::default();
        let p = self.projector();
        let nu = self.normal.into_inner();
        for i in 0..self.nodes.len() {
            r.normal_force_n += self.normal_force(i, x);
            r.tangential_force_n += self.tangential_at(i, x).0;
            r.mean_slip_m += p * (x[self.nodes[i]] - self.initial[i]) * self.area_shares[i];
            r.max_normal_gap_m = r
                .max_normal_gap_m
                .max((nu.dot(&x[self.nodes[i]]) - self.offset_m).abs());
        }
        r
    }
}

/// The lumped area shares of `nodes` (sorted) on the attached face: a third of the area of every
/// triangle of `faces` whose three nodes are in `nodes` to each of them, divided by the total;
/// `None` when that total is not positive.
fn lumped_area_shares(
    nodes: &[usize],
    positions: &[Vector3<f64>],
    faces: &[[usize; 3]],
) -> Option<Vec<f64>> {
    let mut shares = vec![0.0; nodes.len()];
    for f in faces {
        let (Ok(a), Ok(b), Ok(c)) = (
            nodes.binary_search(&f[0]),
            nodes.binary_search(&f[1]),
            nodes.binary_search(&f[2]),
        ) else {
            continue;
        };
        let [pa, pb, pc] = f.map(|n| positions[n]);
        let third = (pb - pa).cross(&(pc - pa)).norm() / 6.0;
        for i in [a, b, c] {
            shares[i] += third;
        }
    }
    let total: f64 = shares.iter().sum();
    (total > 0.0 && total.is_finite()).then(|| shares.iter().map(|a| a / total).collect())
}

impl NodalTerm for SupportPlane {
    fn refresh(
        &mut self,
        x: &[Vector3<f64>],
        node_stiffness: &dyn Fn(usize) -> f64,
        requery: bool,
    ) {
        if requery || self.normal_stiffness.iter().all(|&k| k == 0.0) {
            for (i, &n) in self.nodes.iter().enumerate() {
                self.normal_stiffness[i] = self.normal_penalty_factor * node_stiffness(n);
            }
        }
        for i in 0..self.nodes.len() {
            self.normal_forces_n[i] = self.normal_force(i, x).max(0.0);
        }
    }

    fn add_forces(&self, x: &[Vector3<f64>], out: &mut [Vector3<f64>]) {
        let nu = self.normal.into_inner();
        for (i, &n) in self.nodes.iter().enumerate() {
            out[n] += nu * self.normal_force(i, x) + self.tangential_at(i, x).0;
        }
    }

    fn blocks(&self, x: &[Vector3<f64>]) -> Vec<(usize, Matrix3<f64>)> {
        let nu = self.normal.into_inner();
        let nn = nu * nu.transpose();
        self.nodes
            .iter()
            .enumerate()
            .map(|(i, &n)| {
                (
                    n,
                    nn * self.normal_stiffness[i] + self.tangential_at(i, x).1,
                )
            })
            .collect()
    }

    fn commit(&mut self, x: &[Vector3<f64>]) {
        if let SupportTangential::Friction(fp) = self.tangential {
            let p = self.projector();
            for i in 0..self.nodes.len() {
                let delta = p * (x[self.nodes[i]] - self.anchors[i]);
                let d = delta.norm();
                if d > fp.slip_distance_m {
                    self.anchors[i] += delta * (1.0 - fp.slip_distance_m / d);
                }
            }
        }
    }
}
