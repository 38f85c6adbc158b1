//! Confirmation of a hypothesis by its re-simulated extended model, leave-one-location-out —
//! the ONE selection/scoring loop used by every confirmation path
//! (every hypothesis's extended FEM model, `crate::hypotheses`; the grids come from
//! [`crate::resim`]).
//!
//! Input: candidate predictions (a grid of extended models, each simulated over the whole
//! recording). Per held-out location l:
//!
//! 1. choose the candidate i and the material compliance scale d with the least squared error on
//!    every observation outside l (the other locations and the rest frames):
//!    d = argmin Σ‖d u − v‖² = (Σ u·v)/(Σ u·u), clamped to the [`ComplianceScale`] bounds, with
//!    u = x_i − x_rest the candidate's displacement from the model's unloaded markers and
//!    v = y − x_rest the measured one (a nuisance refit of the overall stiffness: the tissue fit
//!    saw the unmodelled effect, so its stiffness is biased by it) — d = 1 for a
//!    [`Candidate::position_controlled`] one (a rigid-tip replay: the measured tip pose sets the
//!    surface under the tip, and a uniform scale of the displacement field would move that surface
//!    off the tip);
//! 2. the held-out prediction of l is x_rest + d u_i — or, with a refit closure, the closure's
//!    prediction of candidate i refitted without l (e.g. the material refit on the corrected
//!    forces of a force-channel hypothesis, `crate::hypotheses::sensor_lag`);
//! 3. score it on l's `scored` observations (the affected cells) and on all of l's observations.
//!
//! When a candidate's own parameters must be refitted with the extension in place before it can
//! be judged ([`lolo_confirm_each_refitted`]: the support springs and the material), every
//! candidate is refitted per training set and step 1 chooses between the refitted candidates.
//!
//! The full-data choice (nothing held out) is the extended model's prediction and parameters.

use crate::Result;
use crate::baseline::Prepared;
use crate::recording::Recording;
use crate::segment::Segmentation;
use crate::sim::Field;

/// One simulated candidate of a confirmation grid.
pub struct Candidate {
    /// Named parameters of the extended model.
    pub params: Vec<(String, f64)>,
    /// Markers per frame, m.
    pub prediction: Field,
    /// Simulated under position control (the rigid tip replayed at its measured poses): the
    /// compliance scale stays 1 (module docs). A force-driven candidate's displacements scale
    /// with the material's compliance, so its scale is refitted; a position-controlled one's
    /// depth is the measured one whatever the material's stiffness.
    pub position_controlled: bool,
}

/// An extended model confirmed by re-simulation with leave-one-location-out.
pub struct Confirmed {
    /// Held-out RMS on the scored observations, m.
    pub after_scored_m: f64,
    /// Held-out RMS on every observation of the locations, m.
    pub after_all_m: f64,
    /// Full-data parameters.
    pub params: Vec<(String, f64)>,
    /// Full-data prediction, m.
    pub prediction: Field,
    /// How it was confirmed.
    pub method: String,
    /// Held-out RSS on the scored observations per fold (location), m² (empty: not per fold).
    pub fold_rss_m2: Vec<f64>,
    /// Held-out scored observations per fold.
    pub fold_n: Vec<usize>,
    /// The extended model's held-out error on the force channel (`crate::indentation`), for a
    /// hypothesis that changes the force–indentation relation.
    pub force: Option<crate::indentation::ForceScore>,
}

/// The nuisance refit of the material's overall compliance d (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct ComplianceScale {
    /// Refit d on the training observations (else d = 1).
    pub fit: bool,
    /// Lower bound of d (only against degenerate sums).
    pub min: f64,
    /// Upper bound of d.
    pub max: f64,
}

impl ComplianceScale {
    /// Fitted with the bounds [`min`, `max`] (`fit` = false: d = 1).
    pub fn new(fit: bool, min: f64, max: f64) -> Self {
        Self { fit, min, max }
    }
}

/// Sums over the observations of one bucket: a = Σ u·u, b = Σ u·v, c = Σ v·v (module docs);
/// Σ‖d u − v‖² = c − 2 d b + d² a.
#[derive(Clone, Copy, Default, Debug)]
struct Sums {
    a: f64,
    b: f64,
    c: f64,
    n: usize,
}

impl Sums {
    fn add(&mut self, o: &Sums) {
        self.a += o.a;
        self.b += o.b;
        self.c += o.c;
        self.n += o.n;
    }
    fn scale(&self, s: ComplianceScale) -> f64 {
        if s.fit && self.a > 0.0 {
            (self.b / self.a).clamp(s.min, s.max)
        } else {
            1.0
        }
    }
    fn rss(&self, d: f64) -> f64 {
        (self.c - 2.0 * d * self.b + d * d * self.a).max(0.0)
    }
}

/// The refit closure of [`lolo_confirm`]: `(candidate index, held-out location or None for the
/// full data) -> prediction of that candidate refitted without the held-out location`; `Ok(None)`
/// when it cannot refit (then the confirmation gives `None`). The refits of the held-out
/// locations and of the full data are independent: [`lolo_confirm`] runs them in parallel
/// (hence `Fn + Sync`).
pub type RefitFn<'a> = dyn Fn(usize, Option<usize>) -> Result<Option<Field>> + Sync + 'a;

