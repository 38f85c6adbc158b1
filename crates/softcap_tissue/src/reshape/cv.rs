//! Choosing the smoothness weight α̂ without ground truth: k-fold cross-validation on the ICP
//! markers (Stone 1974; Hastie, Tibshirani and Friedman, *The Elements of Statistical Learning*
//! §7.10).
//!
//! saito-barbic fix α (eq. 3) by hand. α̂ trades how closely the reshaped surface follows the
//! markers against how smooth the plastic strain is; the right trade depends on the object (a
//! bulky organ vs a thin layer) and on how dense and noisy the markers are. With
//! `smoothness = "cv"` the ICP markers are split into k folds (marker i in fold i mod k, or
//! k contiguous blocks with `split = "spatial-blocks"`, [`FoldSplit`]); for
//! every α̂ of a log grid each fold is held out in turn, the reshape is run with the other
//! markers, and the held-out markers' distances to the reshaped ICP surface are collected. The
//! score of α̂ is the root mean square of those distances over all markers (each is held out once);
//! the α̂ with the lowest score is chosen (or, with `rule = "one-standard-error"`, the strongest
//! smoothness within one standard error of it, [`CvRule`]) and the reshape is run again with
//! every marker.
//!
//! Cost: the stages before the ICP stage (constant guess, attachments, landmarks) do not see the
//! ICP markers, so they run once per α̂ and every fold starts its ICP stage from their result;
//! the refit reuses them too. A cross-validated reshape costs about (grid × (folds + 1)) ICP
//! stages. Held-out markers score the surface, not where the material lies on it; with
//! `hold_out = "correspondence"` ([`HoldOut`]) the attachments and landmarks are held out instead,
//! scored by the distance of their template point from its target, and every fold runs the whole
//! reshape (grid × folds + 1 reshapes).

use nalgebra::Vector3;
use serde::de::{self, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::problem::IcpMarker;
use super::solve::{ProgressFn, ReshapeOutcome, Solver, State};
use crate::error::{Result, TissueError};

/// α̂ of the smoothness term (TOML: a number, or `"cv"`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Smoothness {
    /// This α̂.
    Fixed(f64),
    /// Chosen by k-fold cross-validation on the ICP markers ([`CrossValidationSettings`]).
    CrossValidated,
}

impl Smoothness {
    /// The fixed α̂, if any.
    pub fn fixed(self) -> Option<f64> {
        match self {
            Self::Fixed(a) => Some(a),
            Self::CrossValidated => None,
        }
    }
}

impl Serialize for Smoothness {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            Self::Fixed(a) => s.serialize_f64(*a),
            Self::CrossValidated => s.serialize_str("cv"),
        }
    }
}

