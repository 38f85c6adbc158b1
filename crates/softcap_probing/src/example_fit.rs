//! The per-example fit of bickel2009 eq. 9: (λ_e, α_e) per tet by projected Levenberg–Marquardt
//! with the adjoint marker Jacobian (appendix eq. 10–12), umbrella smoothing and a shrinkage
//! toward a reference field — one entry point, [`fit_examples`].

use nalgebra::{Vector3, Vector6};
use serde::{Deserialize, Serialize};
use softcap_fem::{
    CorotationalModel, EquilibriumSettings, FemError, LinearParams, Sensitivity, SolveStatus,
    StaticSolver, StiffnessKind,
};

use crate::lm_step::{Umbrella, UmbrellaScratch, damped_step};
use crate::setup::{marker_residuals, rms_of};
use crate::{PatchSettings, ProbeExample, ProbingSetup};

/// Settings of the per-example fit (bickel2009 eq. 9).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExampleFitSettings {
    /// γ of eq. 9 on the log-stiffness field, m² (a unit jump of ln λ between neighbouring tets
    /// costs as much as √γ of marker error).
    pub gamma_m2: f64,
    /// γ on the Poisson-ratio field, m².
    pub gamma_nu_m2: f64,
    /// Bounds on λ_e relative to the initial value.
    pub lambda_factor_bounds: (f64, f64),
    /// Bounds on ν_e = α_e/λ_e (physically valid: within (−1, 0.5)).
    pub nu_bounds: (f64, f64),
    /// Safety cap on the Levenberg–Marquardt iterations (accepted or rejected steps); a fit that
    /// reaches it ends with [`FitStop::IterationCap`], i.e. not converged.
    pub max_iterations: usize,
    /// Stop ([`FitStop::Cost`]) when an accepted step lowers the cost by less than this fraction;
    /// 0 disables the test.
    pub relative_cost_tolerance: f64,
    /// Stop ([`FitStop::Gradient`]) when the projected gradient ‖P g‖∞ (components pushing
    /// against an active bound removed: first-order optimality of the bound-constrained
    /// problem, Nocedal & Wright eq. 12.34 / Moré 1978 §7) has fallen to this fraction of its
    /// value at the start; 0 disables the test.
    pub gradient_tolerance: f64,
    /// Stop ([`FitStop::Step`]) when an accepted step moves no unknown by more than this, in
    /// q = (ln λ, ν) units (1e-4 = 0.01 % of λ); 0 disables the test.
    pub step_tolerance: f64,
    /// Initial Marquardt damping μ, dimensionless: the step solves (JᵀJ + … + μD) h = −g with D
    /// the diagonal of the normal matrix (Marquardt 1963; Nocedal & Wright §10.3). Divided by
    /// 3 after an accepted step, multiplied by 4 after a rejected one.
    pub initial_damping: f64,
    /// Floor of the Marquardt scaling relative to its largest entry: D_i = max(diag_i,
    /// `min_scaling` · max diag) (Moré 1978 §5: a scaling that vanishes in parameters the
    /// markers barely see lets the damped step run off in them at any μ).
    pub min_scaling: f64,
    /// Largest trust radius ‖h‖∞ of a step in q = (ln λ, ν) units (Moré 1978 trust region on
    /// top of the Marquardt damping); 0 disables the trust region.
    pub max_step: f64,
    /// γ_p: Tikhonov shrinkage of the fit toward its start `initial`, cost
    /// γ_p · (1e-8 m²) · (rows / 2T) · ‖q − q₀‖²: with γ_p = 1, moving *every* tet by 1 in ln λ
    /// (or ν) costs as much as 0.1 mm RMS marker error; 0 = eq. 9 as printed.
    pub gamma_prior: f64,
    /// Matrix of the linearization: `Consistent` (exact ∂x/∂p of the corotational equilibrium)
    /// or `Warped` (bickel2009 eq. 11 with rotations held fixed).
    pub jacobian: StiffnessKind,
    /// Equilibrium iterations of every simulation.
    pub equilibrium: EquilibriumSettings,
    /// Conjugate-gradient iterations per damped normal-equation solve.
    pub cg_iterations: usize,
    /// Relative tolerance of that solve on the preconditioned residual (an inexact LM step,
    /// Steihaug 1983 / Dembo et al. 1982 inexact Newton: the step need not be exact far from the
    /// minimum).
    pub cg_tolerance: f64,
    /// Preconditioner of that conjugate-gradient solve.
    pub preconditioner: StepPreconditioner,
    /// Force boundary-condition patch.
    pub patch: PatchSettings,
}

/// Preconditioner of the conjugate-gradient solve of the damped LM normal equations
/// (J_mᵀJ_m + γLᵀL + γ_p I + μD) h = −g of [`fit_examples`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StepPreconditioner {
    /// The diagonal (Jacobi).
    #[default]
    Jacobi,
    /// The exact inverse of J_mᵀJ_m + Δ by the Woodbury identity, Δ = the diagonal of the rest
    /// (μD + γ_p + γ diag LᵀL): P⁻¹ = Δ⁻¹ − Δ⁻¹J_mᵀ(I + J_mΔ⁻¹J_mᵀ)⁻¹J_mΔ⁻¹, a k × k Cholesky
    /// for k observed marker coordinates (k ≪ 2T parameters; saito-barbic use the same
    /// identity for their Gauss–Newton steps). Only the off-diagonal part of γLᵀL is left to
    /// the iteration, so a step takes a few iterations instead of tens.
    Woodbury,
}