/// A candidate refitted on one training set ([`lolo_confirm_each_refitted`]).
pub struct Refitted {
    /// Markers per frame of the refitted candidate, m.
    pub prediction: Field,
    /// The refitted parameters (named).
    pub params: Vec<(String, f64)>,
}

/// The refit closure of [`lolo_confirm_each_refitted`]: `(candidate index, held-out location or
/// None for the full data, the candidate's full-data refit to start from when a location is held
/// out) -> that candidate with its parameters refitted without the held-out location`;
/// `Ok(None)` when it cannot be refitted there (the closure reports why; the candidate is then not
/// offered to that selection). Independent refits, run in parallel (hence `Fn + Sync`).
pub type RefitEachFn<'a> =
    dyn Fn(usize, Option<usize>, Option<&Refitted>) -> Result<Option<Refitted>> + Sync + 'a;

/// One candidate of [`lolo_confirm_each_refitted`]: its full-data refit's parameters and scored
/// RMS over the locations (in-sample), and its held-out scored RMS over the locations whose
/// selection chose it (each predicted by its refit without that location), m; NaN where the
/// full-data refit declined or was not made (not in the first pass nor a neighbour of a choice)
/// or no selection chose it.
#[derive(Clone, Debug)]
pub struct RefittedScore {
    /// The candidate's parameters, then its full-data refit's.
    pub params: Vec<(String, f64)>,
    /// In-sample scored RMS of the full-data refit, m.
    pub in_sample_m: f64,
    /// Held-out scored RMS over the locations that chose it, m.
    pub heldout_m: f64,
    /// The locations whose selection chose it.
    pub chosen_for: Vec<usize>,
}

