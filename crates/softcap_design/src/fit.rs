//! Fitting base materials to probe examples (thesis §8.3).
//!
//! Given example deformations of a homogeneous block — measured surface-marker displacements x̄ᵢ
//! under measured probe forces F̄ᵢ — the RBF weights minimize eq. 8.3,
//! ŵ = argmin Σᵢ ‖xᵢ(p, F̄ᵢ) − x̄ᵢ‖², over *all examples together* by Levenberg–Marquardt
//! (derivatives by finite differences of the full non-linear simulation). The RBF centres come
//! from a homogeneous linear pre-fit: the material is first fitted as a constant (λ, μ), all
//! examples are simulated with it, and P centres are placed by k-means over the element strains
//! they produce (scaled invariants) so that they cover the measured strain range.
//!
//! Missing tangential probe forces (§8.3): the measured force is normal to the surface, but the
//! probe also pulls the contact patch tangentially. With [`BaseFitSettings::tangential`] the
//! tangential forces "that would produce a perfect match at the probed surface points" are
//! computed — by simulating each example with the patch nodes' tangential coordinates held at
//! their measured positions and reading the reaction forces there — and then reintroduced as
//! known nodal forces in the optimization.

use crate::error::{DesignError, Result};
use crate::material::{BaseMaterial, InvariantMaterial, TransverseMaterial, TransverseParams};
use crate::model::CompositeModel;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_core::{
    KMeansSettings, LeastSquaresProblem, LevenbergMarquardtSettings, kmeans, levenberg_marquardt,
};
use softcap_fem::{DirichletBc, ElasticModel, EquilibriumSettings, StaticSolver};
use softcap_mesh::TetMesh;
use std::sync::Arc;

/// One probe example on a base-material block.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeExample {
    /// Top-surface nodes under the probe.
    pub patch_nodes: Vec<usize>,
    /// Measured probe force on the object \[N\] (normal component only, as measured).
    pub force_n: [f64; 3],
    /// Observed marker nodes.
    pub marker_nodes: Vec<usize>,
    /// Observed marker displacements \[m\], one per marker node.
    pub displacements_m: Vec<[f64; 3]>,
}

/// A homogeneous block with bottom fixed, and its examples.
#[derive(Clone, Debug)]
pub struct BaseMeasurements {
    /// The block mesh \[m\].
    pub mesh: TetMesh,
    /// Fixed nodes (the bottom).
    pub fixed_nodes: Vec<usize>,
    /// Examples.
    pub examples: Vec<ProbeExample>,
}

/// Settings of the base-material fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BaseFitSettings {
    /// RBF centres P (thesis: 6 for isotropic materials).
    pub centres: usize,
    /// Load increments per example.
    pub increments: usize,
    /// Reintroduce the missing tangential probe forces.
    pub tangential: bool,
    /// LM of the final fit.
    pub lm: LevenbergMarquardtSettings,
    /// Equilibrium iterations.
    pub equilibrium: EquilibriumSettings,
}

impl Default for BaseFitSettings {
    fn default() -> Self {
        Self {
            centres: 6,
            increments: 2,
            tangential: true,
            lm: LevenbergMarquardtSettings {
                max_iterations: 30,
                relative_cost_tolerance: 1e-8,
                finite_difference: softcap_core::FiniteDifference::Forward,
                ..LevenbergMarquardtSettings::default()
            },
            equilibrium: EquilibriumSettings {
                max_iterations: 200,
                displacement_tol_rel: 1e-8,
                residual_tol_rel: 1e-7,
                line_search: false,
                ..EquilibriumSettings::default()
            },
        }
    }
}

/// Result of a base-material fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BaseFitReport {
    /// Fitted material.
    pub material: BaseMaterial,
    /// The homogeneous linear pre-fit (§8.3).
    pub prefit: BaseMaterial,
    /// RMS marker error of the linear pre-fit \[m\].
    pub linear_rms_m: f64,
    /// RMS marker error of the final fit \[m\].
    pub rms_m: f64,
    /// LM status of the final fit.
    pub status: String,
    /// Simulations of all examples performed.
    pub evaluations: usize,
}

