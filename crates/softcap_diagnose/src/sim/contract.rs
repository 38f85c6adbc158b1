//! The contract between the diagnosis and a model simulator: loads, outputs, the extended models
//! and [`ProbeSimulator`].

use crate::{DiagnoseError, Result};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_mesh::RefineBall;
use softcap_probing::ProbeExample;

/// Field over frames × markers (marker positions or displacements per frame), m.
pub type Field = Vec<Vec<Vector3<f64>>>;

/// A probe load: force `force_n` (by the probe on the object) spread over the contact patch around
/// `tip_m`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeLoad {
    /// Tip position, m.
    pub tip_m: Vector3<f64>,
    /// Unit probe axis (handle → tip), world frame.
    pub axis: Vector3<f64>,
    /// Force on the object, N.
    pub force_n: Vector3<f64>,
}

/// Everything applied in one quasi-static simulation.
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
pub struct SimLoad {
    /// Probe load, if any.
    pub probe: Option<ProbeLoad>,
    /// Body-force density ρ g, N/m³ (zero: no body force).
    pub body_force_n_m3: Vector3<f64>,
}

/// Result of one simulation.
#[derive(Clone, Debug, PartialEq)]
pub struct SimOutput {
    /// Marker positions, m.
    pub markers_m: Vec<Vector3<f64>>,
    /// ∂x_marker/∂f_k (m/N) for k = x, y, z when requested and a probe load was given.
    pub force_response: Option<[Vec<Vector3<f64>>; 3]>,
    /// Where the probe load acts, when a probe load was given and the simulator knows it
    /// (`None` otherwise): the load-weighted mean of the loaded nodes.
    pub load_point: Option<LoadPoint>,
}

/// The point of the body a probe load acts on: x_P = Σ w_i x_i / Σ w_i over the loaded nodes i
/// with the load's weights w_i (the share of the force each node carries), the displacement
/// work-conjugate to the resultant (f · δx_P is the load's virtual work for a uniform δf), so the
/// pair (f, x_P) is the model's force–indentation relation at the tip.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoadPoint {
    /// x_P, m.
    pub position_m: Vector3<f64>,
    /// ∂x_P/∂f_k (m/N) for k = x, y, z, when the force response was requested.
    pub response_m_per_n: Option<[Vector3<f64>; 3]>,
}

/// A homogeneous material refit ([`ProbeSimulator::refit_homogeneous`]).
pub struct MaterialRefit {
    /// The same setup with the refitted material.
    pub sim: Box<dyn ProbeSimulator>,
    /// Refitted Young's modulus, Pa.
    pub young_pa: f64,
    /// Refitted Poisson ratio.
    pub poisson: f64,
    /// Levenberg–Marquardt iterations of the fit.
    pub iterations: usize,
    /// Equilibrium solves of the fit that stopped at the iteration cap (trial points the fit
    /// rejected; `softcap_probing::HomogeneousFit::stalled_solves`).
    pub stalled_solves: usize,
}

/// The outcome of [`ProbeSimulator::refit_homogeneous`]: the refit, or why there is none (a
/// reported status, never a silent drop).
pub enum MaterialRefitOutcome {
    /// The refitted material.
    Refitted(MaterialRefit),
    /// No refit: the simulator cannot refit its material under the extension, or the fit failed
    /// (e.g. an example's equilibrium stopped at the iteration cap at the fitted material).
    Declined(String),
}

/// A natural mode of the model seen at the markers ([`ProbeSimulator::natural_modes`]).
#[derive(Clone, Debug, PartialEq)]
pub struct MarkerMode {
    /// Natural frequency ω / 2π, Hz.
    pub frequency_hz: f64,
    /// The mode shape φ at every marker (M-orthonormal over the mesh's nodes), m/√kg.
    pub markers: Vec<Vector3<f64>>,
}

/// One re-simulation of a grid: the extension and the frames of its sequence
/// ([`ProbeSimulator::simulate_sequences`]).
pub type SequenceJob = (Extension, Vec<SequenceFrame>);