impl Default for ExampleFitSettings {
    fn default() -> Self {
        Self {
            gamma_m2: 1e-12,
            gamma_nu_m2: 1e-11,
            lambda_factor_bounds: (0.02, 50.0),
            nu_bounds: (0.0, 0.49),
            max_iterations: 12,
            relative_cost_tolerance: 1e-3,
            gradient_tolerance: 0.0,
            step_tolerance: 0.0,
            initial_damping: 1e-3,
            min_scaling: 1e-2,
            max_step: 1.0,
            gamma_prior: 0.0,
            jacobian: StiffnessKind::Consistent,
            equilibrium: EquilibriumSettings {
                max_iterations: 60,
                displacement_tol_rel: 1e-9,
                residual_tol_rel: 1e-7,
                ..EquilibriumSettings::default()
            },
            cg_iterations: 300,
            cg_tolerance: 1e-10,
            preconditioner: StepPreconditioner::default(),
            patch: PatchSettings::default(),
        }
    }
}

/// Why the Levenberg–Marquardt iteration of [`fit_examples`] stopped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FitStop {
    /// The projected gradient fell below `gradient_tolerance` of its start value (converged).
    Gradient,
    /// An accepted step was below `step_tolerance` (converged).
    Step,
    /// An accepted step lowered the cost by less than `relative_cost_tolerance` (converged).
    Cost,
    /// No observed marker: nothing to fit.
    NoData,
    /// No step along the damped direction lowered the cost (damping above 10¹² or trust radius
    /// below 10⁻⁶): the cost is flat to the resolution of the equilibrium solves.
    Stalled,
    /// `max_iterations` reached before any tolerance: not converged.
    #[default]
    IterationCap,
}

impl FitStop {
    /// The kebab-case name (as serialized): `gradient`, `step`, `cost`, `no-data`, `stalled`,
    /// `iteration-cap`.
    pub fn name(self) -> &'static str {
        match self {
            FitStop::Gradient => "gradient",
            FitStop::Step => "step",
            FitStop::Cost => "cost",
            FitStop::NoData => "no-data",
            FitStop::Stalled => "stalled",
            FitStop::IterationCap => "iteration-cap",
        }
    }

    /// The iteration stopped on a tolerance (or had nothing to fit), not on the cap or a stall.
    pub fn converged(self) -> bool {
        matches!(
            self,
            FitStop::Gradient | FitStop::Step | FitStop::Cost | FitStop::NoData
        )
    }
}

/// Result of the fit of one example (`ExampleFit::from` the [`JointFit`] of [`fit_examples`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExampleFit {
    /// Fitted (λ_e, α_e) per tet.
    pub params: Vec<LinearParams>,
    /// Equilibrium node positions under the fitted parameters, m.
    pub positions_m: Vec<Vector3<f64>>,
    /// Corotated Voigt strain of each tet at that equilibrium (the strain-space sample ε_e).
    pub strains: Vec<Vector6<f64>>,
    /// RMS marker error before fitting (initial parameters), m.
    pub initial_rms_m: f64,
    /// RMS marker error after fitting, m.
    pub rms_m: f64,
    /// Cost Σ‖r‖² + γ‖Lp‖² after each accepted step (first entry: initial).
    pub cost_history: Vec<f64>,
    /// LM iterations performed.
    pub iterations: usize,
    /// Conjugate-gradient iterations of all damped steps (diagnostic).
    #[serde(default)]
    pub cg_iterations: usize,
    /// Equilibrium status of the final simulation.
    pub status: SolveStatus,
    /// Why the iteration stopped.
    #[serde(default)]
    pub stop: FitStop,
    /// Projected gradient ‖P g‖∞ at each linearization (first entry: the start).
    #[serde(default)]
    pub gradient_history: Vec<f64>,
}

/// (log-λ, ν) parameterization of the per-tet material (λ_e = λ_ref,e · exp(s_e), α_e = ν_e λ_e).
fn params_from_q(lambda_ref: &[f64], q: &[f64]) -> Vec<LinearParams> {
    let t = lambda_ref.len();
    (0..t)
        .map(|e| {
            let lambda = lambda_ref[e] * q[e].exp();
            LinearParams {
                lambda,
                alpha: q[t + e] * lambda,
            }
        })
        .collect()
}

/// The marker Jacobian J_m = ∂x_markers/∂p at the equilibrium `x` of `model`, one row per
/// observed marker coordinate of `example` (3k rows × 2T, parameters interleaved (λ_e, α_e)),
/// by the adjoint method of bickel2009 appendix eq. 10–12: Jᵀw for the k marker weight vectors
/// w by one multi-column solve with one factorization of the `kind` stiffness.
pub fn marker_jacobian(
    setup: &ProbingSetup,
    solver: &mut StaticSolver,
    model: &CorotationalModel,
    example: &ProbeExample,
    x: &[Vector3<f64>],
    kind: StiffnessKind,
) -> Result<Vec<Vec<f64>>, FemError> {
    let sens = Sensitivity::new(solver, model, x, kind, None)?;
    let mut weights = Vec::with_capacity(3 * example.observed.len());
    for o in &example.observed {
        let emb = &setup.markers[o.marker];
        let tet = setup.mesh.tets[emb.tet];
        for c in 0..3 {
            weights.push((0..4).map(|a| (3 * tet[a] + c, emb.weights[a])).collect());
        }
    }
    sens.jt_times_sparse(&weights)
}

