//! Choosing the smoothness weight α̂ without ground truth: k-fold cross-validation on the ICP
//! markers (Stone 1974; Hastie, Tibshirani and Friedman, *The Elements of Statistical Learning*
//! §7.10).
//!
//! saito-barbic fix α (eq. 3) by hand. α̂ trades how closely the reshaped surface follows the
//! markers against how smooth the plastic strain is; the right trade depends on the object (a
//! bulky organ vs a thin layer) and on how dense and noisy the markers are. With
//! `smoothness = "cv"` the ICP markers are split into k folds (marker i in fold i mod k); for
//! every α̂ of a log grid each fold is held out in turn, the reshape is run with the other
//! markers, and the held-out markers' distances to the reshaped ICP surface are collected. The
//! score of α̂ is the root mean square of those distances over all markers (each is held out once);
//! the α̂ with the lowest score is chosen and the reshape is run again with every marker.
//!
//! Cost: the stages before the ICP stage (constant guess, attachments, landmarks) do not see the
//! ICP markers, so they run once per α̂ and every fold starts its ICP stage from their result;
//! the refit reuses them too. A cross-validated reshape costs about (grid × (folds + 1)) ICP
//! stages. Only the ICP markers are held out: landmarks and attachments carry correspondence,
//! few of them each, and every fold needs them.

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
}

impl Default for CrossValidationSettings {
    fn default() -> Self {
        Self {
            folds: 5,
            grid: vec![3e-5, 3e-4, 3e-3, 3e-2, 0.3, 3.0],
            hold_out: HoldOut::IcpMarkers,
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

/// The cross-validation score of one α̂.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CrossValidationScore {
    /// α̂.
    pub smoothness: f64,
    /// Root mean square of the held-out markers' distances to the reshaped surface \[m\].
    pub rms_m: f64,
    /// Gauss–Newton iterations of the ICP stages of all folds.
    pub iterations: usize,
}

/// What cross-validation measured and chose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CrossValidationReport {
    /// k.
    pub folds: usize,
    /// One score per α̂ of the grid, in grid order.
    pub scores: Vec<CrossValidationScore>,
    /// The α̂ chosen (lowest score).
    pub chosen: f64,
}

/// Marker i of `markers` is in fold i mod `folds`: (the others, fold `fold`).
pub fn split_fold(
    markers: &[IcpMarker],
    folds: usize,
    fold: usize,
) -> (Vec<IcpMarker>, Vec<IcpMarker>) {
    let (held, kept): (Vec<_>, Vec<_>) = markers
        .iter()
        .enumerate()
        .partition(|(i, _)| i % folds == fold);
    let strip = |v: Vec<(usize, &IcpMarker)>| v.into_iter().map(|(_, m)| m.clone()).collect();
    (strip(kept), strip(held))
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
        let mut iterations = 0;
        for fold in 0..folds {
            let (kept, held) = split_fold(&all, folds, fold);
            solver.set_icp_markers(kept);
            let mut trial = state.clone();
            let label = format!("{label} fold {}/{folds}", fold + 1);
            let reports =
                solver.run_stages(&icp, &mut trial, &mut Vec::new(), &mut |s, i, e, m| {
                    progress(&format!("{label} {s}"), i, e, m)
                })?;
            iterations += reports.iter().map(|r| r.iterations).sum::<usize>();
            squared += solver
                .marker_distances(&trial, &held)
                .iter()
                .map(|d| d * d)
                .sum::<f64>();
        }
        scores.push(CrossValidationScore {
            smoothness,
            rms_m: (squared / all.len() as f64).sqrt(),
            iterations,
        });
        starts.push((state, stages, history));
    }
    let chosen = best(&scores)?;
    let best = grid.iter().position(|&a| a == chosen).unwrap_or(0);
    solver.set_smoothness(chosen)?;
    solver.set_icp_markers(all);
    let (mut state, mut stages, mut history) = starts.swap_remove(best);
    stages.extend(solver.run_stages(&icp, &mut state, &mut history, progress)?);
    let report = CrossValidationReport {
        folds,
        scores,
        chosen,
    };
    Ok(solver.finish(state, stages, history, Some(report)))
}

/// [`HoldOut::Correspondence`]: the attachments and landmarks (in that order, point i in fold
/// i mod k) are held out in turn; every fold runs the whole reshape without them, the score is
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
    let mut scores = Vec::with_capacity(cv.grid.len());
    for &smoothness in &cv.grid {
        let settings = super::solve::ReshapeSettings {
            smoothness: Smoothness::Fixed(smoothness),
            ..base.clone()
        };
        let mut squared = 0.0;
        let mut iterations = 0;
        for fold in 0..cv.folds {
            let held = |i: usize| i % cv.folds == fold;
            let mut train = problem.clone();
            train.attachments = keep(&problem.attachments, |i| !held(i));
            train.landmarks = keep(&problem.landmarks, |i| !held(attachments + i));
            let label = format!("cv α̂ {smoothness:.0e} fold {}/{}", fold + 1, cv.folds);
            let out = super::solve::reshape(&train, &settings, &mut |s, i, e, m| {
                progress(&format!("{label} {s}"), i, e, m)
            })?;
            iterations += out.stages.iter().map(|s| s.iterations).sum::<usize>();
            let x = &out.positions_m;
            squared += (0..attachments)
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
        }
        scores.push(CrossValidationScore {
            smoothness,
            rms_m: (squared / points as f64).sqrt(),
            iterations,
        });
    }
    let chosen = best(&scores)?;
    let settings = super::solve::ReshapeSettings {
        smoothness: Smoothness::Fixed(chosen),
        ..base.clone()
    };
    let mut out = super::solve::reshape(problem, &settings, progress)?;
    out.cross_validation = Some(CrossValidationReport {
        folds: cv.folds,
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

/// The α̂ with the lowest finite score.
fn best(scores: &[CrossValidationScore]) -> Result<f64> {
    scores
        .iter()
        .filter(|s| s.rms_m.is_finite())
        .min_by(|a, b| a.rms_m.total_cmp(&b.rms_m))
        .map(|s| s.smoothness)
        .ok_or_else(|| TissueError::NotConverged {
            what: "cross-validation of the smoothness weight".into(),
            status: "no α̂ of the grid gave a finite held-out error".into(),
        })
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
            let (kept, held) = split_fold(&markers, 3, fold);
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
