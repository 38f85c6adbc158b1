//! The ICT-FaceKit evaluation of thesis §5.5.1 / Fig. 5.5: greedy basis growth for PSD and WPSD
//! (interpolation and least squares) against global and local blend shapes, measured on
//! held-out poses.

use crate::blend::{global_blend, local_blend};
use crate::detail::{FitMode, Method, greedy_selection};
use crate::error::{PsdError, Result};
use crate::poses::{PoseDeltas, PoseRecipe, random_combinations};
use crate::rig::{Animator, FaceRig, RigSettings};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_mesh::TriMesh;
use std::path::Path;

/// The ICT-FaceKit fixture: neutral mesh, expression and identity deltas (cm).
#[derive(Clone, Debug)]
pub struct IctData {
    /// Neutral face (triangulated quads).
    pub mesh: TriMesh,
    /// 57 expressions as deltas from neutral.
    pub expressions: PoseDeltas,
    /// 5 identities (neutral shapes) as deltas from the generic neutral.
    pub identities: PoseDeltas,
}

impl IctData {
    /// Load `neutral.obj`, `expressions.scpose`, `identities.scpose` from `dir`.
    pub fn load(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref();
        let mesh = softcap_mesh::read_obj_tri_mesh(dir.join("neutral.obj"))?;
        let expressions = PoseDeltas::read(dir.join("expressions.scpose"))?;
        let identities = PoseDeltas::read(dir.join("identities.scpose"))?;
        for p in [&expressions, &identities] {
            if p.num_vertices != mesh.vertices.len() {
                return Err(PsdError::SizeMismatch {
                    what: "pose-file vertices vs neutral.obj",
                    expected: mesh.vertices.len(),
                    got: p.num_vertices,
                });
            }
        }
        Ok(Self {
            mesh,
            expressions,
            identities,
        })
    }

    /// Positions of a recipe on the generic neutral.
    pub fn pose(&self, recipe: &PoseRecipe) -> Vec<Vector3<f64>> {
        self.expressions
            .combine(&self.mesh.vertices, &recipe.weights)
    }
}

/// Settings of the Fig. 5.5 evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvaluationSettings {
    /// Rig (handles, feature edges, shell, edge weights).
    pub rig: RigSettings,
    /// Random expression mixtures added to the 57 expressions for training.
    pub training_mixtures: usize,
    /// Held-out random mixtures (different seed).
    pub heldout_mixtures: usize,
    /// Maximum expressions per mixture.
    pub max_terms: usize,
    /// Largest basis size P (including the rest pose).
    pub max_poses: usize,
    /// Projected-gradient iterations of the blend-shape weight fits.
    pub blend_iterations: usize,
    /// Seed of the mixtures (training uses `seed`, held-out `seed + 1`).
    pub seed: u64,
    /// Expressions of the emulated performance (thesis §5.5.1: the actor performs a handful of
    /// expressions); empty = all 57.
    pub expressions: Vec<String>,
}

/// The default performance: left/right wrinkle-forming expressions of brow, eyes, nose, cheeks
/// and mouth, plus jaw and lip shapes.
pub const PERFORMANCE_EXPRESSIONS: [&str; 16] = [
    "browInnerUp_L",
    "browInnerUp_R",
    "browOuterUp_L",
    "browOuterUp_R",
    "browDown_L",
    "browDown_R",
    "noseSneer_L",
    "noseSneer_R",
    "eyeSquint_L",
    "eyeSquint_R",
    "mouthSmile_L",
    "mouthSmile_R",
    "cheekPuff_L",
    "cheekPuff_R",
    "jawOpen",
    "mouthPucker",
];

impl Default for EvaluationSettings {
    fn default() -> Self {
        Self {
            rig: RigSettings::default(),
            training_mixtures: 60,
            heldout_mixtures: 40,
            max_terms: 3,
            max_poses: 24,
            blend_iterations: 200,
            seed: 2008,
            expressions: PERFORMANCE_EXPRESSIONS
                .iter()
                .map(|s| s.to_string())
                .collect(),
        }
    }
}

/// Error of one method against basis size.
#[derive(Clone, Debug, Serialize)]
pub struct Curve {
    /// Method label (as in Fig. 5.5).
    pub method: String,
    /// Basis sizes P.
    pub basis_sizes: Vec<usize>,
    /// RMS vertex error on held-out poses (mm).
    pub heldout_rms_mm: Vec<f64>,
    /// Greedy basis (training-example names) at the largest P.
    pub basis_names: Vec<String>,
}

/// Result of [`evaluate`].
#[derive(Clone, Debug, Serialize)]
pub struct EvaluationReport {
    /// Vertices, handles, feature edges, training and held-out pose counts.
    pub vertices: usize,
    /// H
    pub handles: usize,
    /// F
    pub feature_edges: usize,
    /// T
    pub training_poses: usize,
    /// held-out poses
    pub heldout_poses: usize,
    /// RMS error of the large-scale shell alone (no details) on held-out poses (mm).
    pub large_scale_only_rms_mm: f64,
    /// One curve per method.
    pub curves: Vec<Curve>,
}

impl EvaluationReport {
    /// The curve of `method`.
    pub fn curve(&self, method: &str) -> Option<&Curve> {
        self.curves.iter().find(|c| c.method == method)
    }
}