/// A model that can simulate a probing frame. `Send + Sync`: the diagnosis runs independent
/// re-simulations of one simulator on several threads ([`Self::simulate_sequences`]).
pub trait ProbeSimulator: Send + Sync {
    /// Number of markers.
    fn num_markers(&self) -> usize;
    /// Marker positions under `load`; with `want_response`, also the tangent response to the probe
    /// force. Non-convergence is an error carrying the solver status.
    fn simulate(&mut self, load: &SimLoad, want_response: bool) -> Result<SimOutput>;

    /// A simulator of the same setup whose material is a homogeneous (λ, α) refit to `examples`
    /// (bickel2009 §6 average fit) with the model extended by `ext` in every example's
    /// equilibrium: [`Extension::Elastic`] (the attached nodes fixed,
    /// `softcap_probing::fit_homogeneous`) — used after a temporal extension corrected the
    /// forces the material was fitted with — or [`Extension::SupportSprings`] (the attached face
    /// on the tangential springs, `softcap_probing::fit_homogeneous_on_support`): the tissue fit
    /// gave the support's slip to the material. The fit starts from `start` = (E Pa, ν) — e.g. the
    /// full data's refit when a training set is refitted — or, `None`, from this simulator's
    /// material. [`MaterialRefitOutcome::Declined`] (default) with the reason when this simulator
    /// cannot refit its material under `ext` or the fit fails.
    fn refit_homogeneous(
        &self,
        examples: &[ProbeExample],
        ext: &Extension,
        start: Option<(f64, f64)>,
    ) -> Result<MaterialRefitOutcome> {
        let _ = (examples, ext, start);
        Ok(MaterialRefitOutcome::Declined(
            "this simulator cannot refit its material".into(),
        ))
    }

    /// The same object on a refined mesh, each child tet with its parent's material, the markers
    /// re-embedded, the same support, tip and settings: refined uniformly (every tet split in
    /// eight, `softcap_mesh::refine_tets`) or only inside the balls `touched` (the recording's
    /// tip positions with the contact radius; `softcap_mesh::refine_near`), as the simulator's
    /// settings say. For extended models whose coarse discretisation cannot form the recorded
    /// deformation (a plastic dent between a few nodes, a stuck contact patch); `None` (default)
    /// when this simulator has no mesh to refine.
    fn refined(&self, touched: &[RefineBall]) -> Result<Option<Box<dyn ProbeSimulator>>> {
        let _ = touched;
        Ok(None)
    }

    /// The same object whose rigid-tip replays of the plasticity extensions
    /// ([`Extension::Plastic`], [`Extension::PlasticPoisson`]) run on the 10-node tets of its
    /// mesh (the truth's element order; linear tets lock under the isochoric plastic flow, refined
    /// or not); everything else as this one. The replay mesh of `Replays::run_coarse_first` with
    /// `plasticity_quadratic_replays`. `None` (default) when this simulator has no mesh.
    fn quadratic(&self) -> Result<Option<Box<dyn ProbeSimulator>>> {
        Ok(None)
    }

    /// The same object on its mesh refined everywhere by conforming longest-edge bisection
    /// (`softcap_mesh::refine_near`) until it has at least `tet_factor` × its tets: the target
    /// longest edge is lowered from the mesh's longest edge in steps of 5 % until the count is
    /// reached (on a mesh of cubes split in six tets, 2 halves every cube's body diagonal: each
    /// tet bisected once). Each child tet with its parent's material, the markers re-embedded, the
    /// same support, tip and settings, as [`ProbeSimulator::refined`]. A cheaper ranking mesh than
    /// the 1 → 8 one (`Replays::run_coarse_first`); `None` (default) when this simulator has no
    /// mesh to refine, and for `tet_factor` ≤ 1.
    fn bisected(&self, tet_factor: usize) -> Result<Option<Box<dyn ProbeSimulator>>> {
        let _ = tet_factor;
        Ok(None)
    }

    /// The default model's Young's modulus E, Pa: the volume-weighted mean over its elements
    /// (the homogeneous fit's E). Under position control a J2 model's displacements depend on
    /// σ_y/E, H/E and ν only (the stresses scale with E at fixed strains), so the rigid-tip
    /// replays of `crate::hypotheses::plasticity` set σ_y and H in units of it. `None` (default)
    /// when this simulator has no elements to read it from.
    fn young_pa(&self) -> Option<f64> {
        None
    }

