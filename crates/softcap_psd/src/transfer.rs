//! Transfer of fine-scale details to another face (thesis §5.4.4).

use crate::detail::{DetailModel, Metric};
use crate::error::{PsdError, Result};
use crate::rig::FaceRig;

/// Dense correspondence: each target vertex as barycentric weights of up to three source
/// vertices (its enclosing triangle on the deformed source, thesis §5.4.4).
pub type Correspondence = Vec<[(u32, f32); 3]>;

/// Identity correspondence for meshes in vertex correspondence (ICT-FaceKit identities).
pub fn identity_correspondence(n: usize) -> Correspondence {
    (0..n as u32)
        .map(|v| [(v, 1.0), (v, 0.0), (v, 0.0)])
        .collect()
}

/// Transfer `model` to `target` (a rig built on the target rest face with the feature graph
/// mapped from the source, see [`FaceRig::with_handles`]): the per-vertex RBF weights `w_{v,j}`
/// are interpolated with the barycentric weights of the correspondence, the basis-pose feature
/// vectors `f_j` are kept (relative stretch is scale-free, so they are meaningful on the target's
/// own rest lengths), and the WPSD edge weights are those of the target rig (eq. 5.4 on the
/// target rest shape). Details stay in local frames, so evaluating eq. 5.5 on the target
/// animation gives target-oriented displacements.
pub fn transfer_details(
    model: &DetailModel,
    target: &FaceRig,
    correspondence: &Correspondence,
) -> Result<DetailModel> {
    let n = target.num_vertices();
    if correspondence.len() != n {
        return Err(PsdError::SizeMismatch {
            what: "correspondence entries",
            expected: n,
            got: correspondence.len(),
        });
    }
    if target.graph.len() != model.num_features {
        return Err(PsdError::SizeMismatch {
            what: "feature edges",
            expected: model.num_features,
            got: target.graph.len(),
        });
    }
    let p3 = 3 * model.num_poses();
    let ns = model.num_vertices();
    let mut weights = vec![0.0f32; n * p3];
    for (v, bary) in correspondence.iter().enumerate() {
        let out = &mut weights[v * p3..(v + 1) * p3];
        for &(s, b) in bary {
            if b == 0.0 {
                continue;
            }
            let s = s as usize;
            if s >= ns {
                return Err(PsdError::SizeMismatch {
                    what: "correspondence source vertex",
                    expected: ns,
                    got: s,
                });
            }
            for (o, w) in out.iter_mut().zip(&model.weights[s * p3..(s + 1) * p3]) {
                *o += b * w;
            }
        }
    }
    let metric = match model.metric {
        Metric::Global => Metric::Global,
        Metric::Weighted(_) => Metric::Weighted(target.edge_weights.clone()),
    };
    Ok(DetailModel {
        num_features: model.num_features,
        centers: model.centers.clone(),
        weights,
        metric,
    })
}