/// Where the iteration of [`fit_examples`] starts. The reference field (λ_ref of the
/// parameterization, the target q₀ of the shrinkage γ_p) is an argument of its own.
#[derive(Clone, Copy, Debug, Default)]
pub enum FitStart<'a> {
    /// At the reference field, every equilibrium from the rest shape.
    #[default]
    Reference,
    /// At another per-tet field (e.g. the fit of the same examples at a neighbouring γ_p), every
    /// equilibrium from the rest shape.
    Params(&'a [LinearParams]),
    /// At an earlier fit of the same examples: its parameters are the first iterate and its
    /// equilibrium positions (one per example) the start of the first equilibrium solves, so
    /// the first simulation costs a few Newton iterations. Same minimizer as
    /// [`FitStart::Params`] with the same parameters (the equilibrium is the same to the solver
    /// tolerance). Positions of the wrong count or length fall back to the rest shape.
    Warm {
        /// Per-tet parameters of the first iterate.
        params: &'a [LinearParams],
        /// Node positions of each example's first equilibrium solve, m.
        positions_m: &'a [Vec<Vector3<f64>>],
    },
}

impl<'a> FitStart<'a> {
    /// [`FitStart::Warm`] from an earlier fit of the same one example.
    pub fn from_fit(previous: &'a ExampleFit) -> Self {
        FitStart::Warm {
            params: &previous.params,
            positions_m: std::slice::from_ref(&previous.positions_m),
        }
    }
}

/// Result of [`fit_examples`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointFit {
    /// Fitted (λ_e, α_e) per tet (one field for all examples).
    pub params: Vec<LinearParams>,
    /// Equilibrium node positions of each example under the fitted parameters, m.
    pub positions_m: Vec<Vec<Vector3<f64>>>,
    /// Corotated Voigt strains of each example at its equilibrium.
    pub strains: Vec<Vec<Vector6<f64>>>,
    /// RMS marker error of each example before fitting, m.
    pub initial_rms_m: Vec<f64>,
    /// RMS marker error of each example after fitting, m.
    pub example_rms_m: Vec<f64>,
    /// RMS marker error over all examples after fitting, m.
    pub rms_m: f64,
    /// Cost after each accepted step (first entry: initial).
    pub cost_history: Vec<f64>,
    /// LM iterations performed.
    pub iterations: usize,
    /// Conjugate-gradient iterations of all damped steps (diagnostic).
    #[serde(default)]
    pub cg_iterations: usize,
    /// Worst equilibrium status of the final simulations.
    pub status: SolveStatus,
    /// Why the iteration stopped.
    #[serde(default)]
    pub stop: FitStop,
    /// Projected gradient ‖P g‖∞ at each linearization (first entry: the start).
    #[serde(default)]
    pub gradient_history: Vec<f64>,
}

impl From<JointFit> for ExampleFit {
    /// The fit of one example as an [`ExampleFit`] (of the last example when there are several).
    fn from(joint: JointFit) -> Self {
        let JointFit {
            params,
            mut positions_m,
            mut strains,
            mut initial_rms_m,
            mut example_rms_m,
            cost_history,
            iterations,
            cg_iterations,
            status,
            stop,
            gradient_history,
            ..
        } = joint;
        ExampleFit {
            params,
            positions_m: positions_m.pop().unwrap_or_default(),
            strains: strains.pop().unwrap_or_default(),
            initial_rms_m: initial_rms_m.pop().unwrap_or(0.0),
            rms_m: example_rms_m.pop().unwrap_or(0.0),
            cost_history,
            iterations,
            cg_iterations,
            status,
            stop,
            gradient_history,
        }
    }
}