impl<'de> Deserialize<'de> for Smoothness {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct SmoothnessVisitor;
        impl Visitor<'_> for SmoothnessVisitor {
            type Value = Smoothness;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a positive number (α̂) or \"cv\" (cross-validation)")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> std::result::Result<Smoothness, E> {
                Ok(Smoothness::Fixed(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> std::result::Result<Smoothness, E> {
                Ok(Smoothness::Fixed(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> std::result::Result<Smoothness, E> {
                Ok(Smoothness::Fixed(v as f64))
            }
            fn visit_str<E: de::Error>(self, v: &str) -> std::result::Result<Smoothness, E> {
                match v {
                    "cv" | "cross-validation" => Ok(Smoothness::CrossValidated),
                    _ => Err(E::invalid_value(de::Unexpected::Str(v), &self)),
                }
            }
        }
        d.deserialize_any(SmoothnessVisitor)
    }
}

/// Settings of `smoothness = "cv"` (TOML table `[cross_validation]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CrossValidationSettings {
    /// Number of folds k (2 ≤ k ≤ the number of held-out points).
    pub folds: usize,
    /// The α̂ tried (positive; a log grid).
    pub grid: Vec<f64>,
    /// Which target points are held out.
    pub hold_out: HoldOut,
    /// How the α̂ is picked from the scores.
    pub rule: CvRule,
    /// How the held-out points are split into folds.
    pub split: FoldSplit,
}

impl Default for CrossValidationSettings {
    fn default() -> Self {
        Self {
            folds: 5,
            grid: vec![3e-5, 3e-4, 3e-3, 3e-2, 0.3, 3.0],
            hold_out: HoldOut::IcpMarkers,
            rule: CvRule::Minimum,
            split: FoldSplit::Interleaved,
        }
    }
}

/// How cross-validation splits the held-out points into k folds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FoldSplit {
    /// Point i in fold i mod k: a held-out point keeps kept neighbours on every side, so the
    /// score measures interpolation between the kept points.
    Interleaved,
    /// Spatially blocked folds (Roberts et al. 2017, *Ecography* 40:913, "block
    /// cross-validation"): the points' positions (template positions of attachments and
    /// landmarks, marker positions) are grouped into k contiguous clusters by k-means
    /// ([`spatial_blocks`]) and fold j is cluster j. A held-out point's near neighbours are held
    /// out with it, so the score measures extrapolation away from the kept points — as at a free
    /// boundary or a gap between landmarks — rather than interpolation.
    SpatialBlocks,
}

/// How cross-validation picks α̂ from the scores of the grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CvRule {
    /// The α̂ with the lowest score.
    Minimum,
    /// The one-standard-error rule (Hastie, Tibshirani and Friedman, *The Elements of Statistical
    /// Learning* §7.10): the strongest smoothness (largest α̂) whose mean squared held-out error
    /// is at most the lowest one plus its standard error, sd(MSE₁ … MSE_k)/√k over the k folds.
    /// Where the score is flat near its minimum the folds cannot tell the α̂ there apart, and the
    /// rule takes the smoothest of them.
    OneStandardError,
}

impl CvRule {
    /// Name in reports (as in TOML).
    pub fn name(self) -> &'static str {
        match self {
            Self::Minimum => "minimum",
            Self::OneStandardError => "one-standard-error",
        }
    }
}

/// The target points cross-validation holds out.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HoldOut {
    /// ICP markers, scored by their distance to the reshaped surface: how well the surface is
    /// fitted, not where the material lies on it.
    IcpMarkers,
    /// Attachments and landmarks, scored by the distance of their template point from its
    /// target: correspondence, tangential error included. Every fold runs the whole reshape.
    Correspondence,
}

impl HoldOut {
    /// Name in reports (as in TOML).
    pub fn name(self) -> &'static str {
        match self {
            Self::IcpMarkers => "icp-markers",
            Self::Correspondence => "correspondence",
        }
    }
}

/// The cross-validation score of one α̂.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CrossValidationScore {
    /// α̂.
    pub smoothness: f64,
    /// Root mean square of the held-out errors over all folds \[m\] (markers: distance to the
    /// reshaped surface; correspondence: distance of the template point from its target).
    pub rms_m: f64,
    /// The RMS of each fold's held-out errors \[m\].
    pub fold_rms_m: Vec<f64>,
    /// Gauss–Newton iterations of the ICP stages of all folds.
    pub iterations: usize,
}

/// What cross-validation measured and chose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CrossValidationReport {
    /// k.
    pub folds: usize,
    /// Which target points were held out.
    pub hold_out: HoldOut,
    /// How α̂ was picked from the scores.
    pub rule: CvRule,
    /// One score per α̂ of the grid, in grid order.
    pub scores: Vec<CrossValidationScore>,
    /// The α̂ chosen (by the settings' [`CvRule`]).
    pub chosen: f64,
}

/// Marker i of `markers` is in fold `assignment[i]`: (the others, fold `fold`).
pub fn split_fold(
    markers: &[IcpMarker],
    assignment: &[usize],
    fold: usize,
) -> (Vec<IcpMarker>, Vec<IcpMarker>) {
    let (held, kept): (Vec<_>, Vec<_>) = markers
        .iter()
        .zip(assignment)
        .partition(|(_, f)| **f == fold);
    let strip = |v: Vec<(&IcpMarker, &usize)>| v.into_iter().map(|(m, _)| m.clone()).collect();
    (strip(kept), strip(held))
}

