//! Support slip: the attached face rests on a rigid plane instead of being fixed.
//!
//! The plane is {x : ν·x = d} with unit normal ν pointing into the body. Every support node keeps
//! the **normal constraint** through a bilateral penalty spring
//!
//! f_n = k_n ν (d − ν·x),  −∂f_n/∂x = k_n ννᵀ,  k_n = `normal_penalty_factor` × node stiffness,
//!
//! (residual normal gap ≈ 1/penalty of the local elastic compliance) and moves **tangentially**
//! with one of ([`SupportTangential`]):
//! * `Springs`: tangential springs f_t = −k_t P (x − a), P = I − ννᵀ, a = the node's position
//!   when the support was built, k_t [N/m] per node (a viscoelastic/compliant mount). A block of
//!   n support nodes under a total tangential load F translates by exactly F/(n k_t) on average
//!   (Σ f_t = −F), plus its elastic shear;
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
    /// Linear tangential springs of stiffness k_t per node [N/m].
    Springs {
        /// k_t [N/m]
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
    /// Mean tangential displacement of the support nodes from their anchors at build time \[m\].
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
    initial: Vec<Vector3<f64>>,
    anchors: Vec<Vector3<f64>>,
    normal_stiffness: Vec<f64>,
    normal_forces_n: Vec<f64>,
}

impl SupportPlane {
    /// Support of `nodes` (taken at `positions`, e.g. the rest positions) on the plane ν·x = d.
    pub fn new(
        normal: Unit<Vector3<f64>>,
        offset_m: f64,
        mut nodes: Vec<usize>,
        positions: &[Vector3<f64>],
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
            normal_stiffness: vec![0.0; nodes.len()],
            normal_forces_n: vec![0.0; nodes.len()],
            nodes,
        })
    }

    fn projector(&self) -> Matrix3<f64> {
        Matrix3::identity() - self.normal.into_inner() * self.normal.transpose()
    }

    fn tangential_at(&self, i: usize, x: &[Vector3<f64>]) -> (Vector3<f64>, Matrix3<f64>) {
        let p = self.projector();
        let delta = p * (x[self.nodes[i]] - self.anchors[i]);
        match self.tangential {
            SupportTangential::Springs { stiffness_n_per_m } => {
                (-delta * stiffness_n_per_m, p * stiffness_n_per_m)
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
            r.mean_slip_m += p * (x[self.nodes[i]] - self.initial[i]);
            r.max_normal_gap_m = r
                .max_normal_gap_m
                .max((nu.dot(&x[self.nodes[i]]) - self.offset_m).abs());
        }
        if !self.nodes.is_empty() {
            r.mean_slip_m /= self.nodes.len() as f64;
        }
        r
    }
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