/// Simulates every example of `meas` with `material` and extra known nodal forces
/// (`extra[k]`: (node, force) of example k); returns marker displacements, example-major.
pub fn simulate_examples(
    meas: &BaseMeasurements,
    material: &BaseMaterial,
    extra: &[Vec<(usize, Vector3<f64>)>],
    settings: &BaseFitSettings,
) -> Result<Vec<f64>> {
    let mats = Arc::new(vec![material.clone()]);
    let mut model = CompositeModel::new(&meas.mesh, mats, vec![0; meas.mesh.tets.len()])?;
    let mut bc = DirichletBc::new();
    for &i in &meas.fixed_nodes {
        bc.fix_node(i, meas.mesh.vertices[i]);
    }
    let mut solver = StaticSolver::new(&model, &bc.dofs())?;
    let mut out = Vec::new();
    for (k, ex) in meas.examples.iter().enumerate() {
        let x = solve_example(
            &mut solver,
            &mut model,
            meas,
            ex,
            extra.get(k),
            None,
            settings,
        )?;
        for &i in &ex.marker_nodes {
            let u = x[i] - meas.mesh.vertices[i];
            out.extend_from_slice(&[u.x, u.y, u.z]);
        }
    }
    Ok(out)
}

/// Simulates every example of `meas` with `material` (no extra forces); returns all node
/// positions \[m\] per example (e.g. for the element strains the examples produce).
pub fn simulate_positions(
    meas: &BaseMeasurements,
    material: &BaseMaterial,
    settings: &BaseFitSettings,
) -> Result<Vec<Vec<Vector3<f64>>>> {
    let mats = Arc::new(vec![material.clone()]);
    let mut model = CompositeModel::new(&meas.mesh, mats, vec![0; meas.mesh.tets.len()])?;
    let mut bc = DirichletBc::new();
    for &i in &meas.fixed_nodes {
        bc.fix_node(i, meas.mesh.vertices[i]);
    }
    let mut solver = StaticSolver::new(&model, &bc.dofs())?;
    meas.examples
        .iter()
        .map(|ex| solve_example(&mut solver, &mut model, meas, ex, None, None, settings))
        .collect()
}

fn solve_example(
    solver: &mut StaticSolver,
    model: &mut CompositeModel,
    meas: &BaseMeasurements,
    ex: &ProbeExample,
    extra: Option<&Vec<(usize, Vector3<f64>)>>,
    pinned: Option<&DirichletBc>,
    settings: &BaseFitSettings,
) -> Result<Vec<Vector3<f64>>> {
    let n = meas.mesh.vertices.len();
    let mut x = meas.mesh.vertices.clone();
    let inc = settings.increments.max(1);
    let share = 1.0 / ex.patch_nodes.len().max(1) as f64;
    let f = Vector3::from(ex.force_n);
    for s in 1..=inc {
        let t = s as f64 / inc as f64;
        let mut f_ext = vec![Vector3::zeros(); n];
        for &i in &ex.patch_nodes {
            f_ext[i] += f * (share * t);
        }
        if let Some(e) = extra {
            for (i, g) in e {
                f_ext[*i] += g * t;
            }
        }
        if let Some(p) = pinned {
            // Interpolate the pinned tangential coordinates from rest to measured.
            for (&dof, &v) in &p.values {
                let rest = meas.mesh.vertices[dof / 3][dof % 3];
                x[dof / 3][dof % 3] = rest + t * (v - rest);
            }
        }
        let rep = solver.solve(model, &mut x, &f_ext, None, &settings.equilibrium);
        if !rep.converged() {
            return Err(DesignError::NotConverged {
                what: format!("base example at t = {t:.2}"),
                status: format!("{:?}", rep.status),
            });
        }
    }
    Ok(x)
}