/// The fold of each point (0 … k − 1) under `split`; `positions` are the points' positions.
pub fn fold_assignment(positions: &[Vector3<f64>], folds: usize, split: FoldSplit) -> Vec<usize> {
    match split {
        FoldSplit::Interleaved => (0..positions.len()).map(|i| i % folds.max(1)).collect(),
        FoldSplit::SpatialBlocks => spatial_blocks(positions, folds),
    }
}

/// k contiguous blocks of `points` by k-means (Lloyd's algorithm): the cluster of each point.
///
/// Deterministic: the seeds are farthest-point samples (the point farthest from the centroid,
/// then each next the point farthest from the seeds so far; ties to the lower index); Lloyd's
/// iterations (assign each point to its nearest centre, ties to the lower cluster; move each
/// centre to its cluster's mean) run until no assignment changes (at most 100). A cluster left
/// empty is re-seeded at the point farthest from its own centre. At the fixed point every point
/// is nearer its own cluster's mean than any other's: the clusters are the cells of a Voronoi
/// partition, contiguous in space. `k` is clamped to 1 … the number of points.
pub fn spatial_blocks(points: &[Vector3<f64>], k: usize) -> Vec<usize> {
    let n = points.len();
    let k = k.clamp(1, n.max(1));
    if n == 0 {
        return Vec::new();
    }
    let centroid = points.iter().sum::<Vector3<f64>>() / n as f64;
    let farthest_from = |d: &[f64]| {
        (0..n)
            .max_by(|&a, &b| d[a].total_cmp(&d[b]).then(b.cmp(&a)))
            .unwrap_or(0)
    };
    let mut d: Vec<f64> = points.iter().map(|p| (p - centroid).norm()).collect();
    let mut centres = Vec::with_capacity(k);
    while centres.len() < k {
        let next = farthest_from(&d);
        centres.push(points[next]);
        for (di, p) in d.iter_mut().zip(points) {
            *di = di.min((p - points[next]).norm());
        }
        d[next] = -1.0;
    }
    let nearest = |p: &Vector3<f64>, centres: &[Vector3<f64>]| {
        (0..centres.len())
            .min_by(|&a, &b| {
                (p - centres[a])
                    .norm_squared()
                    .total_cmp(&(p - centres[b]).norm_squared())
                    .then(a.cmp(&b))
            })
            .unwrap_or(0)
    };
    let mut cluster: Vec<usize> = points.iter().map(|p| nearest(p, &centres)).collect();
    for _ in 0..100 {
        for (j, centre) in centres.iter_mut().enumerate() {
            let members: Vec<&Vector3<f64>> = (0..n)
                .filter(|&i| cluster[i] == j)
                .map(|i| &points[i])
                .collect();
            if members.is_empty() {
                let d: Vec<f64> = points.iter().map(|p| (p - *centre).norm()).collect();
                *centre = points[farthest_from(&d)];
            } else {
                *centre = members.iter().copied().sum::<Vector3<f64>>() / members.len() as f64;
            }
        }
        let next: Vec<usize> = points.iter().map(|p| nearest(p, &centres)).collect();
        if next == cluster {
            break;
        }
        cluster = next;
    }
    cluster
}

/// Checks the cross-validation settings against `markers` ICP markers.
fn check(settings: &CrossValidationSettings, markers: usize) -> Result<()> {
    let bad = |field: &str, problem: String| TissueError::BadSettings {
        field: format!("cross_validation.{field}"),
        problem,
    };
    if settings.folds < 2 || settings.folds > markers {
        return Err(bad(
            "folds",
            format!(
                "{} folds: smoothness = \"cv\" needs 2 ≤ folds ≤ the number of ICP markers ({markers})",
                settings.folds
            ),
        ));
    }
    if settings.grid.is_empty() || settings.grid.iter().any(|a| !(a.is_finite() && *a > 0.0)) {
        return Err(bad(
            "grid",
            format!("{:?}: expected one or more positive α̂", settings.grid),
        ));
    }
    Ok(())
}