/// Parameter estimation of bickel2009 eq. 9 — the one entry point of the per-example fit:
///
/// p̂ = argmin_p Σᵢ ‖xᵢ(p, F̄) − x̄ᵢ‖² + γ‖Lp‖²,
///
/// the sum running over the observed markers of `examples` with one heterogeneous linear field
/// p for all of them: one example is the per-example fit of §4.2 (convert the result with
/// `ExampleFit::from`); several give the heterogeneous counterpart of the average-fit
/// homogeneous model ([`crate::fit_homogeneous`], bickel2009 Fig. 8).
///
/// By a projected Levenberg–Marquardt iteration over q = (ln λ_e/λ_ref,e, ν_e) with box bounds
/// (Poisson's ratio stays in `nu_bounds`, so α = νλ is always physically valid). Each iteration
/// simulates the examples ([`ProbingSetup::simulate`]), builds the marker Jacobian by the adjoint
/// method (appendix eq. 10–12, [`Sensitivity`], one factorization per example for all its rows),
/// and solves the damped normal equations (J_mᵀJ_m + γLᵀL + γ_p I + μD) h = −g matrix-free by
/// preconditioned conjugate gradients (J_m is 3k × 2T and dense, L sparse;
/// [`crate::lm_step`]). `reference` gives λ_ref and q₀; γ_p (`gamma_prior`, default 0) shrinks
/// the fit toward it; `start` is the first iterate ([`FitStart`]).
///
/// Step control: the Marquardt scaling D is floored at `min_scaling` × its largest entry, and
/// the step is cut to a trust radius ‖h‖∞ ≤ r (r ≤ `max_step`, ×2 after an accepted step, ×¼
/// of the tried length after a rejected one; Moré 1978). Without it, parameters the markers
/// barely see (tets far from the probe, deep tets) get steps of ≈ 6 in ln λ at any damping,
/// are clamped at the bounds, and every step of a small-force example is rejected (measured,
/// docs/tissue.md).
pub fn fit_examples(
    setup: &ProbingSetup,
    examples: &[ProbeExample],
    reference: &[LinearParams],
    start: FitStart<'_>,
    settings: &ExampleFitSettings,
) -> Result<JointFit, FemError> {
    let (start_params, start_positions) = match start {
        FitStart::Reference => (reference, None),
        FitStart::Params(params) => (params, None),
        FitStart::Warm {
            params,
            positions_m,
        } => (params, Some(positions_m)),
    };
    let (space, q0, mut q) = ParameterSpace::new(setup, reference, start_params, settings)?;
    let problem = Eq9Problem::new(setup, examples, settings, space, q0);
    let t = setup.num_elements();
    let n = 2 * t;
    let mut scratch = UmbrellaScratch::new(t);
    let mut model = CorotationalModel::new(&setup.mesh, problem.space.params(&q))?;
    let mut solver = setup.solver(&model)?;
    let mut xs: Vec<Vec<Vector3<f64>>> = match start_positions {
        Some(p)
            if p.len() == examples.len()
                && p.iter().all(|x| x.len() == setup.mesh.vertices.len()) =>
        {
            p.to_vec()
        }
        _ => vec![setup.mesh.vertices.clone(); examples.len()],
    };

    let first = problem.simulate_all(&mut model, &mut solver, &q, &mut xs)?;
    let (mut rs, mut status) = (first.residuals, first.status);
    let initial_rms_m: Vec<f64> = rs.iter().map(|r| rms_of(r)).collect();
    let mut cost = sum_of_squares(&rs) + problem.regularization(&q, &mut scratch);
    let mut history = vec![cost];
    let mut iterations = 0;
    let mut mu_rel = settings.initial_damping;
    let max_radius = if settings.max_step > 0.0 {
        settings.max_step
    } else {
        f64::INFINITY
    };
    let mut radius = max_radius;
    let mut linearization = Linearization::new(n);
    let mut jac_valid = false;
    let mut cg_iterations = 0;

    let mut gradient_history = Vec::new();
    let stop = if problem.num_rows == 0 {
        FitStop::NoData
    } else {
        loop {
            if iterations >= settings.max_iterations {
                break FitStop::IterationCap;
            }
            if !jac_valid {
                problem.linearize(
                    &model,
                    &mut solver,
                    &q,
                    &xs,
                    &rs,
                    &mut scratch,
                    &mut linearization,
                )?;
                jac_valid = true;
                let pg = problem.projected_gradient_norm(&linearization, &q);
                gradient_history.push(pg);
                if pg <= settings.gradient_tolerance * gradient_history[0] {
                    break FitStop::Gradient;
                }
            }
            iterations += 1;
            let (h, cg) = problem.step(&linearization, &q, mu_rel, &mut scratch);
            cg_iterations += cg;
            // Trust region ‖h‖∞ ≤ radius on top of the damping: shortens the step uniformly.
            let h_inf = h.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let shrink = if h_inf > radius { radius / h_inf } else { 1.0 };
            let mut q_trial: Vec<f64> = (0..n).map(|i| q[i] + shrink * h[i]).collect();
            problem.space.clamp(&mut q_trial);
            let mut xs_trial = xs.clone();
            let trial = problem.simulate_all(&mut model, &mut solver, &q_trial, &mut xs_trial)?;
            let cost_trial =
                sum_of_squares(&trial.residuals) + problem.regularization(&q_trial, &mut scratch);
            if trial.converged && cost_trial.is_finite() && cost_trial < cost {
                let decrease = (cost - cost_trial) / cost.max(f64::MIN_POSITIVE);
                let moved = q_trial
                    .iter()
                    .zip(&q)
                    .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
                q = q_trial;
                xs = xs_trial;
                rs = trial.residuals;
                cost = cost_trial;
                status = trial.status;
                history.push(cost);
                jac_valid = false;
                mu_rel = (mu_rel / 3.0).max(1e-12);
                radius = (2.0 * radius).min(max_radius);
                if decrease < settings.relative_cost_tolerance {
                    break FitStop::Cost;
                }
                if moved <= settings.step_tolerance {
                    break FitStop::Step;
                }
            } else {
                // Restore the model to the accepted parameters.
                model.set_params(&problem.space.params(&q))?;
                mu_rel *= 4.0;
                if settings.max_step > 0.0 {
                    radius = 0.25 * radius.min(shrink * h_inf);
                }
                if mu_rel > 1e12 || radius < 1e-6 {
                    break FitStop::Stalled;
                }
            }
        }
    };
    let params = problem.space.params(&q);
    model.set_params(&params)?;
    let strains = xs.iter().map(|x| model.strains(x)).collect();
    let example_rms_m: Vec<f64> = rs.iter().map(|r| rms_of(r)).collect();
    let rms_m = rms_of(&rs.concat());
    Ok(JointFit {
        params,
        positions_m: xs,
        strains,
        initial_rms_m,
        example_rms_m,
        rms_m,
        cost_history: history,
        iterations,
        cg_iterations,
        status,
        stop,
        gradient_history,
    })
}