/// Training and held-out pose recipes: rest, the 57 expressions and seeded mixtures.
pub fn pose_sets(data: &IctData, s: &EvaluationSettings) -> (Vec<PoseRecipe>, Vec<PoseRecipe>) {
    let all: Vec<usize> = (0..data.expressions.names.len())
        .filter(|&k| s.expressions.is_empty() || s.expressions.contains(&data.expressions.names[k]))
        .collect();
    let mut training = vec![PoseRecipe {
        name: "rest".into(),
        weights: vec![],
    }];
    training.extend(all.iter().map(|&k| PoseRecipe {
        name: data.expressions.names[k].clone(),
        weights: vec![(k, 1.0)],
    }));
    training.extend(random_combinations(
        &data.expressions,
        &all,
        s.training_mixtures,
        s.max_terms,
        s.seed,
    ));
    let heldout = random_combinations(
        &data.expressions,
        &all,
        s.heldout_mixtures,
        s.max_terms,
        s.seed + 1,
    );
    (training, heldout)
}

fn rms_mm(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    // data are in cm
    10.0 * (a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).norm_squared())
        .sum::<f64>()
        / a.len() as f64)
        .sqrt()
}

fn to_vec3(x: &[[f32; 3]]) -> Vec<Vector3<f64>> {
    x.iter()
        .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect()
}

/// Run the Fig. 5.5 comparison on `rig` (built on `data.mesh`).
pub fn evaluate(data: &IctData, rig: &FaceRig, s: &EvaluationSettings) -> Result<EvaluationReport> {
    let (training, heldout) = pose_sets(data, s);
    let train_pos: Vec<Vec<Vector3<f64>>> = training.iter().map(|r| data.pose(r)).collect();
    let held_pos: Vec<Vec<Vector3<f64>>> = heldout.iter().map(|r| data.pose(r)).collect();
    let examples = rig.examples(&train_pos)?;
    let held_handles: Vec<Vec<Vector3<f64>>> =
        held_pos.iter().map(|p| rig.handle_positions(p)).collect();

    let large_only = held_pos
        .iter()
        .zip(&held_handles)
        .map(|(truth, h)| rms_mm(&to_vec3(&rig.large_scale(h).0), truth).powi(2))
        .sum::<f64>()
        / held_pos.len() as f64;

    let mut curves = Vec::new();
    let mut wpsd_basis_order: Vec<usize> = Vec::new();
    let methods = [
        ("PSD", Method::Psd(FitMode::Interpolate)),
        ("PSD LSq", Method::Psd(FitMode::LeastSquares)),
        (
            "WPSD",
            Method::Wpsd(FitMode::Interpolate, rig.edge_weights.clone()),
        ),
        (
            "WPSD LSq",
            Method::Wpsd(FitMode::LeastSquares, rig.edge_weights.clone()),
        ),
    ];
    for (label, method) in &methods {
        let mut sizes = Vec::new();
        let mut errs = Vec::new();
        let steps = greedy_selection(&examples, method, 0, s.max_poses, |step, model| {
            let mut anim = Animator::new(rig, model)?;
            let mut acc = 0.0;
            for (h, truth) in held_handles.iter().zip(&held_pos) {
                anim.frame(h)?;
                acc += rms_mm(&to_vec3(&anim.positions), truth).powi(2);
            }
            sizes.push(step.basis.len());
            errs.push((acc / held_pos.len() as f64).sqrt());
            Ok(())
        })?;
        let last = steps.last().map(|s| s.basis.clone()).unwrap_or_default();
        if *label == "WPSD" {
            wpsd_basis_order = last.clone();
        }
        curves.push(Curve {
            method: label.to_string(),
            basis_sizes: sizes,
            heldout_rms_mm: errs,
            basis_names: last.iter().map(|&t| training[t].name.clone()).collect(),
        });
    }

    // Blend-shape baselines on the WPSD greedy basis order (same examples for all methods, as
    // in Fig. 5.6).
    let rel = |p: &[Vector3<f64>]| -> Vec<Vector3<f64>> {
        rig.handles.iter().map(|&v| p[v] - rig.rest[v]).collect()
    };
    let train_handles: Vec<Vec<Vector3<f64>>> = train_pos.iter().map(|p| rel(p)).collect();
    let held_rel: Vec<Vec<Vector3<f64>>> = held_pos.iter().map(|p| rel(p)).collect();
    for label in ["global blend shapes", "local blend shapes"] {
        let mut sizes = Vec::new();
        let mut errs = Vec::new();
        for p in 1..=wpsd_basis_order.len() {
            let basis = &wpsd_basis_order[..p];
            let bp: Vec<&[Vector3<f64>]> = basis.iter().map(|&t| train_pos[t].as_slice()).collect();
            let bh: Vec<&[Vector3<f64>]> =
                basis.iter().map(|&t| train_handles[t].as_slice()).collect();
            let mut acc = 0.0;
            for (target, truth) in held_rel.iter().zip(&held_pos) {
                let x = if label.starts_with("global") {
                    global_blend(&bp, &bh, target, s.blend_iterations)
                } else {
                    local_blend(
                        &bp,
                        &bh,
                        target,
                        &rig.handles,
                        &rig.graph.edges,
                        &rig.edge_weights,
                        s.blend_iterations,
                    )
                };
                acc += rms_mm(&x, truth).powi(2);
            }
            sizes.push(p);
            errs.push((acc / held_pos.len() as f64).sqrt());
        }
        curves.push(Curve {
            method: label.to_string(),
            basis_sizes: sizes,
            heldout_rms_mm: errs,
            basis_names: wpsd_basis_order
                .iter()
                .map(|&t| training[t].name.clone())
                .collect(),
        });
    }

    Ok(EvaluationReport {
        vertices: rig.num_vertices(),
        handles: rig.handles.len(),
        feature_edges: rig.graph.len(),
        training_poses: training.len(),
        heldout_poses: heldout.len(),
        large_scale_only_rms_mm: large_only.sqrt(),
        curves,
    })
}