/// The reshape with α̂ chosen by k-fold cross-validation (module docs), from `initial` (the
/// template in equilibrium).
pub(super) fn cross_validated(
    mut solver: Solver<'_>,
    initial: State,
    progress: &mut ProgressFn<'_>,
) -> Result<ReshapeOutcome> {
    let settings = &solver.settings.cross_validation;
    if settings.hold_out == HoldOut::Correspondence {
        return correspondence_cross_validated(solver, progress);
    }
    let all = solver.problem.icp_markers.clone();
    check(settings, all.len())?;
    let folds = settings.folds;
    let grid = settings.grid.clone();
    let positions: Vec<Vector3<f64>> = all.iter().map(|m| m.position_m).collect();
    let assignment = fold_assignment(&positions, folds, settings.split);
    let schedule = solver.schedule();
    let (icp, before): (Vec<_>, Vec<_>) = schedule.into_iter().partition(|s| s.icp);
    let mut starts = Vec::with_capacity(grid.len());
    let mut scores = Vec::with_capacity(grid.len());
    for &smoothness in &grid {
        solver.set_smoothness(smoothness)?;
        solver.set_icp_markers(all.clone());
        let mut state = initial.clone();
        let mut history = Vec::new();
        let label = format!("cv α̂ {smoothness:.0e}");
        let stages = solver.run_stages(&before, &mut state, &mut history, &mut |s, i, e, m| {
            progress(&format!("{label} {s}"), i, e, m)
        })?;
        let mut squared = 0.0;
        let mut fold_rms_m = Vec::with_capacity(folds);
        let mut iterations = 0;
        for fold in 0..folds {
            let (kept, held) = split_fold(&all, &assignment, fold);
            solver.set_icp_markers(kept);
            let mut trial = state.clone();
            let label = format!("{label} fold {}/{folds}", fold + 1);
            let reports =
                solver.run_stages(&icp, &mut trial, &mut Vec::new(), &mut |s, i, e, m| {
                    progress(&format!("{label} {s}"), i, e, m)
                })?;
            iterations += reports.iter().map(|r| r.iterations).sum::<usize>();
            let fold_squared = solver
                .marker_distances(&trial, &held)
                .iter()
                .map(|d| d * d)
                .sum::<f64>();
            squared += fold_squared;
            fold_rms_m.push((fold_squared / held.len().max(1) as f64).sqrt());
        }
        scores.push(CrossValidationScore {
            smoothness,
            rms_m: (squared / all.len() as f64).sqrt(),
            fold_rms_m,
            iterations,
        });
        starts.push((state, stages, history));
    }
    let chosen = choose(&scores, settings.rule)?;
    let best = grid.iter().position(|&a| a == chosen).unwrap_or(0);
    solver.set_smoothness(chosen)?;
    solver.set_icp_markers(all);
    let (mut state, mut stages, mut history) = starts.swap_remove(best);
    stages.extend(solver.run_stages(&icp, &mut state, &mut history, progress)?);
    let report = CrossValidationReport {
        folds,
        hold_out: HoldOut::IcpMarkers,
        rule: settings.rule,
        scores,
        chosen,
    };
    Ok(solver.finish(state, stages, history, Some(report)))
}