/// The unknowns of eq. 9 as q = (s, ν) ∈ ℝ^{2T}: λ_e = λ_ref,e · exp(s_e), α_e = ν_e λ_e, with
/// the box bounds of `lambda_factor_bounds` (on λ_e/λ_ref,e) and `nu_bounds`.
struct ParameterSpace {
    lambda_ref: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
}

impl ParameterSpace {
    /// The space of `reference` with q₀ (the reference field: s = 0 and its ν) and the first
    /// iterate (the `start` field), both clamped to the bounds. Checks one valid parameter set
    /// per tet in both fields and ν bounds inside (−1, 0.5).
    fn new(
        setup: &ProbingSetup,
        reference: &[LinearParams],
        start: &[LinearParams],
        settings: &ExampleFitSettings,
    ) -> Result<(Self, Vec<f64>, Vec<f64>), FemError> {
        let t = setup.num_elements();
        for (what, field) in [
            ("initial per-element parameters", reference),
            ("start per-element parameters", start),
        ] {
            if field.len() != t {
                return Err(FemError::LengthMismatch {
                    what,
                    expected: t,
                    got: field.len(),
                });
            }
            for (e, p) in field.iter().enumerate() {
                p.validate(e)?;
            }
        }
        let n = 2 * t;
        let (nlo, nhi) = settings.nu_bounds;
        if !(nlo > -1.0 && nhi < 0.5 && nlo <= nhi) {
            return Err(FemError::InvalidPoissonRatio {
                nu: if nhi >= 0.5 { nhi } else { nlo },
            });
        }
        let (flo, fhi) = settings.lambda_factor_bounds;
        let space = Self {
            lambda_ref: reference.iter().map(|p| p.lambda).collect(),
            lower: (0..n).map(|i| if i < t { flo.ln() } else { nlo }).collect(),
            upper: (0..n).map(|i| if i < t { fhi.ln() } else { nhi }).collect(),
        };
        let nu = |p: &LinearParams| p.alpha / p.lambda;
        let mut q0: Vec<f64> = (0..n)
            .map(|i| if i < t { 0.0 } else { nu(&reference[i - t]) })
            .collect();
        space.clamp(&mut q0);
        let mut q: Vec<f64> = (0..n)
            .map(|i| {
                if i < t {
                    (start[i].lambda / space.lambda_ref[i]).ln()
                } else {
                    nu(&start[i - t])
                }
            })
            .collect();
        space.clamp(&mut q);
        Ok((space, q0, q))
    }

    /// Per-tet (λ, α) of q.
    fn params(&self, q: &[f64]) -> Vec<LinearParams> {
        params_from_q(&self.lambda_ref, q)
    }

    /// q clamped to the box bounds.
    fn clamp(&self, q: &mut [f64]) {
        for i in 0..q.len() {
            q[i] = q[i].clamp(self.lower[i], self.upper[i]);
        }
    }
}

/// The simulations of every example at one q.
struct Simulated {
    /// Marker residuals of each example (3 per observed marker), m.
    residuals: Vec<Vec<f64>>,
    /// `Converged`, or the status of the last example that did not converge.
    status: SolveStatus,
    /// Every equilibrium converged.
    converged: bool,
}

/// The linearization of eq. 9 at the current iterate (rebuilt after every accepted step).
struct Linearization {
    /// J_m in q-space, one row after the other (= J_mᵀ column-major, n × rows).
    jm: Vec<f64>,
    /// g = J_mᵀ r + γ LᵀL q + γ_p (q − q₀).
    grad: Vec<f64>,
    /// Running maximum over the iterations of the diagonal of the normal matrix
    /// J_mᵀJ_m + γLᵀL + γ_p I (the Marquardt scaling D).
    diag_max: Vec<f64>,
}

impl Linearization {
    fn new(n: usize) -> Self {
        Self {
            jm: Vec::new(),
            grad: vec![0.0; n],
            diag_max: vec![0.0; n],
        }
    }
}

/// Eq. 9 over a set of examples: their force boundary conditions, the umbrella smoothing and the
/// shrinkage, and what is computed at one q — simulations, cost, linearization, damped step.
struct Eq9Problem<'a> {
    setup: &'a ProbingSetup,
    examples: &'a [ProbeExample],
    settings: &'a ExampleFitSettings,
    space: ParameterSpace,
    /// Nodal forces of each example (bickel2009 §4.1 force boundary condition).
    forces: Vec<Vec<Vector3<f64>>>,
    umbrella: Umbrella,
    /// (γ, γ_ν) on the (log-stiffness, Poisson-ratio) blocks.
    gammas: [f64; 2],
    /// The shrinkage target q₀ (the reference field).
    q0: Vec<f64>,
    /// γ_p scaled by the marker count: γ_p · 1e-8 m² · rows / 2T.
    prior_scale: f64,
    /// Observed marker coordinates over all examples.
    num_rows: usize,
}