/// Leave-one-location-out in which the candidates' own parameters are refitted with the
/// extension in place (the material of an extended model, `crate::hypotheses::support_slip`):
/// the candidates of `first_pass` are refitted on the full data (`refit(i, None, None)`), then,
/// while some selection's least-training-error candidate (below) has `neighbours` not yet
/// refitted, those — so every selection's choice is a local minimum of its training error over
/// `neighbours` (on a grid whose training error is unimodal, the grid's minimum: a coarse pass
/// and its refinement instead of every point; `first_pass` = every candidate refits them all).
/// The selection for a
/// held-out location l takes the candidate whose full-data refit has the least squared error on
/// l's training observations (every observation outside l: the other locations and the rest
/// frames; with `train_on_scored` the other locations' scored ones, and the held-out "all" number
/// over the scored ones too); only that candidate is refitted without l, starting from its
/// full-data refit (`refit(i, Some(l), Some(full_i))`), and predicts l, scored on l's `scored`
/// observations and on all of them (a refit that declines passes l to the next candidate by
/// training error). The full data's choice is the extended model and its parameters. So the
/// choice is made between refitted candidates (none is judged on the material a fit without the
/// extension gave) for at most `candidates + locations` refits instead of `candidates × (locations + 1)`;
/// the discrete choice for l sees l through the full-data refits' parameters, the held-out
/// prediction does not. No compliance scale: the refit replaces it. Returns the confirmation
/// (`None` without candidates or when a location has no refitted candidate) and every
/// candidate's [`RefittedScore`].
pub fn lolo_confirm_each_refitted(
    params: &[Vec<(String, f64)>],
    rec: &Recording,
    seg: &Segmentation,
    scored: &dyn Fn(usize, usize) -> bool,
    train_on_scored: bool,
    first_pass: &[usize],
    neighbours: &dyn Fn(usize) -> Vec<usize>,
    refit: &RefitEachFn<'_>,
    method: String,
) -> Result<(Option<Confirmed>, Vec<RefittedScore>)> {
    use rayon::prelude::*;
    let nf = seg.num_folds();
    // The sums of a refit per bucket (the folds, then the rest frames): all, scored.
    let bucket = |k: usize| seg.fold_of_frame[k].unwrap_or(nf);
    let sums = |r: Refitted| {
        let (mut all, mut sc) = (vec![Sums::default(); nf + 1], vec![Sums::default(); nf + 1]);
        for (k, f) in rec.frames.iter().enumerate() {
            for (m, y) in f.markers_m.iter().enumerate() {
                let Some(y) = y else { continue };
                let o = Sums {
                    c: (y - r.prediction[k][m]).norm_squared(),
                    n: 1,
                    ..Sums::default()
                };
                let is_scored = seg.fold_of_frame[k].is_some() && scored(k, m);
                if !train_on_scored || is_scored {
                    all[bucket(k)].add(&o);
                }
                if is_scored {
                    sc[bucket(k)].add(&o);
                }
            }
        }
        (r, all, sc)
    };
    // The training error of a full-data refit's sums for held-out bucket l (l = nf: all).
    let training_of = |all: &[Sums], l: usize| {
        all.iter()
            .enumerate()
            .filter(|&(b, _)| b != l)
            .map(|(_, s)| s.c)
            .sum::<f64>()
    };
    // Full-data refits: the first pass, then the unrefitted neighbours of every selection's
    // least-training-error candidate until each selection's choice is a local minimum.
    let mut full: Vec<Option<(Refitted, Vec<Sums>, Vec<Sums>)>> =
        (0..params.len()).map(|_| None).collect();
    let mut tried = vec![false; params.len()];
    let mut batch: Vec<usize> = first_pass
        .iter()
        .copied()
        .filter(|&i| i < params.len())
        .collect();
    while !batch.is_empty() {
        let refits: Vec<Result<Option<Refitted>>> =
            batch.par_iter().map(|&i| refit(i, None, None)).collect();
        for (&i, r) in batch.iter().zip(refits) {
            tried[i] = true;
            full[i] = r?.map(sums);
        }
        let mut next: Vec<usize> = (0..=nf)
            .filter_map(|l| {
                (0..params.len())
                    .filter_map(|i| full[i].as_ref().map(|(_, all, _)| (i, training_of(all, l))))
                    .min_by(|a, b| a.1.total_cmp(&b.1))
            })
            .flat_map(|(i, _)| neighbours(i))
            .filter(|&j| j < params.len() && !tried[j])
            .collect();
        next.sort_unstable();
        next.dedup();
        batch = next;
    }
    let training = |i: usize, l: usize| full[i].as_ref().map(|(_, all, _)| training_of(all, l));
    let by_training = |l: usize| {
        let mut order: Vec<(usize, f64)> = (0..params.len())
            .filter_map(|i| training(i, l).map(|e| (i, e)))
            .collect();
        order.sort_by(|a, b| a.1.total_cmp(&b.1));
        order.into_iter().map(|(i, _)| i).collect::<Vec<_>>()
    };
    // Per location: the first candidate by training error whose refit without it succeeds.
    let held: Vec<Result<Option<(usize, Refitted)>>> = (0..nf)
        .into_par_iter()
        .map(|l| {
            for i in by_training(l) {
                let from = full[i].as_ref().map(|(r, _, _)| r);
                if let Some(r) = refit(i, Some(l), from)? {
                    return Ok(Some((i, r)));
                }
            }
            Ok(None)
        })
        .collect();
    let rms = |e: f64, n: usize| (e / n.max(1) as f64).sqrt();
    let mut scores: Vec<RefittedScore> = (0..params.len())
        .map(|i| {
            let mut params = params[i].clone();
            let in_sample_m = match &full[i] {
                Some((r, _, sc)) => {
                    params.extend(r.params.iter().cloned());
                    let sc = &sc[..nf];
                    rms(sc.iter().map(|s| s.c).sum(), sc.iter().map(|s| s.n).sum())
                }
                None => f64::NAN,
            };
            RefittedScore {
                params,
                in_sample_m,
                heldout_m: f64::NAN,
                chosen_for: Vec::new(),
            }
        })
        .collect();
    let mut chosen_folds = Vec::with_capacity(nf);
    for h in held {
        chosen_folds.push(h?.map(|(i, r)| {
            let (_, all, sc) = sums(r);
            (i, all, sc)
        }));
    }
    let (mut e_sc, mut n_sc, mut e_all, mut n_all) = (0.0, 0usize, 0.0, 0usize);
    let (mut fold_rss_m2, mut fold_n) = (Vec::with_capacity(nf), Vec::with_capacity(nf));
    let mut per_candidate = vec![(0.0, 0usize); params.len()];
    for (l, h) in chosen_folds.iter().enumerate() {
        let Some((i, all, sc)) = h else { continue };
        e_sc += sc[l].c;
        n_sc += sc[l].n;
        e_all += all[l].c;
        n_all += all[l].n;
        fold_rss_m2.push(sc[l].c);
        fold_n.push(sc[l].n);
        per_candidate[*i].0 += sc[l].c;
        per_candidate[*i].1 += sc[l].n;
        scores[*i].chosen_for.push(l);
    }
    for (s, &(e, n)) in scores.iter_mut().zip(&per_candidate) {
        if !s.chosen_for.is_empty() {
            s.heldout_m = rms(e, n);
        }
    }
    let full_choice = by_training(nf).first().copied();
    let (Some(i), true) = (full_choice, chosen_folds.iter().all(Option::is_some)) else {
        return Ok((None, scores));
    };
    let (r, _, _) = full[i].as_ref().expect("chosen among the refitted");
    let mut chosen = params[i].clone();
    chosen.extend(r.params.iter().cloned());
    let confirmed = Confirmed {
        after_scored_m: rms(e_sc, n_sc),
        after_all_m: rms(e_all, n_all),
        params: chosen,
        prediction: r.prediction.clone(),
        method,
        fold_rss_m2,
        fold_n,
        force: None,
    };
    Ok((Some(confirmed), scores))
}

/// Which candidates a selection may choose: `eligible(candidate, held-out fold)` (`None`: the
/// full-data choice). A candidate whose very existence was decided with the data of a fold (a
/// refined re-simulation of another fold's choice, `crate::hypotheses::anisotropy`) must not be
/// offered to that fold.
pub type EligibleFn<'a> = dyn Fn(usize, Option<usize>) -> bool + 'a;