/// The missing tangential probe forces of every example (thesis §8.3): the reactions at the
/// patch nodes when their tangential (x, y) coordinates are held at the measured positions.
pub fn tangential_forces(
    meas: &BaseMeasurements,
    material: &BaseMaterial,
    settings: &BaseFitSettings,
) -> Result<Vec<Vec<(usize, Vector3<f64>)>>> {
    let mats = Arc::new(vec![material.clone()]);
    let mut out = Vec::new();
    for ex in &meas.examples {
        let mut bc = DirichletBc::new();
        for &i in &meas.fixed_nodes {
            bc.fix_node(i, meas.mesh.vertices[i]);
        }
        let mut pinned = DirichletBc::new();
        for &i in &ex.patch_nodes {
            let Some(m) = ex.marker_nodes.iter().position(|&j| j == i) else {
                continue; // a patch node without an observation stays free
            };
            for c in 0..2 {
                let v = meas.mesh.vertices[i][c] + ex.displacements_m[m][c];
                bc.fix_dof(3 * i + c, v);
                pinned.fix_dof(3 * i + c, v);
            }
        }
        let mut model =
            CompositeModel::new(&meas.mesh, mats.clone(), vec![0; meas.mesh.tets.len()])?;
        let mut solver = StaticSolver::new(&model, &bc.dofs())?;
        let x = solve_example(
            &mut solver,
            &mut model,
            meas,
            ex,
            None,
            Some(&pinned),
            settings,
        )?;
        model.update_state(&x);
        let f_int = model.internal_forces(&x);
        let share = 1.0 / ex.patch_nodes.len().max(1) as f64;
        let f = Vector3::from(ex.force_n);
        let mut forces = Vec::new();
        for &i in &ex.patch_nodes {
            if pinned.values.contains_key(&(3 * i)) {
                // Reaction = f_int − f_ext at the pinned dofs (tangential components only).
                let r = f_int[i] - f * share;
                forces.push((i, Vector3::new(r.x, r.y, 0.0)));
            }
        }
        out.push(forces);
    }
    Ok(out)
}

struct FitProblem<'a> {
    meas: &'a BaseMeasurements,
    material: BaseMaterial,
    extra: Vec<Vec<(usize, Vector3<f64>)>>,
    observed: Vec<f64>,
    settings: &'a BaseFitSettings,
    /// Parameters are optimized relative to these scales (Pa → O(1)).
    scale: Vec<f64>,
    evaluations: usize,
}

impl LeastSquaresProblem for FitProblem<'_> {
    fn num_params(&self) -> usize {
        self.scale.len()
    }
    fn num_residuals(&self) -> usize {
        self.observed.len()
    }
    fn residuals(&mut self, params: &[f64], residuals: &mut [f64]) {
        let theta: Vec<f64> = params.iter().zip(&self.scale).map(|(p, s)| p * s).collect();
        self.material.rbf_mut().set_parameters(&theta);
        self.evaluations += 1;
        match simulate_examples(self.meas, &self.material, &self.extra, self.settings) {
            Ok(x) => {
                for (r, (a, b)) in residuals.iter_mut().zip(x.iter().zip(&self.observed)) {
                    *r = a - b;
                }
            }
            Err(_) => residuals.fill(f64::NAN),
        }
    }
}

fn observed(meas: &BaseMeasurements) -> Vec<f64> {
    meas.examples
        .iter()
        .flat_map(|e| e.displacements_m.iter().flat_map(|d| d.iter().copied()))
        .collect()
}

fn rms(r: &[f64]) -> f64 {
    (r.iter().map(|v| v * v).sum::<f64>() / (r.len() / 3).max(1) as f64).sqrt()
}

