//! Per-colour wrinkle-paint pixel classification (thesis §4.3.1): a binary support vector
//! machine with RBF kernel, trained on a mask of the first frame and applied to the others.
//!
//! The SVM is smartcore's [`SVC`] (LASVM-style solver, soft margin C, kernel
//! K(x, y) = exp(−γ‖x − y‖²)). Features are the pixel's chromaticity (r, g, b)/(r + g + b) and
//! its brightness relative to the frame's 99th percentile, so the shaded valley of a painted
//! wrinkle and its lit bulges fall on the same side of the boundary.

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use smartcore::linalg::basic::matrix::DenseMatrix;
use smartcore::svm::Kernels;
use smartcore::svm::svc::{SVC, SVCParameters};

use crate::error::{FaceError, Result};
use crate::image::RgbImage;

/// Settings of [`classify_frames`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SvmSettings {
    /// Soft-margin penalty C.
    pub c: f64,
    /// RBF kernel γ in K(x, y) = exp(−γ‖x − y‖²) on the features.
    pub gamma: f64,
    /// Training pixels drawn per class (seeded), to bound the O(n²) kernel work.
    pub samples_per_class: usize,
    /// Solver passes over the training data.
    pub epochs: usize,
    /// Seed for the training subsample.
    pub seed: u64,
}

impl Default for SvmSettings {
    fn default() -> Self {
        Self {
            c: 10.0,
            gamma: 30.0,
            samples_per_class: 250,
            epochs: 3,
            seed: 11,
        }
    }
}

fn features(image: &RgbImage) -> Vec<Vec<f64>> {
    let mut sums: Vec<f64> = image.data.iter().map(|p| p[0] + p[1] + p[2]).collect();
    let mut sorted = sums.clone();
    sorted.sort_by(f64::total_cmp);
    let bright = sorted[((sorted.len() as f64 - 1.0) * 0.99) as usize].max(1e-12);
    image
        .data
        .iter()
        .zip(sums.iter_mut())
        .map(|(p, s)| {
            let t = s.max(1e-12);
            vec![p[0] / t, p[1] / t, p[2] / t, 0.3 * *s / bright]
        })
        .collect()
}

/// Train the RBF-SVM on (`train`, `train_mask`) and classify every pixel of every frame in
/// `frames`. Returns one wrinkle mask per frame.
pub fn classify_frames(
    train: &RgbImage,
    train_mask: &[bool],
    frames: &[&RgbImage],
    settings: &SvmSettings,
) -> Result<Vec<Vec<bool>>> {
    if train_mask.len() != train.data.len() {
        return Err(FaceError::InvalidInput {
            what: "train_mask",
            reason: format!(
                "{} entries for {} pixels",
                train_mask.len(),
                train.data.len()
            ),
        });
    }
    let feats = features(train);
    let mut pos: Vec<usize> = (0..feats.len()).filter(|&i| train_mask[i]).collect();
    let mut neg: Vec<usize> = (0..feats.len()).filter(|&i| !train_mask[i]).collect();
    if pos.is_empty() || neg.is_empty() {
        return Err(FaceError::InvalidInput {
            what: "train_mask",
            reason: "needs both wrinkle and skin pixels".into(),
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    pos.shuffle(&mut rng);
    neg.shuffle(&mut rng);
    pos.truncate(settings.samples_per_class);
    neg.truncate(settings.samples_per_class);
    let mut rows = Vec::new();
    let mut labels = Vec::new();
    for (&i, &j) in pos.iter().zip(neg.iter()) {
        rows.push(feats[i].clone());
        labels.push(1i32);
        rows.push(feats[j].clone());
        labels.push(-1i32);
    }
    let x = DenseMatrix::from_2d_vec(&rows).map_err(|e| FaceError::Classifier(e.to_string()))?;
    let params = SVCParameters::default()
        .with_c(settings.c)
        .with_epoch(settings.epochs)
        .with_kernel(Kernels::rbf().with_gamma(settings.gamma))
        .with_seed(Some(settings.seed));
    let svc = SVC::fit(&x, &labels, &params).map_err(|e| FaceError::Classifier(e.to_string()))?;
    let mut out = Vec::with_capacity(frames.len());
    for frame in frames {
        let f = features(frame);
        let m = DenseMatrix::from_2d_vec(&f).map_err(|e| FaceError::Classifier(e.to_string()))?;
        let y = svc
            .predict(&m)
            .map_err(|e| FaceError::Classifier(e.to_string()))?;
        out.push(y.iter().map(|&v| v > 0.0).collect());
    }
    Ok(out)
}