/// What a leave-one-location-out selection scores candidates against: the recording, its
/// segmentation into folds (one per probe location) and the baseline's prepared data, the
/// nuisance compliance scale, which observations `scored(frame, marker)` counts (the hypothesis's
/// effect cells) and, with `train_on_scored`, that the training error counts only those too.
#[derive(Clone, Copy)]
pub struct Lolo<'a> {
    /// The recording (its markers are the observations).
    pub rec: &'a Recording,
    /// Its segmentation (the folds: one per probe location).
    pub seg: &'a Segmentation,
    /// The baseline's prepared data (the model's unloaded markers).
    pub p: &'a Prepared,
    /// The compliance scale's refit and bounds.
    pub scale: ComplianceScale,
    /// Which observations (frame, marker) are scored.
    pub scored: &'a dyn Fn(usize, usize) -> bool,
    /// Train on the scored observations only (else on every one).
    pub train_on_scored: bool,
}

/// Per (candidate, fold bucket) sums of the observations of a recording (module docs): `all`
/// over the training observations (every one, or with `train_on_scored` only the scored ones),
/// `sc` over the scored ones; bucket `num_folds` holds the frames of no fold (rest).
struct Tally {
    all: Vec<Vec<Sums>>,
    sc: Vec<Vec<Sums>>,
    /// Per candidate: its compliance scale is 1 ([`Candidate::position_controlled`]).
    unscaled: Vec<bool>,
}

impl Tally {
    fn new(cands: &[Candidate], lolo: &Lolo<'_>) -> Self {
        let Lolo {
            rec,
            seg,
            p,
            scored,
            train_on_scored,
            ..
        } = *lolo;
        let nf = seg.num_folds();
        let bucket = |k: usize| seg.fold_of_frame[k].unwrap_or(nf);
        let mut all = Vec::with_capacity(cands.len());
        let mut sc = Vec::with_capacity(cands.len());
        for c in cands {
            let mut sa = vec![Sums::default(); nf + 1];
            let mut ss = vec![Sums::default(); nf + 1];
            for (k, f) in rec.frames.iter().enumerate() {
                for (m, y) in f.markers_m.iter().enumerate() {
                    let Some(y) = y else { continue };
                    let u = c.prediction[k][m] - p.rest_model_m[m];
                    let v = y - p.rest_model_m[m];
                    let o = Sums {
                        a: u.norm_squared(),
                        b: u.dot(&v),
                        c: v.norm_squared(),
                        n: 1,
                    };
                    let is_scored = seg.fold_of_frame[k].is_some() && scored(k, m);
                    if !train_on_scored || is_scored {
                        sa[bucket(k)].add(&o);
                    }
                    if is_scored {
                        ss[bucket(k)].add(&o);
                    }
                }
            }
            all.push(sa);
            sc.push(ss);
        }
        let unscaled = cands.iter().map(|c| c.position_controlled).collect();
        Self { all, sc, unscaled }
    }

    /// The eligible candidates with their compliance scales ordered by training error without
    /// bucket `skip` (`None`: every bucket), least first, ties in candidate order: (candidate,
    /// scale, residual sum of squares).
    fn ranked(
        &self,
        skip: Option<usize>,
        scale: ComplianceScale,
        eligible: Option<&EligibleFn<'_>>,
    ) -> Vec<(usize, f64, f64)> {
        let mut ranked: Vec<(usize, f64, f64)> = (0..self.all.len())
            .filter(|&i| eligible.is_none_or(|e| e(i, skip)))
            .map(|i| {
                let mut t = Sums::default();
                for (b, x) in self.all[i].iter().enumerate() {
                    if Some(b) != skip {
                        t.add(x);
                    }
                }
                let d = if self.unscaled[i] {
                    1.0
                } else {
                    t.scale(scale)
                };
                (i, d, t.rss(d))
            })
            .collect();
        // stable: equal errors keep the candidate order (the first is the choice)
        ranked.sort_by(|a, b| a.2.total_cmp(&b.2));
        ranked
    }

    /// The eligible candidate and compliance scale with the least training error without bucket
    /// `skip` (`None`: every bucket): (candidate, scale, residual sum of squares).
    fn best(
        &self,
        skip: Option<usize>,
        scale: ComplianceScale,
        eligible: Option<&EligibleFn<'_>>,
    ) -> (usize, f64, f64) {
        self.ranked(skip, scale, eligible)
            .first()
            .copied()
            .unwrap_or((0, 1.0, f64::INFINITY))
    }

    /// [`Self::best`] per held-out location of the `nf` (index l of the result), then for the full
    /// data (nothing held out): (held-out location, candidate, scale, residual sum of squares).
    fn best_per_fold(
        &self,
        nf: usize,
        scale: ComplianceScale,
        eligible: Option<&EligibleFn<'_>>,
    ) -> Vec<(Option<usize>, usize, f64, f64)> {
        (0..nf)
            .map(Some)
            .chain([None])
            .map(|skip| {
                let (i, d, rss) = self.best(skip, scale, eligible);
                (skip, i, d, rss)
            })
            .collect()
    }
}

/// The candidate [`lolo_confirm`] chooses for each held-out location (index l of the result) and,
/// last, for the full data (nothing held out); empty without candidates.
pub fn lolo_choices(cands: &[Candidate], lolo: &Lolo<'_>) -> Vec<usize> {
    lolo_rankings(cands, lolo, 1, None)
        .into_iter()
        .filter_map(|ranking| ranking.first().copied())
        .collect()
}

/// The value of the parameter `name` of a candidate (`None`: it has no such parameter), the key
/// of its family in [`lolo_rankings`].
pub fn family_key(c: &Candidate, name: &str) -> Option<f64> {
    c.params.iter().find(|(k, _)| k == name).map(|&(_, v)| v)
}