impl<'a> Eq9Problem<'a> {
    fn new(
        setup: &'a ProbingSetup,
        examples: &'a [ProbeExample],
        settings: &'a ExampleFitSettings,
        space: ParameterSpace,
        q0: Vec<f64>,
    ) -> Self {
        let t = setup.num_elements();
        let num_rows: usize = examples.iter().map(|e| 3 * e.observed.len()).sum();
        let prior = settings.gamma_prior.max(0.0);
        Self {
            setup,
            examples,
            settings,
            forces: examples
                .iter()
                .map(|ex| setup.nodal_forces(ex, &settings.patch))
                .collect(),
            umbrella: Umbrella::new(&setup.adjacency),
            gammas: [settings.gamma_m2, settings.gamma_nu_m2],
            q0,
            prior_scale: prior * 1e-8 * num_rows as f64 / (2 * t) as f64,
            num_rows,
            space,
        }
    }

    /// The terms of the eq. 9 cost beyond the markers: γ‖L s‖² + γ_ν‖L ν‖² + γ_p‖q − q₀‖²
    /// (γ_p scaled by the marker count).
    fn regularization(&self, q: &[f64], scratch: &mut UmbrellaScratch) -> f64 {
        self.umbrella.smoothing_cost(q, self.gammas, scratch)
            + self.prior_scale
                * q.iter()
                    .zip(&self.q0)
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum::<f64>()
    }

    /// Simulates every example with the parameters q, each warm-started from its entry of `xs`.
    fn simulate_all(
        &self,
        model: &mut CorotationalModel,
        solver: &mut StaticSolver,
        q: &[f64],
        xs: &mut [Vec<Vector3<f64>>],
    ) -> Result<Simulated, FemError> {
        model.set_params(&self.space.params(q))?;
        let mut residuals = Vec::with_capacity(self.examples.len());
        let mut status = SolveStatus::Converged;
        let mut converged = true;
        for (k, ex) in self.examples.iter().enumerate() {
            let rep = self.setup.simulate(
                solver,
                model,
                &mut xs[k],
                &self.forces[k],
                &self.settings.equilibrium,
            );
            if !rep.converged() {
                converged = false;
                status = rep.status.clone();
            }
            residuals.push(marker_residuals(self.setup, ex, &xs[k]));
        }
        Ok(Simulated {
            residuals,
            status,
            converged,
        })
    }

    /// Rebuilds `lin` at q (the model holds q, `xs` are the equilibria and `rs` the residuals
    /// there): J_m by the adjoint method (the `jacobian` stiffness, the warped one if that
    /// fails) with the chain rule to q, the gradient and the diagonal.
    #[allow(clippy::too_many_arguments)]
    fn linearize(
        &self,
        model: &CorotationalModel,
        solver: &mut StaticSolver,
        q: &[f64],
        xs: &[Vec<Vector3<f64>>],
        rs: &[Vec<f64>],
        scratch: &mut UmbrellaScratch,
        lin: &mut Linearization,
    ) -> Result<(), FemError> {
        let t = self.setup.num_elements();
        let n = 2 * t;
        let params = model.params().to_vec();
        lin.jm.clear();
        for (k, ex) in self.examples.iter().enumerate() {
            let rows = marker_jacobian(
                self.setup,
                solver,
                model,
                ex,
                &xs[k],
                self.settings.jacobian,
            )
            .or_else(|_| {
                marker_jacobian(self.setup, solver, model, ex, &xs[k], StiffnessKind::Warped)
            })?;
            // Chain rule to q: ∂/∂s_e = λ_e (∂/∂λ_e + ν_e ∂/∂α_e), ∂/∂ν_e = λ_e ∂/∂α_e.
            for row in &rows {
                let start = lin.jm.len();
                lin.jm.resize(start + n, 0.0);
                let out = &mut lin.jm[start..];
                for e in 0..t {
                    let (jl, ja) = (row[2 * e], row[2 * e + 1]);
                    let lam = params[e].lambda;
                    let nu = q[t + e];
                    out[e] = lam * (jl + nu * ja);
                    out[t + e] = lam * ja;
                }
            }
        }
        // g = J_mᵀ r + γ Lᵀ L q + γ_p (q − q₀) (L symmetric); Σ_rows J_m² per column.
        lin.grad.iter_mut().for_each(|g| *g = 0.0);
        let mut col_sq = vec![0.0; n];
        for (row, ri) in lin.jm.chunks_exact(n).zip(rs.iter().flatten()) {
            for i in 0..n {
                lin.grad[i] += row[i] * ri;
                col_sq[i] += row[i] * row[i];
            }
        }
        self.umbrella
            .add_smoothing(q, self.gammas, scratch, &mut lin.grad);
        for i in 0..n {
            lin.grad[i] += self.prior_scale * (q[i] - self.q0[i]);
            let deg = self.umbrella.degree(i % t) as f64;
            let gamma = self.gammas[usize::from(i >= t)];
            let d = col_sq[i] + gamma * (deg * deg + deg) + self.prior_scale;
            lin.diag_max[i] = lin.diag_max[i].max(d);
        }
        Ok(())
    }