    /// True when the fit mesh already resolves a tip of radius `tip_radius_m` at the tip
    /// positions `tips_m`: its boundary nodes there are spaced ≤ 0.8 tip radii, the rule of
    /// [`super::friction_refinement`] (which then adds no refinement level). A model
    /// re-simulated on such a mesh gains nothing from [`Self::refined`] but its cost (8× the
    /// tets). `false` (default) when this simulator has no mesh to measure.
    fn resolves_footprint(&self, tip_radius_m: f64, tips_m: &[Vector3<f64>]) -> bool {
        let _ = (tip_radius_m, tips_m);
        false
    }

    /// The lowest `count` natural modes of the model about its rest shape, K φ = ω² M φ with the
    /// lumped mass matrix M of density `density_kg_m3` and the attached nodes fixed (wang2015
    /// §6.3; `softcap_fem::lanczos_modes`), ascending: each mode's frequency and its shape at
    /// the markers. `Ok(None)` (default) when this simulator has no mesh to analyse.
    fn natural_modes(&self, density_kg_m3: f64, count: usize) -> Result<Option<Vec<MarkerMode>>> {
        let _ = (density_kg_m3, count);
        Ok(None)
    }

    /// Marker positions of every frame (time order) under the model extended by `ext`, with the
    /// probe replayed as a RIGID tip at each frame's measured pose (position control, bickel2009
    /// §3.4 rigid-probe contact) instead of the measured force over the patch (§4.1). Only
    /// `load.probe`'s `tip_m` / `axis` and `load.body_force_n_m3` of each frame are used.
    /// `Ok(None)` (default) when the simulator knows no tip geometry or cannot replay `ext`.
    fn simulate_sequence_rigid_tip(
        &mut self,
        ext: &Extension,
        frames: &[SequenceFrame],
    ) -> Result<Option<Vec<Vec<Vector3<f64>>>>> {
        let _ = (ext, frames);
        Ok(None)
    }

    /// [`Self::simulate_sequence_rigid_tip`] of every extension of `exts` over the same `frames`,
    /// results in the order of `exts`. The default runs them one after another;
    /// `FemProbeSimulator` runs them in parallel (each replay is independent: its own model
    /// state, solver and contact history), so the results are the serial ones bit for bit.
    fn simulate_sequences_rigid_tip(
        &mut self,
        exts: &[Extension],
        frames: &[SequenceFrame],
    ) -> Vec<Result<Option<Field>>> {
        exts.iter()
            .map(|e| self.simulate_sequence_rigid_tip(e, frames))
            .collect()
    }

    /// [`Self::simulate_sequence`] of every job, results in job order. The default runs them one
    /// after another; `FemProbeSimulator` runs them in parallel (each sequence is independent:
    /// its own model state and solver, started at rest), so the results are the serial ones bit
    /// for bit.
    fn simulate_sequences(&mut self, jobs: &[SequenceJob]) -> Vec<Result<Field>> {
        jobs.iter()
            .map(|(e, f)| self.simulate_sequence(e, f))
            .collect()
    }

    /// Marker positions of every frame (time order) under the model extended by `ext`
    /// (the table above). The default handles [`Extension::Elastic`] frame by frame; other
    /// extensions need a simulator that implements them (an error otherwise).
    fn simulate_sequence(
        &mut self,
        ext: &Extension,
        frames: &[SequenceFrame],
    ) -> Result<Vec<Vec<Vector3<f64>>>> {
        match ext {
            Extension::Elastic => frames
                .iter()
                .map(|f| self.simulate(&f.load, false).map(|o| o.markers_m))
                .collect(),
            other => Err(DiagnoseError::BadRecording {
                what: format!("this simulator cannot simulate the extension {other:?}"),
            }),
        }
    }
}