/// Per held-out location (index l of the result) and, last, for the full data: the `n`
/// candidates with the least training error, least first (the first is [`lolo_choices`]'s
/// choice); empty without candidates. With `family` = Some(name), only the best candidate of
/// each value of the parameter `name` ([`family_key`]) is ranked: a biased error (the fit
/// mesh's contact error under a rigid-tip replay) that shifts all of one family's points
/// ahead of another's then still leaves one point per family to decide between.
pub fn lolo_rankings(
    cands: &[Candidate],
    lolo: &Lolo<'_>,
    n: usize,
    family: Option<&str>,
) -> Vec<Vec<usize>> {
    if cands.is_empty() {
        return Vec::new();
    }
    let t = Tally::new(cands, lolo);
    (0..lolo.seg.num_folds())
        .map(Some)
        .chain([None])
        .map(|skip| {
            let mut seen: Vec<Option<f64>> = Vec::new();
            t.ranked(skip, lolo.scale, None)
                .into_iter()
                .map(|(i, _, _)| i)
                .filter(|&i| match family {
                    None => true,
                    Some(name) => {
                        let key = family_key(&cands[i], name);
                        let first = !seen.contains(&key);
                        seen.push(key);
                        first
                    }
                })
                .take(n)
                .collect()
        })
        .collect()
}

/// [`lolo_choices`] with each selection restricted to the `eligible` candidates: per held-out
/// location, then the full data, the eligible candidate with the least training error (its
/// compliance scale fitted) and that error (RSS, m²); `None` where no candidate is eligible.
pub fn lolo_choices_among(
    cands: &[Candidate],
    eligible: &EligibleFn<'_>,
    lolo: &Lolo<'_>,
) -> Vec<Option<(usize, f64)>> {
    let t = Tally::new(cands, lolo);
    t.best_per_fold(lolo.seg.num_folds(), lolo.scale, Some(eligible))
        .into_iter()
        .map(|(_, i, _, rss)| rss.is_finite().then_some((i, rss)))
        .collect()
}

/// Leave-one-location-out over simulated candidates (module docs): per held-out location the
/// candidate and compliance scale with the least error on every other observation (with
/// `train_on_scored`: only the other locations' `scored` observations, and the held-out "all"
/// number is then over the scored ones too), scored on the held-out location's `scored(k, m)`
/// observations; with `refit`, the held-out (and the
/// full-data) prediction is the refit closure's instead of the scaled candidate (no compliance
/// scale is then reported: the refit replaces it). `Ok(None)` when there is no candidate or the
/// refit declines.
pub fn lolo_confirm(
    cands: &[Candidate],
    lolo: &Lolo<'_>,
    refit: Option<&RefitFn<'_>>,
    method: String,
) -> Result<Option<Confirmed>> {
    lolo_confirm_among(cands, None, lolo, refit, method)
}

