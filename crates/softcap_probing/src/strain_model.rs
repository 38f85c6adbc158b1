//! The strain-space material as an elastic model (bickel2009 §3.4): parameters refreshed from
//! the strain at every equilibrium iteration (under-relaxed), and its equilibrium continued
//! from the previous frame with incremental loading from rest as the fallback.

use std::sync::Arc;

use nalgebra::{Vector3, Vector6};
use serde::{Deserialize, Serialize};
use softcap_fem::{
    CorotationalModel, ElasticModel, EquilibriumReport, EquilibriumSettings, FemError,
    LinearParams, SolveStatus, StaticSolver, StiffnessKind,
};
use softcap_mesh::TetMesh;

use crate::{ProbingSetup, StrainSpaceMaterial, probing_error};

/// The strain-space material as an [`ElasticModel`] for synthesis (bickel2009 §3.4: "at each
/// iteration ... we first compute the material parameters for the current configuration") with
/// under-relaxed parameter updates p ← p + ω (p(ε) − p).
///
/// The plain iteration (ω = 1, [`StrainSpaceMaterial::model`]) is a Picard (secant) iteration
/// on p(ε): where λ rises with strain a step from the soft parameters overshoots, the stiff
/// parameters of the overshoot pull back too far, and the equilibrium oscillates (measured: no
/// convergence in 300 iterations for the 1 N examples of a three-layer block, docs/tissue.md).
/// Damping the parameter update keeps the same fixed points — at equilibrium p = p(ε) — and
/// contracts the oscillation. The convex combination of two valid parameter sets is valid
/// (ν of the blend lies between the two ν), so the clamp of [`StrainSpaceMaterial::evaluate`]
/// keeps holding. The parameters persist across solves (warm start along incremental loading);
/// [`Self::reset`] returns to the zero-strain material.
#[derive(Clone, Debug)]
pub struct StrainSpaceModel {
    inner: CorotationalModel,
    material: Arc<StrainSpaceMaterial>,
    /// Relaxation ω ∈ (0, 1] of the parameter update.
    pub relaxation: f64,
}

impl StrainSpaceModel {
    /// The model over `mesh` starting from the material at zero strain.
    pub fn new(
        material: Arc<StrainSpaceMaterial>,
        mesh: &TetMesh,
        relaxation: f64,
    ) -> Result<Self, FemError> {
        if material.elements.len() != mesh.tets.len() {
            return Err(FemError::LengthMismatch {
                what: "strain-space elements",
                expected: mesh.tets.len(),
                got: material.elements.len(),
            });
        }
        if !(relaxation > 0.0 && relaxation <= 1.0) {
            return Err(probing_error(format!(
                "relaxation {relaxation} must lie in (0, 1]"
            )));
        }
        let zero = Vector6::zeros();
        let params = (0..mesh.tets.len())
            .map(|e| material.evaluate(e, &zero))
            .collect();
        Ok(Self {
            inner: CorotationalModel::new(mesh, params)?,
            material,
            relaxation,
        })
    }

    /// Current per-element parameters.
    pub fn params(&self) -> &[LinearParams] {
        self.inner.params()
    }

    /// Back to the material at zero strain.
    pub fn reset(&mut self) {
        let zero = Vector6::zeros();
        let params: Vec<LinearParams> = (0..self.material.elements.len())
            .map(|e| self.material.evaluate(e, &zero))
            .collect();
        self.inner
            .set_params(&params)
            .expect("one parameter set per element");
    }

    /// The material.
    pub fn material(&self) -> &Arc<StrainSpaceMaterial> {
        &self.material
    }
}

impl ElasticModel for StrainSpaceModel {
    fn rest_positions(&self) -> &[Vector3<f64>] {
        self.inner.rest_positions()
    }
    fn elements(&self) -> &[softcap_fem::TetGeometry] {
        self.inner.elements()
    }
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        self.inner.element_forces(e, x)
    }
    fn element_matrix(
        &self,
        e: usize,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
    ) -> softcap_fem::Matrix12 {
        self.inner.element_matrix(e, x, kind)
    }
    fn energy(&self, _x: &[Vector3<f64>]) -> Option<f64> {
        None // Cauchy-elastic (thesis §7.4.3): no potential.
    }
    fn internal_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        self.inner.internal_forces(x)
    }
    fn forces_and_energy(&self, x: &[Vector3<f64>]) -> (Vec<Vector3<f64>>, Option<f64>) {
        (self.inner.internal_forces(x), None)
    }
    fn linearize_elements(
        &self,
        first: usize,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        forces: &mut [[Vector3<f64>; 4]],
        matrices: &mut [softcap_fem::Matrix12],
    ) -> Option<f64> {
        self.inner
            .linearize_elements(first, x, kind, forces, matrices);
        None
    }
    fn update_state(&mut self, x: &[Vector3<f64>]) {
        let strains = self.inner.strains(x);
        let w = self.relaxation;
        let params: Vec<LinearParams> = self
            .inner
            .params()
            .iter()
            .zip(&strains)
            .enumerate()
            .map(|(e, (p, eps))| {
                let target = self.material.evaluate(e, eps);
                LinearParams {
                    lambda: p.lambda + w * (target.lambda - p.lambda),
                    alpha: p.alpha + w * (target.alpha - p.alpha),
                }
            })
            .collect();
        self.inner
            .set_params(&params)
            .expect("one parameter set per element");
    }
}