/// [`HoldOut::Correspondence`]: the attachments and landmarks (in that order, split by
/// [`FoldSplit`] on their template positions) are held out in turn; every fold runs the whole reshape without them, the score is
/// the RMS distance of the held-out template points from their targets.
fn correspondence_cross_validated(
    solver: Solver<'_>,
    progress: &mut ProgressFn<'_>,
) -> Result<ReshapeOutcome> {
    let (problem, base) = (solver.problem, solver.settings);
    let cv = &base.cross_validation;
    let (attachments, landmarks) = (problem.attachments.len(), problem.landmarks.len());
    let points = attachments + landmarks;
    check(cv, points)?;
    let rest = &problem.template.vertices;
    let positions: Vec<Vector3<f64>> = (problem.attachments.iter().map(|a| rest[a.node]))
        .chain(problem.landmarks.iter().map(|l| l.point.at(rest)))
        .collect();
    let assignment = fold_assignment(&positions, cv.folds, cv.split);
    let mut scores = Vec::with_capacity(cv.grid.len());
    for &smoothness in &cv.grid {
        let settings = super::solve::ReshapeSettings {
            smoothness: Smoothness::Fixed(smoothness),
            ..base.clone()
        };
        let mut squared = 0.0;
        let mut fold_rms_m = Vec::with_capacity(cv.folds);
        let mut iterations = 0;
        for fold in 0..cv.folds {
            let held = |i: usize| assignment[i] == fold;
            let mut train = problem.clone();
            train.attachments = keep(&problem.attachments, |i| !held(i));
            train.landmarks = keep(&problem.landmarks, |i| !held(attachments + i));
            let label = format!("cv α̂ {smoothness:.0e} fold {}/{}", fold + 1, cv.folds);
            let out = super::solve::reshape(&train, &settings, &mut |s, i, e, m| {
                progress(&format!("{label} {s}"), i, e, m)
            })?;
            iterations += out.stages.iter().map(|s| s.iterations).sum::<usize>();
            let x = &out.positions_m;
            let fold_points = (0..points).filter(|&i| held(i)).count();
            let fold_squared = (0..attachments)
                .filter(|&i| held(i))
                .map(|i| &problem.attachments[i])
                .map(|a| (x[a.node] - a.target_m).norm_squared())
                .chain(
                    (0..landmarks)
                        .filter(|&i| held(attachments + i))
                        .map(|i| &problem.landmarks[i])
                        .map(|l| (l.point.at(x) - l.target_m).norm_squared()),
                )
                .sum::<f64>();
            squared += fold_squared;
            fold_rms_m.push((fold_squared / fold_points.max(1) as f64).sqrt());
        }
        scores.push(CrossValidationScore {
            smoothness,
            rms_m: (squared / points as f64).sqrt(),
            fold_rms_m,
            iterations,
        });
    }
    let chosen = choose(&scores, cv.rule)?;
    let settings = super::solve::ReshapeSettings {
        smoothness: Smoothness::Fixed(chosen),
        ..base.clone()
    };
    let mut out = super::solve::reshape(problem, &settings, progress)?;
    out.cross_validation = Some(CrossValidationReport {
        folds: cv.folds,
        hold_out: HoldOut::Correspondence,
        rule: cv.rule,
        scores,
        chosen,
    });
    Ok(out)
}

/// The items of `v` whose index passes `pred`.
fn keep<T: Clone>(v: &[T], pred: impl Fn(usize) -> bool) -> Vec<T> {
    v.iter()
        .enumerate()
        .filter(|(i, _)| pred(*i))
        .map(|(_, t)| t.clone())
        .collect()
}

/// The α̂ picked from `scores` by `rule`, among those with a finite score.
pub fn choose(scores: &[CrossValidationScore], rule: CvRule) -> Result<f64> {
    let finite = || scores.iter().filter(|s| s.rms_m.is_finite());
    let best = finite()
        .min_by(|a, b| a.rms_m.total_cmp(&b.rms_m))
        .ok_or_else(|| TissueError::NotConverged {
            what: "cross-validation of the smoothness weight".into(),
            status: "no α̂ of the grid gave a finite held-out error".into(),
        })?;
    Ok(match rule {
        CvRule::Minimum => best.smoothness,
        CvRule::OneStandardError => {
            let limit = best.rms_m.powi(2) + standard_error(&best.fold_rms_m);
            finite()
                .filter(|s| s.rms_m.powi(2) <= limit)
                .map(|s| s.smoothness)
                .fold(best.smoothness, f64::max)
        }
    })
}