/// [`lolo_confirm`] with each selection restricted to the `eligible` candidates.
pub fn lolo_confirm_among(
    cands: &[Candidate],
    eligible: Option<&EligibleFn<'_>>,
    lolo: &Lolo<'_>,
    refit: Option<&RefitFn<'_>>,
    method: String,
) -> Result<Option<Confirmed>> {
    use rayon::prelude::*;
    if cands.is_empty() {
        return Ok(None);
    }
    let Lolo {
        rec,
        seg,
        p,
        scale,
        scored,
        ..
    } = *lolo;
    let nf = seg.num_folds();
    let tally = Tally::new(cands, lolo);
    let (all, sc) = (&tally.all, &tally.sc);
    // per held-out location, then the full data: the chosen candidate and compliance scale
    let choices: Vec<(Option<usize>, usize, f64)> = tally
        .best_per_fold(nf, scale, eligible)
        .into_iter()
        .map(|(skip, i, d, _)| (skip, i, d))
        .collect();
    // With a refit closure, its independent refits run in parallel; taken in this order below
    // (the first error or declined refit decides, as one after another).
    let mut refits = refit.map(|refit| {
        choices
            .par_iter()
            .map(|&(skip, i, _)| refit(i, skip))
            .collect::<Vec<_>>()
            .into_iter()
    });
    let (mut e_sc, mut n_sc, mut e_all, mut n_all) = (0.0, 0usize, 0.0, 0usize);
    let (mut fold_rss_m2, mut fold_n) = (Vec::with_capacity(nf), Vec::with_capacity(nf));
    for &(skip, i, d) in &choices[..nf] {
        let l = skip.unwrap_or(nf);
        let (e_sc0, n_sc0) = (e_sc, n_sc);
        match refits.as_mut() {
            None => {
                e_sc += sc[i][l].rss(d);
                n_sc += sc[i][l].n;
                e_all += all[i][l].rss(d);
                n_all += all[i][l].n;
            }
            Some(refits) => {
                let Some(pred) = refits.next().unwrap_or(Ok(None))? else {
                    return Ok(None);
                };
                for (k, f) in rec.frames.iter().enumerate() {
                    if seg.fold_of_frame[k] != Some(l) {
                        continue;
                    }
                    for (m, y) in f.markers_m.iter().enumerate() {
                        let Some(y) = y else { continue };
                        let r = (y - pred[k][m]).norm_squared();
                        e_all += r;
                        n_all += 1;
                        if scored(k, m) {
                            e_sc += r;
                            n_sc += 1;
                        }
                    }
                }
            }
        }
        fold_rss_m2.push(e_sc - e_sc0);
        fold_n.push(n_sc - n_sc0);
    }
    let (_, i, d) = choices[nf];
    let (params, prediction) = match refits.as_mut() {
        None => {
            let mut params = cands[i].params.clone();
            params.push(("compliance_scale".into(), d));
            let prediction: Field = cands[i]
                .prediction
                .iter()
                .map(|row| {
                    row.iter()
                        .zip(&p.rest_model_m)
                        .map(|(x, r)| r + (x - r) * d)
                        .collect()
                })
                .collect();
            (params, prediction)
        }
        Some(refits) => {
            let Some(prediction) = refits.next().unwrap_or(Ok(None))? else {
                return Ok(None);
            };
            (cands[i].params.clone(), prediction)
        }
    };
    Ok(Some(Confirmed {
        after_scored_m: (e_sc / n_sc.max(1) as f64).sqrt(),
        after_all_m: (e_all / n_all.max(1) as f64).sqrt(),
        params,
        prediction,
        method,
        fold_rss_m2,
        fold_n,
        force: None,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::Frame;
    use crate::segment::SegmentSettings;
    use nalgebra::Vector3;

    /// Two probe locations (ramp / hold / release each), two markers; the measured displacement
    /// is exactly 2 × candidate 0's.
    fn toy() -> (Recording, Segmentation, Prepared, Vec<Candidate>) {
        let profile = [0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 0.5, 0.0, 0.0];
        let rest = vec![Vector3::new(0.0, 0.0, 0.01), Vector3::new(0.03, 0.0, 0.01)];
        let mut frames = Vec::new();
        let mut u_true = Vec::new();
        for (l, tip) in [Vector3::new(0.0, 0.0, 0.01), Vector3::new(0.03, 0.0, 0.01)]
            .into_iter()
            .enumerate()
        {
            for &s in &profile {
                let k = frames.len();
                // displacement of candidate 0: down at the probed marker, a little sideways at
                // the other one
                let u: Vec<Vector3<f64>> = (0..2)
                    .map(|m| {
                        if m == l {
                            Vector3::new(0.0, 0.0, -1e-3 * s)
                        } else {
                            Vector3::new(2e-4 * s, 0.0, -1e-4 * s)
                        }
                    })
                    .collect();
                frames.push(Frame {
                    frame: k as u64,
                    time_s: k as f64 * 0.1,
                    tip_m: tip - Vector3::z() * 0.002 * s,
                    axis: -Vector3::z(),
                    force_n: -Vector3::z() * 2.0 * s,
                    markers_m: (0..2).map(|m| Some(rest[m] + u[m] * 2.0)).collect(),
                });
                u_true.push(u);
            }
        }
        let rec = Recording::two_marker_toy(frames);
        assert_eq!(rec.rest_markers_m, rest);
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        let p = Prepared {
            times_s: rec.times_s(),
            force_n: rec.frames.iter().map(|f| f.force_n).collect(),
            baseline_m: vec![rest.clone(); rec.frames.len()],
            response: Vec::new(),
            rest_model_m: rest.clone(),
            gravity_field_m: vec![Vector3::zeros(); 2],
            friction_dir: Vec::new(),
            load_point: Vec::new(),
        };
        let field = |f: &dyn Fn(&Vector3<f64>) -> Vector3<f64>| -> Field {
            u_true
                .iter()
                .map(|row| row.iter().zip(&rest).map(|(u, r)| r + f(u)).collect())
                .collect()
        };
        let cands = vec![
            Candidate {
                params: vec![("a".into(), 1.0)],
                prediction: field(&|u| *u),
                position_controlled: false,
            },
            Candidate {
                params: vec![("a".into(), 2.0)],
                prediction: field(&|u| Vector3::new(-u.x, 0.0, u.z)),
                position_controlled: false,
            },
        ];
        (rec, seg, p, cands)
    }

    /// [`lolo_confirm`] of the toy with every observation scored and the compliance scale fitted.
    fn confirm_all_scored(
        cands: &[Candidate],
        rec: &Recording,
        seg: &Segmentation,
        p: &Prepared,
    ) -> Confirmed {
        let lolo = Lolo {
            rec,
            seg,
            p,
            scale: ComplianceScale::new(true, 0.1, 10.0),
            scored: &|_, _| true,
            train_on_scored: false,
        };
        lolo_confirm(cands, &lolo, None, "toy".into())
            .unwrap()
            .unwrap()
    }

    #[test]
    fn picks_the_right_candidate_and_compliance_scale() {
        let (rec, seg, p, cands) = toy();
        assert_eq!(seg.num_folds(), 2);
        let c = confirm_all_scored(&cands, &rec, &seg, &p);
        // candidate 0 scaled by d = 2 reproduces the data exactly
        assert!(c.after_scored_m < 1e-12, "{}", c.after_scored_m);
        assert!(c.after_all_m < 1e-12);
        assert_eq!(c.params[0], ("a".to_string(), 1.0));
        assert_eq!(c.params[1].0, "compliance_scale");
        assert!((c.params[1].1 - 2.0).abs() < 1e-12);
        for (k, f) in rec.frames.iter().enumerate() {
            for m in 0..2 {
                assert!((c.prediction[k][m] - f.markers_m[m].unwrap()).norm() < 1e-15);
            }
        }
    }

    /// A position-controlled candidate keeps d = 1: the toy data are candidate 0's displacement
    /// × 2, which the force-driven candidate 0 reproduces exactly with d = 2; marked as a rigid-tip
    /// replay it is scored unscaled (held-out RMS = the RMS of u, not 0) and reports d = 1.
    #[test]
    fn a_position_controlled_candidate_is_not_scaled() {
        let (rec, seg, p, mut cands) = toy();
        cands.truncate(1);
        cands[0].position_controlled = true;
        let c = confirm_all_scored(&cands, &rec, &seg, &p);
        assert_eq!(c.params[1], ("compliance_scale".to_string(), 1.0));
        // data = rest + 2u, prediction = rest + u: the residual is u on every observation
        let (mut e, mut n) = (0.0, 0usize);
        for (k, f) in rec.frames.iter().enumerate() {
            if seg.fold_of_frame[k].is_none() {
                continue;
            }
            for m in 0..2 {
                e += (f.markers_m[m].unwrap() - cands[0].prediction[k][m]).norm_squared();
                n += 1;
            }
        }
        let want = (e / n as f64).sqrt();
        assert!(want > 1e-4, "{want}");
        assert!(
            (c.after_all_m - want).abs() < 1e-12 * want.max(1.0),
            "{} vs {want}",
            c.after_all_m
        );
    }

    /// `lolo_choices` names the per-fold and full-data choice, and an eligibility restriction
    /// that withholds the exact candidate from fold 0 only makes fold 0 (and nothing else) fall
    /// back to the other one.
    #[test]
    fn choices_and_eligibility_restrict_each_fold() {
        let (rec, seg, p, cands) = toy();
        let lolo = Lolo {
            rec: &rec,
            seg: &seg,
            p: &p,
            scale: ComplianceScale::new(true, 0.1, 10.0),
            scored: &|_, _| true,
            train_on_scored: false,
        };
        let choices = lolo_choices(&cands, &lolo);
        assert_eq!(choices, vec![0, 0, 0]);
        let run = |eligible: Option<&EligibleFn<'_>>| {
            lolo_confirm_among(&cands, eligible, &lolo, None, "toy".into())
                .unwrap()
                .unwrap()
        };
        let all = run(None);
        assert!(all.after_scored_m < 1e-12);
        let not_in_fold_0 = |i: usize, fold: Option<usize>| !(i == 0 && fold == Some(0));
        let restricted = run(Some(&not_in_fold_0));
        assert!(
            restricted.after_scored_m > 1e-6,
            "{}",
            restricted.after_scored_m
        );
        // The full-data choice is still the exact candidate.
        assert_eq!(restricted.params[0], ("a".to_string(), 1.0));
    }

    #[test]
    fn clamped_scale_leaves_the_analytic_remainder() {
        // d clamped at 1.5: the held-out residual is 0.5 u on every observation, so the held-out
        // RMS is 0.5 × RMS(u) over the location frames.
        let (rec, seg, p, cands) = toy();
        let lolo = Lolo {
            rec: &rec,
            seg: &seg,
            p: &p,
            scale: ComplianceScale::new(true, 0.1, 1.5),
            scored: &|_, _| true,
            train_on_scored: false,
        };
        let c = lolo_confirm(&cands, &lolo, None, "toy".into())
            .unwrap()
            .unwrap();
        let (mut e, mut n) = (0.0, 0);
        for (k, f) in rec.frames.iter().enumerate() {
            if seg.fold_of_frame[k].is_some() {
                for m in 0..2 {
                    let u = f.markers_m[m].unwrap() - p.rest_model_m[m];
                    e += (0.25 * u).norm_squared();
                    n += 1;
                }
            }
        }
        let want = (e / n as f64).sqrt();
        assert!((c.after_all_m - want).abs() < 1e-12 * want.max(1e-9) + 1e-18);
        assert!((c.params[1].1 - 1.5).abs() < 1e-12);
    }

    /// Every candidate refitted on the full data, only the chosen one per training set: a refit of
    /// candidate 0 reproduces the data (rest + 2u), candidate 1's has the wrong shape; each
    /// location's selection takes candidate 0 by its full-data training error and refits only it,
    /// from its full-data refit (2 + 2 refits, not 2 × 3); a refit of candidate 0 that declines
    /// for location 0 passes that location to candidate 1 (held-out error there, none elsewhere),
    /// while the full data still chooses candidate 0 with its refitted parameters.
    #[test]
    fn each_candidate_refitted_per_training_set() {
        let (rec, seg, p, cands) = toy();
        let names: Vec<Vec<(String, f64)>> = cands.iter().map(|c| c.params.clone()).collect();
        let twice = |i: usize| -> Field {
            cands[i]
                .prediction
                .iter()
                .map(|row| {
                    row.iter()
                        .zip(&p.rest_model_m)
                        .map(|(x, r)| r + (x - r) * 2.0)
                        .collect()
                })
                .collect()
        };
        let calls = std::sync::Mutex::new(Vec::new());
        let log = &calls;
        let refit = |decline: Option<usize>| {
            move |i: usize,
                  skip: Option<usize>,
                  from: Option<&Refitted>|
                  -> Result<Option<Refitted>> {
                // a held-out refit starts from the same candidate's full-data refit
                assert_eq!(skip.is_some(), from.is_some());
                let start = from.map(|f| f.params[0].1);
                log.lock().unwrap().push((i, skip, start));
                if i == 0 && skip.is_some() && skip == decline {
                    return Ok(None);
                }
                Ok(Some(Refitted {
                    prediction: twice(i),
                    params: vec![("scale".into(), start.unwrap_or(2.0 + i as f64))],
                }))
            }
        };
        let scored = |_: usize, _: usize| true;
        let none = |_: usize| -> Vec<usize> { Vec::new() };
        let run_from = |first: &[usize], neighbours: &dyn Fn(usize) -> Vec<usize>, decline| {
            lolo_confirm_each_refitted(
                &names,
                &rec,
                &seg,
                &scored,
                false,
                first,
                neighbours,
                &refit(decline),
                "toy".into(),
            )
            .unwrap()
        };
        let run = |decline| run_from(&[0, 1], &none, decline);
        // a first pass of candidate 1 alone: its neighbour 0 is refitted (1 is every selection's
        // least error so far), then chosen everywhere; with no neighbours 1 alone is chosen
        let other = |i: usize| vec![1 - i];
        let (c, _) = run_from(&[1], &other, None);
        assert!(c.unwrap().after_scored_m < 1e-12);
        let (c, scores) = run_from(&[1], &none, None);
        assert!(c.unwrap().after_scored_m > 1e-5);
        assert!(scores[0].in_sample_m.is_nan());
        calls.lock().unwrap().clear();
        let (c, scores) = run(None);
        let c = c.unwrap();
        assert!(c.after_scored_m < 1e-12, "{}", c.after_scored_m);
        assert_eq!(
            c.params,
            vec![("a".to_string(), 1.0), ("scale".to_string(), 2.0)]
        );
        // two candidates on the full data, then candidate 0 alone per location, from its full fit
        let mut calls_made = std::mem::take(&mut *calls.lock().unwrap());
        calls_made.sort_by_key(|a| (a.0, a.1));
        assert_eq!(
            calls_made,
            vec![
                (0, None, None),
                (0, Some(0), Some(2.0)),
                (0, Some(1), Some(2.0)),
                (1, None, None)
            ]
        );
        assert!(scores[0].heldout_m < 1e-12 && scores[0].in_sample_m < 1e-12);
        assert_eq!(scores[0].chosen_for, vec![0, 1]);
        assert!(scores[1].in_sample_m > 1e-5, "{}", scores[1].in_sample_m);
        assert!(scores[1].heldout_m.is_nan() && scores[1].chosen_for.is_empty());
        let (c, scores) = run(Some(0));
        let c = c.unwrap();
        assert!(c.fold_rss_m2[0] > 1e-12, "{:?}", c.fold_rss_m2);
        assert!(c.fold_rss_m2[1] < 1e-20, "{:?}", c.fold_rss_m2);
        assert_eq!(c.params[1], ("scale".to_string(), 2.0));
        assert_eq!(scores[0].chosen_for, vec![1]);
        assert_eq!(scores[1].chosen_for, vec![0]);
        assert!(scores[1].heldout_m > 1e-5, "{}", scores[1].heldout_m);
    }

    #[test]
    fn refit_closure_replaces_the_scaled_candidate() {
        let (rec, seg, p, cands) = toy();
        let measured: Field = rec
            .frames
            .iter()
            .map(|f| f.markers_m.iter().map(|y| y.unwrap()).collect())
            .collect();
        let calls = std::sync::Mutex::new(Vec::new());
        let refit = |i: usize, skip: Option<usize>| -> Result<Option<Field>> {
            calls.lock().unwrap().push((i, skip));
            // a refit that is off by 0.1 mm along x everywhere
            Ok(Some(
                measured
                    .iter()
                    .map(|row| row.iter().map(|y| y + Vector3::x() * 1e-4).collect())
                    .collect(),
            ))
        };
        let lolo = Lolo {
            rec: &rec,
            seg: &seg,
            p: &p,
            scale: ComplianceScale::new(true, 0.1, 10.0),
            scored: &|_, m| m == 0,
            train_on_scored: false,
        };
        let c = lolo_confirm(&cands, &lolo, Some(&refit), "toy".into())
            .unwrap()
            .unwrap();
        // one refit per held-out location and one on the full data (run in parallel)
        let mut calls = calls.into_inner().unwrap();
        calls.sort_unstable();
        assert_eq!(calls, vec![(0, None), (0, Some(0)), (0, Some(1))]);
        assert!((c.after_scored_m - 1e-4).abs() < 1e-15);
        assert!((c.after_all_m - 1e-4).abs() < 1e-15);
        assert_eq!(
            c.params,
            vec![("a".to_string(), 1.0)],
            "no compliance scale with a refit"
        );
        // a refit that declines gives no confirmation
        let no = |_: usize, _: Option<usize>| -> Result<Option<Field>> { Ok(None) };
        assert!(
            lolo_confirm(&cands, &lolo, Some(&no), String::new())
                .unwrap()
                .is_none()
        );
    }
}