/// Fits an isotropic base material (thesis §8.3, eq. 8.1–8.3, see module docs), starting the
/// pre-fit from Young's modulus `young_guess_pa` (ν = 0.3).
pub fn fit_isotropic(
    meas: &BaseMeasurements,
    young_guess_pa: f64,
    settings: &BaseFitSettings,
) -> Result<BaseFitReport> {
    fit_base(
        meas,
        BaseMaterial::Isotropic(InvariantMaterial::from_young_poisson(young_guess_pa, 0.3)),
        settings,
    )
}

/// Fits a transversely isotropic base material (thesis §8.3 with the five parameters of eq. 8.5,
/// tubes along z): p(ε) = (E11, E12, E13, E33, E44) as an RBF over the 6-D Voigt strain, every
/// evaluation projected to a positive-definite transversely isotropic matrix
/// ([`crate::project_transverse`], the Rebonato–Jäckel clipping §8.3 cites); linear pre-fit of
/// the five constants from `start`, centres by k-means over the pre-fit's element strains
/// (scaled per component), then LM over (p₀, w) on all examples together (eq. 8.3).
pub fn fit_transverse(
    meas: &BaseMeasurements,
    start: TransverseParams,
    settings: &BaseFitSettings,
) -> Result<BaseFitReport> {
    fit_base(
        meas,
        BaseMaterial::Transverse(TransverseMaterial::linear(start)),
        settings,
    )
}

/// The §8.3 fit of a base material of either kind starting from the linear material `start`
/// (see module docs and [`fit_isotropic`], [`fit_transverse`]).
pub fn fit_base(
    meas: &BaseMeasurements,
    start: BaseMaterial,
    settings: &BaseFitSettings,
) -> Result<BaseFitReport> {
    let obs = observed(meas);
    if obs.is_empty() {
        return Err(DesignError::Invalid {
            field: "examples",
            reason: "no observed markers".into(),
        });
    }
    let p0 = start.rbf().constant.clone();
    let k_out = p0.len();
    let no_extra = vec![Vec::new(); meas.examples.len()];
    // 1. Homogeneous linear pre-fit (parameters relative to the start: O(1)).
    let pre_scale: Vec<f64> = p0.iter().map(|v| v.abs().max(1.0)).collect();
    let pre_init: Vec<f64> = p0.iter().zip(&pre_scale).map(|(v, s)| v / s).collect();
    let mut lin = FitProblem {
        meas,
        material: start,
        extra: no_extra.clone(),
        observed: obs.clone(),
        settings,
        scale: pre_scale.clone(),
        evaluations: 0,
    };
    let rep = levenberg_marquardt(&mut lin, &pre_init, None, &settings.lm)?;
    let lin_theta: Vec<f64> = rep
        .params
        .iter()
        .zip(&pre_scale)
        .map(|(p, s)| p * s)
        .collect();
    lin.material.rbf_mut().set_parameters(&lin_theta);
    let linear_rms_m = rms(&rep.residuals);
    let mut evaluations = lin.evaluations;
    let mut material = lin.material.clone();
    let prefit = material.clone();
    // 2. Missing tangential forces under the pre-fit material.
    let extra = if settings.tangential {
        tangential_forces(meas, &material, settings)?
    } else {
        no_extra
    };
    // 3. Centres from the pre-fit strains (invariants or Voigt strain, scaled per component).
    let mats = Arc::new(vec![material.clone()]);
    let model = CompositeModel::new(&meas.mesh, mats, vec![0; meas.mesh.tets.len()])?;
    let mut bc = DirichletBc::new();
    for &i in &meas.fixed_nodes {
        bc.fix_node(i, meas.mesh.vertices[i]);
    }
    let mut solver = StaticSolver::new(&model, &bc.dofs())?;
    let mut model = model;
    let mut coords: Vec<Vec<f64>> = Vec::new();
    for (k, ex) in meas.examples.iter().enumerate() {
        let x = solve_example(
            &mut solver,
            &mut model,
            meas,
            ex,
            extra.get(k),
            None,
            settings,
        )?;
        for e in model.strains(&x) {
            coords.push(material.coordinates(&e));
        }
    }
    let dim = coords.first().map_or(0, Vec::len);
    let mut scale = vec![0.0f64; dim];
    for c in &coords {
        for k in 0..dim {
            scale[k] = scale[k].max(c[k].abs());
        }
    }
    let scale: Vec<f64> = scale
        .into_iter()
        .map(|s| if s > 0.0 { s } else { 1.0 })
        .collect();
    let pts: Vec<f64> = coords
        .iter()
        .flat_map(|c| c.iter().zip(&scale).map(|(v, s)| v / s))
        .collect();
    let p = settings.centres.min(coords.len()).max(1);
    let km = kmeans(
        &pts,
        dim,
        p,
        &KMeansSettings {
            seed: 83,
            ..KMeansSettings::default()
        },
    )?;
    {
        let rbf = material.rbf_mut();
        rbf.scale = scale;
        rbf.centres = km.centroids.chunks(dim).map(|c| c.to_vec()).collect();
        rbf.weights = vec![vec![0.0; k_out]; p];
    }
    // 4. LM over (p₀, w) on all examples together (eq. 8.3).
    let pscale: Vec<f64> = (0..=p)
        .flat_map(|i| {
            let f = if i == 0 { 1.0 } else { 0.1 };
            lin_theta.iter().map(move |v| v.abs().max(1.0) * f)
        })
        .collect();
    let init: Vec<f64> = material
        .rbf()
        .parameters()
        .iter()
        .zip(&pscale)
        .map(|(v, s)| v / s)
        .collect();
    let mut full = FitProblem {
        meas,
        material,
        extra,
        observed: obs,
        settings,
        scale: pscale,
        evaluations: 0,
    };
    let rep = levenberg_marquardt(&mut full, &init, None, &settings.lm)?;
    let theta: Vec<f64> = rep
        .params
        .iter()
        .zip(&full.scale)
        .map(|(p, s)| p * s)
        .collect();
    full.material.rbf_mut().set_parameters(&theta);
    evaluations += full.evaluations;
    Ok(BaseFitReport {
        material: full.material,
        prefit,
        linear_rms_m,
        rms_m: rms(&rep.residuals),
        status: format!("{:?}", rep.status),
        evaluations,
    })
}