    /// ‖P g‖∞: the gradient with the components that push against an active bound removed
    /// (the same free set as [`Self::step`]).
    fn projected_gradient_norm(&self, lin: &Linearization, q: &[f64]) -> f64 {
        let (lower, upper) = (&self.space.lower, &self.space.upper);
        (0..q.len())
            .filter(|&i| {
                let g = lin.grad[i];
                !((q[i] <= lower[i] && g > 0.0) || (q[i] >= upper[i] && g < 0.0))
            })
            .fold(0.0f64, |m, i| m.max(lin.grad[i].abs()))
    }

    /// The damped step h at q ([`marquardt_step`] with damping `mu_rel`) on the variables not
    /// held at a bound by the gradient; returns it with its CG iterations.
    fn step(
        &self,
        lin: &Linearization,
        q: &[f64],
        mu_rel: f64,
        scratch: &mut UmbrellaScratch,
    ) -> (Vec<f64>, usize) {
        let (lower, upper, grad) = (&self.space.lower, &self.space.upper, &lin.grad);
        let free: Vec<bool> = (0..q.len())
            .map(|i| !((q[i] <= lower[i] && grad[i] > 0.0) || (q[i] >= upper[i] && grad[i] < 0.0)))
            .collect();
        marquardt_step(
            &self.umbrella,
            scratch,
            &lin.jm,
            grad,
            &free,
            &lin.diag_max,
            mu_rel,
            self.prior_scale,
            self.gammas,
            self.settings,
        )
    }
}

/// The Levenberg–Marquardt step of eq. 9: h solving
///
/// (J_mᵀJ_m + γLᵀL + γ_p I + μD) h = −g
///
/// on the `free` variables, with the Marquardt scaling D = `diag_max` (the running maximum of
/// the normal matrix's diagonal) floored at `min_scaling` × its largest entry (Moré 1978 §5),
/// and μ = `mu` **dimensionless**: the damping term μD has the units of the normal matrix, so
/// the step does not change when the residual's unit does (Marquardt 1963 scales by
/// diag(JᵀJ); Nocedal & Wright §10.3, eq. 10.33 with D² = diag(JᵀJ); Moré 1978 eq. 2.3).
/// μ → 0 is the Gauss–Newton step, μ → ∞ the scaled gradient step −g/(μD).
#[allow(clippy::too_many_arguments)]
fn marquardt_step(
    umbrella: &Umbrella,
    scratch: &mut UmbrellaScratch,
    jm: &[f64],
    grad: &[f64],
    free: &[bool],
    diag_max: &[f64],
    mu: f64,
    prior_scale: f64,
    gammas: [f64; 2],
    settings: &ExampleFitSettings,
) -> (Vec<f64>, usize) {
    let dmax = diag_max.iter().copied().fold(0.0, f64::max).max(1e-300);
    let floor = settings.min_scaling.max(0.0) * dmax;
    let scaling: Vec<f64> = diag_max.iter().map(|d| d.max(floor)).collect();
    damped_step(
        umbrella,
        scratch,
        jm,
        grad,
        free,
        &scaling,
        mu,
        prior_scale,
        gammas,
        settings.cg_iterations,
        settings.cg_tolerance,
        settings.preconditioner,
    )
}

/// Σ‖r‖² over the stacked residuals.
fn sum_of_squares(rs: &[Vec<f64>]) -> f64 {
    rs.iter().flatten().map(|v| v * v).sum::<f64>()
}

#[cfg(test)]
mod tests {
    use super::{ExampleFitSettings, marquardt_step};
    use crate::lm_step::{Umbrella, UmbrellaScratch};
    use nalgebra::{DMatrix, DVector};

    /// Deterministic entries in [−1, 1) (a fixed hash of the index, no RNG).
    fn entries(len: usize, salt: u64) -> Vec<f64> {
        (0..len as u64)
            .map(|i| {
                let h = (i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ salt)
                    .wrapping_mul(0xBF58_476D_1CE4_E5B9);
                2.0 * ((h >> 11) as f64 / (1u64 << 53) as f64) - 1.0
            })
            .collect()
    }

    /// A small eq. 9 problem: 4 tets in a chain (n = 8 unknowns), 5 marker rows, J_m in
    /// metres per unit q (entries ≈ `unit`), the umbrella smoothing and the shrinkage scaled
    /// like J_mᵀJ_m. Returns (J_m rows flat, g, D = diag of the normal matrix, γ_p, γ).
    fn problem(unit: f64) -> (Vec<f64>, Vec<f64>, Vec<f64>, f64, [f64; 2]) {
        let (t, rows) = (4, 5);
        let n = 2 * t;
        let jm: Vec<f64> = entries(n * rows, 7).iter().map(|v| unit * v).collect();
        let r: Vec<f64> = entries(rows, 11).iter().map(|v| unit * v).collect();
        let (prior, gammas) = (0.05 * unit * unit, [0.02 * unit * unit, 0.1 * unit * unit]);
        let normal = normal_matrix(&jm, n, prior, gammas);
        let mut g = vec![0.0; n];
        for (row, ri) in jm.chunks_exact(n).zip(&r) {
            for i in 0..n {
                g[i] += row[i] * ri;
            }
        }
        let diag = (0..n).map(|i| normal[(i, i)]).collect();
        (jm, g, diag, prior, gammas)
    }