/// Settings of [`StrainSpaceModel::solve_continued`]: equilibrium of the strain-space material
/// under one load, continued from the previous equilibrium, with incremental loading from rest
/// (bickel2009 §3.4) as the fallback path.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StrainSpaceSolveSettings {
    /// Relaxation ω ∈ (0, 1] of the parameter update p ← p + ω (p(ε) − p)
    /// ([`StrainSpaceModel`]; 1 = the plain iteration of bickel2009 §3.4).
    pub relaxation: f64,
    /// Load increments of the solve from rest when the continued solve does not converge.
    pub load_steps: usize,
    /// Halvings of ω, each with twice the increments, after a solve from rest that does not
    /// converge (a smaller ω contracts the parameter oscillation more; same fixed points).
    pub relaxation_retries: usize,
    /// Equilibrium iterations per solve (replaces the equilibrium settings' limit). The
    /// displacement iteration is Newton's, but the parameters converge only linearly, at the
    /// rate |1 − ω (1 − μ)| of the relaxed fixed point p ← p + ω (p(ε) − p) (μ the eigenvalues
    /// of ∂p(ε(p))/∂p): measured on the diagnose suite's clean control (648 tets, 1.4 N
    /// presses, ω ½, Newton, displacement tolerance 10⁻⁸ of the bounding-box diagonal), the
    /// deepest frames need 100–110 iterations with the whole load in one solve, so 100 (the
    /// equilibrium default) stopped them just short of the tolerance.
    pub max_iterations: usize,
}

impl Default for StrainSpaceSolveSettings {
    fn default() -> Self {
        Self {
            // ½ halves every parameter jump: it stops the oscillation of the plain iteration on
            // the three-layer block of docs/tissue.md (the tissue stage's default, too).
            relaxation: 0.5,
            load_steps: 4,
            relaxation_retries: 2,
            max_iterations: 400,
        }
    }
}

/// How [`StrainSpaceModel::solve_continued`] reached (or missed) its equilibrium.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StrainSpaceSolve {
    /// The last equilibrium solve (of the last increment when loaded from rest).
    pub report: EquilibriumReport,
    /// `None`: continued from the previous equilibrium; `Some(k)`: from rest by incremental
    /// loading with ω halved k times (the last attempt when not converged).
    pub from_rest_attempt: Option<usize>,
    /// Equilibrium iterations over every attempt.
    pub iterations: usize,
}

impl StrainSpaceSolve {
    /// True if the equilibrium was reached.
    pub fn converged(&self) -> bool {
        self.report.converged()
    }
}