/// Standard error of the cross-validated mean squared error (ESL §7.10): sd(MSE₁ … MSE_k)/√k
/// from the folds' RMS errors; 0 for fewer than two folds.
pub fn standard_error(fold_rms_m: &[f64]) -> f64 {
    let k = fold_rms_m.len();
    if k < 2 {
        return 0.0;
    }
    let mse: Vec<f64> = fold_rms_m.iter().map(|r| r * r).collect();
    let mean = mse.iter().sum::<f64>() / k as f64;
    let variance = mse.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / (k - 1) as f64;
    (variance / k as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reshape::ReshapeSettings;

    #[test]
    fn smoothness_reads_a_number_or_cv() {
        let s: ReshapeSettings = toml::from_str("smoothness = 0.3").unwrap();
        assert_eq!(s.smoothness, Smoothness::Fixed(0.3));
        let s: ReshapeSettings = toml::from_str("smoothness = 1").unwrap();
        assert_eq!(s.smoothness, Smoothness::Fixed(1.0));
        let s: ReshapeSettings =
            toml::from_str("smoothness = \"cv\"\n[cross_validation]\nfolds = 3\n").unwrap();
        assert_eq!(s.smoothness, Smoothness::CrossValidated);
        assert_eq!(s.cross_validation.folds, 3);
        assert_eq!(
            s.cross_validation.grid,
            CrossValidationSettings::default().grid
        );
        let e = toml::from_str::<ReshapeSettings>("smoothness = \"auto\"")
            .unwrap_err()
            .to_string();
        assert!(e.contains("\"cv\""), "{e}");
        let back = toml::to_string(&ReshapeSettings {
            smoothness: Smoothness::CrossValidated,
            ..ReshapeSettings::default()
        })
        .unwrap();
        assert!(back.contains("smoothness = \"cv\""), "{back}");
    }

    fn score(smoothness: f64, fold_rms_mm: &[f64]) -> CrossValidationScore {
        let fold_rms_m: Vec<f64> = fold_rms_mm.iter().map(|r| r * 1e-3).collect();
        let mse = fold_rms_m.iter().map(|r| r * r).sum::<f64>() / fold_rms_m.len() as f64;
        CrossValidationScore {
            smoothness,
            rms_m: mse.sqrt(),
            fold_rms_m,
            iterations: 0,
        }
    }

    /// The one-standard-error rule against a hand computation: fold MSEs 0.04, 0.09, 0.16,
    /// 0.25 mm² (mean 0.135, sd 0.0911, SE 0.0456) at α̂ = 0.1 make the limit 0.1806 mm²; α̂ = 0.3
    /// (MSE 0.17) is within it, α̂ = 1 (MSE 0.19) is not.
    #[test]
    fn one_standard_error_rule_takes_the_smoothest_within_one_se() {
        assert!((standard_error(&[0.2e-3, 0.3e-3, 0.4e-3, 0.5e-3]) - 0.045_552e-6).abs() < 1e-12);
        let scores = vec![
            score(1e-2, &[0.4, 0.4, 0.4, 0.4]),
            score(0.1, &[0.2, 0.3, 0.4, 0.5]),
            score(0.3, &[0.17f64.sqrt(); 4]),
            score(1.0, &[0.19f64.sqrt(); 4]),
            score(3.0, &[f64::NAN; 4]),
        ];
        assert_eq!(choose(&scores, CvRule::Minimum).unwrap(), 0.1);
        assert_eq!(choose(&scores, CvRule::OneStandardError).unwrap(), 0.3);
        // Folds that agree leave no room: the minimum itself.
        let sharp = vec![score(0.1, &[0.3; 4]), score(0.3, &[0.31; 4])];
        assert_eq!(choose(&sharp, CvRule::OneStandardError).unwrap(), 0.1);
        assert!(choose(&[score(1.0, &[f64::NAN; 2])], CvRule::Minimum).is_err());
    }

    /// Spatial blocks on four well-separated groups of points (listed interleaved, so index
    /// folds would mix them): each block is one group, every point is in exactly one block, and
    /// the split does not depend on anything but the positions (same call, same answer).
    #[test]
    fn spatial_blocks_are_contiguous_deterministic_and_cover_every_point_once() {
        let corners = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(1.0, 1.0, 0.2),
        ];
        let points: Vec<Vector3<f64>> = (0..40)
            .map(|i| {
                let u = |k: usize| (((3 * i + k) as f64 * 12.9898).sin() * 43758.5453).fract();
                corners[i % 4] + Vector3::new(u(0), u(1), u(2)) * 0.1
            })
            .collect();
        let blocks = fold_assignment(&points, 4, FoldSplit::SpatialBlocks);
        assert_eq!(blocks.len(), points.len());
        assert_eq!(blocks, spatial_blocks(&points, 4));
        for i in 0..points.len() {
            assert!(blocks[i] < 4);
            // Same group ⇔ same block.
            for j in 0..points.len() {
                assert_eq!(blocks[i] == blocks[j], i % 4 == j % 4, "points {i} and {j}");
            }
        }
        // Contiguity on points without obvious groups (a 7 × 6 grid): every point is nearer
        // its own block's mean than any other block's (the blocks are Voronoi cells), and
        // every block holds points.
        let grid: Vec<Vector3<f64>> = (0..42)
            .map(|i| Vector3::new((i % 7) as f64, (i / 7) as f64 * 1.1, 0.0))
            .collect();
        let blocks = spatial_blocks(&grid, 4);
        let means: Vec<Vector3<f64>> = (0..4)
            .map(|j| {
                let m: Vec<&Vector3<f64>> = (0..42)
                    .filter(|&i| blocks[i] == j)
                    .map(|i| &grid[i])
                    .collect();
                assert!(!m.is_empty(), "block {j} is empty");
                m.iter().copied().sum::<Vector3<f64>>() / m.len() as f64
            })
            .collect();
        for (p, &b) in grid.iter().zip(&blocks) {
            for m in &means {
                assert!((p - means[b]).norm() <= (p - m).norm() + 1e-12);
            }
        }
        let interleaved = fold_assignment(&grid, 4, FoldSplit::Interleaved);
        assert_eq!(interleaved[..5], [0, 1, 2, 3, 0]);
        // Degenerate sizes: more blocks than points, no points.
        assert_eq!(spatial_blocks(&grid[..2], 4).len(), 2);
        assert!(spatial_blocks(&[], 3).is_empty());
    }

    #[test]
    fn split_reads_from_toml() {
        let s: ReshapeSettings =
            toml::from_str("smoothness = \"cv\"\n[cross_validation]\nsplit = \"spatial-blocks\"\n")
                .unwrap();
        assert_eq!(s.cross_validation.split, FoldSplit::SpatialBlocks);
        assert_eq!(
            CrossValidationSettings::default().split,
            FoldSplit::Interleaved
        );
    }

    #[test]
    fn folds_partition_the_markers() {
        let markers: Vec<IcpMarker> = (0..11)
            .map(|i| IcpMarker {
                id: format!("m{i}"),
                position_m: nalgebra::Vector3::repeat(i as f64),
            })
            .collect();
        let mut seen = Vec::new();
        for fold in 0..3 {
            let assignment =
                fold_assignment(&vec![Vector3::zeros(); 11], 3, FoldSplit::Interleaved);
            let (kept, held) = split_fold(&markers, &assignment, fold);
            assert_eq!(kept.len() + held.len(), 11);
            assert!(held.iter().all(|m| !kept.contains(m)));
            seen.extend(held.into_iter().map(|m| m.id));
        }
        seen.sort();
        let mut ids: Vec<String> = markers.into_iter().map(|m| m.id).collect();
        ids.sort();
        assert_eq!(seen, ids);
    }
}