    /// J_mᵀJ_m + γLᵀL + γ_p I as a dense matrix, L the umbrella operator of the chain 0–1–2–3.
    fn normal_matrix(jm: &[f64], n: usize, prior: f64, gammas: [f64; 2]) -> DMatrix<f64> {
        let t = n / 2;
        let rows = jm.len() / n;
        let j = DMatrix::from_row_slice(rows, n, jm);
        let mut l = DMatrix::<f64>::zeros(t, t);
        for (i, nb) in chain(t).iter().enumerate() {
            l[(i, i)] = nb.len() as f64;
            for &k in nb {
                l[(i, k)] -= 1.0;
            }
        }
        let ll = l.transpose() * &l;
        let mut a = j.transpose() * j + DMatrix::identity(n, n) * prior;
        for b in 0..2 {
            let mut block = a.view_mut((b * t, b * t), (t, t));
            block += &ll * gammas[b];
        }
        a
    }

    fn chain(t: usize) -> Vec<Vec<usize>> {
        (0..t)
            .map(|i| {
                [i.checked_sub(1), (i + 1 < t).then_some(i + 1)]
                    .into_iter()
                    .flatten()
                    .collect()
            })
            .collect()
    }

    fn settings() -> ExampleFitSettings {
        ExampleFitSettings {
            min_scaling: 0.0,
            cg_iterations: 200,
            cg_tolerance: 1e-14,
            ..ExampleFitSettings::default()
        }
    }

    fn step(unit: f64, mu: f64, free: &[bool]) -> Vec<f64> {
        let (jm, g, diag, prior, gammas) = problem(unit);
        let umbrella = Umbrella::new(&chain(4));
        let mut scratch = UmbrellaScratch::new(4);
        let free = free.to_vec();
        marquardt_step(
            &umbrella,
            &mut scratch,
            &jm,
            &g,
            &free,
            &diag,
            mu,
            prior,
            gammas,
            &settings(),
        )
        .0
    }

    /// The closed form h = −(N + μ diag N)⁻¹ g on the free variables (N the normal matrix), by a
    /// dense LU.
    fn closed_form(unit: f64, mu: f64, free: &[bool]) -> Vec<f64> {
        let (jm, g, diag, prior, gammas) = problem(unit);
        let n = g.len();
        let mut a = normal_matrix(&jm, n, prior, gammas);
        for i in 0..n {
            a[(i, i)] += mu * diag[i];
        }
        let idx: Vec<usize> = (0..n).filter(|&i| free[i]).collect();
        let af = DMatrix::from_fn(idx.len(), idx.len(), |a_, b| a[(idx[a_], idx[b])]);
        let gf = DVector::from_iterator(idx.len(), idx.iter().map(|&i| -g[i]));
        let hf = af.lu().solve(&gf).unwrap();
        let mut h = vec![0.0; n];
        for (k, &i) in idx.iter().enumerate() {
            h[i] = hf[k];
        }
        h
    }

    fn max_rel(a: &[f64], b: &[f64]) -> f64 {
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        a.iter()
            .zip(b)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs() / scale))
    }

    /// The LM step is (N + μ diag N)⁻¹(−g) with μ dimensionless (Marquardt 1963; Nocedal &
    /// Wright §10.3): against the dense closed form at μ from Gauss–Newton (10⁻⁹) to strongly
    /// damped (10³), all unknowns free and two held at a bound; tolerance 10⁻⁸ of the largest
    /// entry (CG to 10⁻¹⁴ on 8 unknowns).
    #[test]
    fn marquardt_step_matches_the_closed_form() {
        let all = [true; 8];
        let mut some = all;
        some[1] = false;
        some[6] = false;
        for mu in [1e-9, 1e-3, 1.0, 1e3] {
            for free in [&all, &some] {
                let (h, want) = (step(1e-4, mu, free), closed_form(1e-4, mu, free));
                assert!(max_rel(&h, &want) < 1e-8, "μ {mu}: {h:?} vs {want:?}");
                for i in (0..8).filter(|&i| !free[i]) {
                    assert_eq!(h[i], 0.0);
                }
            }
        }
        // μ → ∞: the scaled gradient step −g/(μD), to O(1/μ).
        let (_, g, diag, ..) = problem(1e-4);
        let mu = 1e8;
        let h = step(1e-4, mu, &all);
        let sd: Vec<f64> = g.iter().zip(&diag).map(|(g, d)| -g / (mu * d)).collect();
        assert!(max_rel(&h, &sd) < 1e-6, "{h:?} vs {sd:?}");
    }

    /// The step does not depend on the residual's unit: the same problem in metres (J_m
    /// entries ≈ 10⁻⁴) and in millimetres (≈ 10⁻¹, the normal matrix 10⁶ larger) gives the
    /// same h at the same μ, to 10⁻⁸. A damping μ · max D · D (the damping scaled by the
    /// largest diagonal once more) is 10⁶ stronger in millimetres and fails this.
    #[test]
    fn marquardt_step_is_unit_invariant() {
        let all = [true; 8];
        for mu in [1e-3, 1.0] {
            let (m, mm) = (step(1e-4, mu, &all), step(1e-1, mu, &all));
            assert!(max_rel(&mm, &m) < 1e-8, "μ {mu}: {m:?} vs {mm:?}");
        }
    }
}