impl StrainSpaceModel {
    /// Equilibrium of the strain-space material (p = p(ε) at every element, bickel2009 §3.4)
    /// under the external nodal `forces` on `setup` (attached nodes fixed at rest), continued
    /// from the equilibrium this model and `x` hold under `previous_forces` — the previous frame
    /// of a recording; the rest shape, the zero-strain parameters and zero forces before the
    /// first solve.
    ///
    /// The path is the incremental loading of §3.4. A Cauchy-elastic material (thesis §7.4.3)
    /// has no memory, but the strain-space fixed point p = p(ε(p)) need not be unique: measured
    /// on the diagnose suite's clean control (648 tets), the full 1.3 N load applied in one step
    /// from rest reaches an equilibrium 0.077 mm (of 0.93 mm) away from the one that 2, 4, 8 or
    /// 16 increments reach (those agree to 10⁻⁸ m). So the load goes from `previous_forces` to
    /// `forces` in ⌈n ‖Δf‖ / max(‖f‖, ‖f_prev‖)⌉ increments (n = `settings.load_steps`, ‖·‖ over
    /// all nodal forces): a recording's next frame is usually one increment; a change of more
    /// than half the load (another location, a jump) is loaded from rest in n increments
    /// instead, the path of the tissue fit's re-simulation, so the equilibrium does not depend
    /// on which frame came before. When that does not converge, the load is applied from rest
    /// again with ω halved and twice the increments, `settings.relaxation_retries` times.
    ///
    /// Non-convergence is the returned status; then `x` and the parameters are left at the
    /// state the call started from, so a later solve continues from the last equilibrium. On
    /// convergence the solver's factor is the consistent tangent at the equilibrium with the
    /// parameters frozen at their final values (p(ε) to the solver tolerance).
    #[allow(clippy::too_many_arguments)]
    pub fn solve_continued(
        &mut self,
        setup: &ProbingSetup,
        solver: &mut StaticSolver,
        x: &mut [Vector3<f64>],
        previous_forces: &[Vector3<f64>],
        forces: &[Vector3<f64>],
        equilibrium: &EquilibriumSettings,
        settings: &StrainSpaceSolveSettings,
    ) -> Result<StrainSpaceSolve, FemError> {
        if !(settings.relaxation > 0.0 && settings.relaxation <= 1.0) {
            return Err(probing_error(format!(
                "relaxation {} must lie in (0, 1]",
                settings.relaxation
            )));
        }
        let n = setup.mesh.vertices.len();
        for (what, len) in [
            ("node positions", x.len()),
            ("previous nodal forces", previous_forces.len()),
            ("nodal forces", forces.len()),
        ] {
            if len != n {
                return Err(FemError::LengthMismatch {
                    what,
                    expected: n,
                    got: len,
                });
            }
        }
        let equilibrium = &EquilibriumSettings {
            max_iterations: settings.max_iterations.max(1),
            ..equilibrium.clone()
        };
        let steps = settings.load_steps.max(1);
        let norm = |f: &[Vector3<f64>]| f.iter().map(|v| v.norm_squared()).sum::<f64>().sqrt();
        let change = previous_forces
            .iter()
            .zip(forces)
            .map(|(a, b)| (b - a).norm_squared())
            .sum::<f64>()
            .sqrt();
        let scale = norm(forces).max(norm(previous_forces));
        let start_x = x.to_vec();
        let start_params = self.params().to_vec();
        let mut iterations = 0;
        let mut last = None;
        let mut path = |m: &mut Self,
                        x: &mut [Vector3<f64>],
                        from: &[Vector3<f64>],
                        increments: usize,
                        iterations: &mut usize| {
            let run = softcap_fem::incremental_loading(
                solver,
                m,
                x,
                |t| softcap_fem::LoadState {
                    external_forces_n: from
                        .iter()
                        .zip(forces)
                        .map(|(a, b)| a + (b - a) * t)
                        .collect(),
                    prescribed: setup.dirichlet(),
                    contact: None,
                },
                &softcap_fem::IncrementalSettings {
                    steps: increments,
                    equilibrium: equilibrium.clone(),
                },
            );
            *iterations += run
                .steps
                .iter()
                .map(|s| s.equilibrium.iterations)
                .sum::<usize>();
            let converged = run.status == SolveStatus::Converged;
            (
                converged,
                run.steps.into_iter().last().map(|s| s.equilibrium),
            )
        };
        self.relaxation = settings.relaxation;
        if change <= 0.5 * scale || scale == 0.0 {
            let increments = if scale > 0.0 {
                ((steps as f64 * change / scale).ceil() as usize).clamp(1, steps)
            } else {
                1
            };
            let (ok, rep) = path(self, x, previous_forces, increments, &mut iterations);
            last = rep;
            if ok && let Some(report) = last.clone() {
                return Ok(StrainSpaceSolve {
                    report,
                    from_rest_attempt: None,
                    iterations,
                });
            }
        }
        let zero = vec![Vector3::zeros(); n];
        let mut increments = steps;
        for attempt in 0..=settings.relaxation_retries {
            self.reset();
            self.relaxation = settings.relaxation * 0.5f64.powi(attempt as i32);
            x.copy_from_slice(&setup.mesh.vertices);
            let (ok, rep) = path(self, x, &zero, increments, &mut iterations);
            if rep.is_some() {
                last = rep;
            }
            if ok && let Some(report) = last.clone() {
                self.relaxation = settings.relaxation;
                return Ok(StrainSpaceSolve {
                    report,
                    from_rest_attempt: Some(attempt),
                    iterations,
                });
            }
            increments *= 2;
        }
        self.relaxation = settings.relaxation;
        self.inner.set_params(&start_params)?;
        x.copy_from_slice(&start_x);
        Ok(StrainSpaceSolve {
            report: last.unwrap_or_else(|| EquilibriumReport::begin(n, n, n)),
            from_rest_attempt: Some(settings.relaxation_retries),
            iterations,
        })
    }
}