/// The bottom (fixed) and top (probed, observed) face nodes of a block mesh, within 1 nm of the
/// lowest and highest z.
fn block_faces(mesh: &TetMesh) -> (Vec<usize>, Vec<usize>) {
    let eps = 1e-9;
    let (zmin, zmax) = mesh
        .vertices
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v.z), hi.max(v.z))
        });
    let on = |z: f64| -> Vec<usize> {
        (0..mesh.vertices.len())
            .filter(|&i| (mesh.vertices[i].z - z).abs() < eps)
            .collect()
    };
    (on(zmin), on(zmax))
}

/// The `top` nodes within `probe_radius_m` (x, y distance) of the probe centre `c`; an error when
/// there is none.
fn probe_patch(
    mesh: &TetMesh,
    top: &[usize],
    c: [f64; 2],
    probe_radius_m: f64,
) -> Result<Vec<usize>> {
    let patch: Vec<usize> = top
        .iter()
        .copied()
        .filter(|&i| {
            let v = mesh.vertices[i];
            ((v.x - c[0]).powi(2) + (v.y - c[1]).powi(2)).sqrt() <= probe_radius_m + 1e-9
        })
        .collect();
    if patch.is_empty() {
        return Err(DesignError::Invalid {
            field: "probe centre",
            reason: format!("no top node within {probe_radius_m} m of {c:?}"),
        });
    }
    Ok(patch)
}