/// One extended model (see the module table).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Extension {
    /// The default model (loads may carry the extension).
    Elastic,
    /// One Prony branch.
    Viscoelastic {
        /// Relaxing fraction g of the long-term stiffness.
        g: f64,
        /// Relaxation time, s.
        tau_s: f64,
    },
    /// J2 plasticity with linear isotropic hardening.
    Plastic {
        /// Uniaxial yield stress, Pa.
        yield_stress_pa: f64,
        /// Hardening modulus, Pa.
        hardening_pa: f64,
    },
    /// J2 plasticity as [`Extension::Plastic`] on the default model's Young's moduli with the
    /// Poisson ratio set to `poisson`: the tissue fit's ν is biased by the unmodelled plastic
    /// flow (suite plasticity session: fitted 0.48, truth 0.45), and under the rigid-tip replay
    /// (position control) the displacements depend on σ_y/E, H/E and ν only.
    PlasticPoisson {
        /// Uniaxial yield stress, Pa.
        yield_stress_pa: f64,
        /// Hardening modulus, Pa.
        hardening_pa: f64,
        /// Poisson ratio ν of every element (Young's modulus kept).
        poisson: f64,
    },
    /// Tangential springs under the attached face.
    SupportSprings {
        /// Total tangential stiffness, N/m.
        stiffness_n_per_m: f64,
    },
    /// Transversely isotropic stiffening along a fibre.
    Anisotropic {
        /// Fibre direction (world, unit).
        fibre: Vector3<f64>,
        /// Fibre / transverse Young's modulus.
        ratio: f64,
    },
    /// Coulomb friction between the rigid tip and the surface (bickel2009 §7: the shaft-axis
    /// sensor does not measure it; thesis §6.4 models the indenter as a high-friction surface):
    /// `softcap_fem::FrictionalContact` with normal forces lagged per solve, the same law and
    /// iterations the synthetic ground truth uses. Only in the rigid-tip replay (a traction needs
    /// the tip's pose and the patch's stick history; the force boundary condition has neither).
    ProbeFriction {
        /// Coulomb coefficient μ.
        mu: f64,
    },
    /// Inertia and Rayleigh damping: the default model's implicit dynamics
    /// M ü + D u̇ + f_int(u) = f_ext, D = α M + β K (wang2015 eq. 3), lumped M of a uniform
    /// density, driven by the measured force or (rigid-tip replay) by the tip at its measured
    /// poses.
    Dynamic {
        /// Density ρ of the lumped mass, kg/m³.
        density_kg_m3: f64,
        /// Rayleigh mass-proportional coefficient α, 1/s.
        alpha_per_s: f64,
        /// Rayleigh stiffness-proportional coefficient β, s.
        beta_s: f64,
        /// Factor on every element's Lamé ratio λ_L/μ of the default model, its Young's modulus
        /// kept ([`crate::sim::with_lame_ratio`]; 1: the default model's material). Under
        /// position control E and ρ act only through E/ρ, so ν is the material's one free
        /// parameter left to the dynamic model (ν shared by the body, wang2015 §6.2).
        lame_ratio_factor: f64,
    },
    /// Two HGO fibre families (Holzapfel, Gasser & Ogden 2000 §4.2, linearized:
    /// `softcap_fem::AnisotropicModel::with_fibre_families`) on the default model's isotropic
    /// (E, ν): each family adds 4 k1 = `ratio` · E along its direction. The two directions are
    /// symmetric about an axis (angles ±θ); θ = 0 is one family of twice the modulus.
    FibreFamilies {
        /// The two fibre directions (world, unit).
        fibres: [Vector3<f64>; 2],
        /// Each family's modulus 4 k1 over the element's Young's modulus E.
        ratio: f64,
        /// The matrix's Poisson ratio (Young's modulus kept); `None`: the default model's. The
        /// isotropic fit's ν is biased by the unmodelled fibres (third-party anisotropy: fitted
        /// 0.35, matrix truth 0.475).
        poisson: Option<f64>,
    },
    /// Transversely isotropic with the Poisson ratios as parameters.
    TransverselyIsotropic {
        /// Fibre direction (world, unit).
        fibre: Vector3<f64>,
        /// Fibre / transverse Young's modulus E_a / E_t.
        ratio: f64,
        /// Poisson ratio in the plane across the fibre ν_t.
        nu_transverse: f64,
        /// Poisson ratio ν_a (transverse contraction under fibre stress).
        nu_fibre: f64,
    },
}

/// One frame of a sequence: its time and load.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SequenceFrame {
    /// Time, s.
    pub time_s: f64,
    /// Probe and body load.
    pub load: SimLoad,
}