/// Probe examples of a known base material on a block, simulated with the same composite FEM the
/// §8.3 fit uses (so the full probe force is known: no missing tangential forces): the bottom
/// face is fixed, every top-face node is an observed marker, and example k shares `loads[k].1`
/// (force on the object \[N\], any direction) among the top nodes within `probe_radius_m` of
/// `loads[k].0` (x, y \[m\]). The virtual measurements of the fitting tests and of the
/// fitted-library example.
pub fn simulate_block_probes(
    mesh: &TetMesh,
    truth: &BaseMaterial,
    loads: &[([f64; 2], [f64; 3])],
    probe_radius_m: f64,
    settings: &BaseFitSettings,
) -> Result<BaseMeasurements> {
    let (fixed_nodes, top) = block_faces(mesh);
    let mut examples = Vec::with_capacity(loads.len());
    for &(c, force_n) in loads {
        let patch_nodes = probe_patch(mesh, &top, c, probe_radius_m)?;
        examples.push(ProbeExample {
            patch_nodes,
            force_n,
            marker_nodes: top.clone(),
            displacements_m: vec![[0.0; 3]; top.len()],
        });
    }
    let mut meas = BaseMeasurements {
        mesh: mesh.clone(),
        fixed_nodes,
        examples,
    };
    let x = simulate_examples(&meas, truth, &[], settings)?;
    let n = top.len();
    for (k, ex) in meas.examples.iter_mut().enumerate() {
        for (a, d) in ex.displacements_m.iter_mut().enumerate() {
            let o = 3 * (k * n + a);
            *d = [x[o], x[o + 1], x[o + 2]];
        }
    }
    Ok(meas)
}

/// Probe examples on a homogeneous block generated with softcap_fem directly (no recordings of
/// base materials exist): ground truth is the stable neo-Hookean model (a known non-linear
/// material) on `mesh`, the probe presses the top face with force `force_n` (−z) shared by the
/// top nodes within `probe_radius_m` of `centre_xy_m`; with `sticky` the patch nodes cannot
/// slide (x, y held), which produces the tangential probe forces of §8.3 that a normal-force
/// sensor does not measure. All top-face nodes are the observed markers.
pub fn synthesize_measurements(
    mesh: &TetMesh,
    truth: softcap_fem::NeoHookeanParams,
    examples: &[([f64; 2], f64)],
    probe_radius_m: f64,
    sticky: bool,
) -> Result<BaseMeasurements> {
    let (fixed_nodes, top) = block_faces(mesh);
    let mut model = softcap_fem::NeoHookeanModel::homogeneous(mesh, truth)?;
    let mut out = Vec::new();
    for &(c, force) in examples {
        let patch = probe_patch(mesh, &top, c, probe_radius_m)?;
        let mut bc = DirichletBc::new();
        for &i in &fixed_nodes {
            bc.fix_node(i, mesh.vertices[i]);
        }
        if sticky {
            for &i in &patch {
                bc.fix_dof(3 * i, mesh.vertices[i].x);
                bc.fix_dof(3 * i + 1, mesh.vertices[i].y);
            }
        }
        let mut solver = StaticSolver::new(&model, &bc.dofs())?;
        let mut x = mesh.vertices.clone();
        let steps = 4;
        for s in 1..=steps {
            let mut f_ext = vec![Vector3::zeros(); x.len()];
            for &i in &patch {
                f_ext[i].z = -force * s as f64 / steps as f64 / patch.len() as f64;
            }
            let rep = solver.solve(
                &mut model,
                &mut x,
                &f_ext,
                None,
                &EquilibriumSettings::newton(),
            );
            if !rep.converged() {
                return Err(DesignError::NotConverged {
                    what: format!("ground-truth example at {c:?}, {force} N"),
                    status: format!("{:?}", rep.status),
                });
            }
        }
        out.push(ProbeExample {
            patch_nodes: patch,
            force_n: [0.0, 0.0, -force],
            marker_nodes: top.clone(),
            displacements_m: top
                .iter()
                .map(|&i| {
                    let u = x[i] - mesh.vertices[i];
                    [u.x, u.y, u.z]
                })
                .collect(),
        });
    }
    Ok(BaseMeasurements {
        mesh: mesh.clone(),
        fixed_nodes,
        examples: out,
    })
}
