//! The re-simulation harness: a recording turned into load sequences, grids of extended models
//! simulated over the whole recording in time order (force-driven under the measured force over
//! the contact patch, or as rigid-tip replays at the measured poses), and the candidates they give
//! the leave-one-location-out confirmation ([`crate::confirm`]).
//!
//! The grid points are independent sequences: [`simulate_grid`] and [`simulate_rigid_grid`] hand
//! them to the simulator as one batch (`ProbeSimulator::simulate_sequences`,
//! `ProbeSimulator::simulate_sequences_rigid_tip`: in parallel in `FemProbeSimulator`), and
//! [`Replays::run`] runs the rigid-tip replays on the refined copy beside the force-driven grid
//! (`rayon::join`). The results are taken in grid order with the serial loop's first-error rule,
//! so every choice is the one-after-another one bit for bit.

use crate::baseline::Prepared;
use crate::cells::touched_balls;
use crate::confirm::{
    Candidate, ComplianceScale, Confirmed, Lolo, family_key, lolo_confirm_among, lolo_rankings,
};
use crate::recording::Recording;
use crate::segment::Segmentation;
use crate::sim::{
    Extension, Field, ProbeLoad, ProbeSimulator, SequenceFrame, SequenceJob, SimLoad,
};
use crate::{DiagnoseError, Result};
use nalgebra::Vector3;

/// A grid point of a force-driven confirmation: named parameters, the extension, the per-frame
/// probe forces.
pub type GridPoint = (Vec<(String, f64)>, Extension, Vec<Vector3<f64>>);

/// A grid point of a rigid-tip replay: named parameters, the extension.
pub type RigidPoint = (Vec<(String, f64)>, Extension);

/// The recording as a rigid-tip replay's input: every frame carries its measured probe pose (and
/// force, which a position-controlled replay does not use).
pub fn pose_sequence(rec: &Recording) -> Vec<SequenceFrame> {
    rec.frames
        .iter()
        .map(|f| SequenceFrame {
            time_s: f.time_s,
            load: SimLoad {
                probe: Some(ProbeLoad {
                    tip_m: f.tip_m,
                    axis: f.axis,
                    force_n: f.force_n,
                }),
                body_force_n_m3: Vector3::zeros(),
            },
        })
        .collect()
}

/// The recording as a sequence to re-simulate under per-frame probe forces `forces`: a contact
/// frame (segmentation) with a non-zero force carries the probe load at its tip and axis, every
/// other frame is unloaded.
pub fn contact_sequence(
    rec: &Recording,
    seg: &Segmentation,
    forces: &[Vector3<f64>],
) -> Vec<SequenceFrame> {
    rec.frames
        .iter()
        .enumerate()
        .map(|(k, f)| SequenceFrame {
            time_s: f.time_s,
            load: SimLoad {
                probe: (seg.phases[k].in_contact() && forces[k].norm() > 1e-9).then_some(
                    ProbeLoad {
                        tip_m: f.tip_m,
                        axis: f.axis,
                        force_n: forces[k],
                    },
                ),
                body_force_n_m3: Vector3::zeros(),
            },
        })
        .collect()
}

/// Simulates every grid point (skipping those that do not reach equilibrium); returns the
/// candidates, the grid size and, aligned with the candidates, the grid point each came from. With
/// `contact_only` (extensions without history), only the contact frames are solved and every
/// other frame is the unloaded model.
pub fn simulate_grid(
    sim: &mut dyn ProbeSimulator,
    grid: Vec<GridPoint>,
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    contact_only: bool,
) -> Result<(Vec<Candidate>, usize, Vec<GridPoint>)> {
    let total = grid.len();
    let mut out = Vec::with_capacity(total);
    let mut sources = Vec::with_capacity(total);
    let solved: Vec<usize> = (0..rec.frames.len())
        .filter(|&k| !contact_only || seg.phases[k].in_contact())
        .collect();
    let jobs: Vec<SequenceJob> = grid
        .iter()
        .map(|(_, ext, forces)| {
            let all = contact_sequence(rec, seg, forces);
            (*ext, solved.iter().map(|&k| all[k]).collect())
        })
        .collect();
    // independent sequences, simulated in parallel by the simulator; taken in grid order
    for (point, result) in grid.into_iter().zip(sim.simulate_sequences(&jobs)) {
        match result {
            Ok(x) => {
                let mut prediction = vec![p.rest_model_m.clone(); rec.frames.len()];
                for (row, &k) in x.into_iter().zip(&solved) {
                    prediction[k] = row;
                }
                out.push(Candidate {
                    params: point.0.clone(),
                    prediction,
                    position_controlled: false,
                });
                sources.push(point);
            }
            Err(DiagnoseError::Simulation { .. }) => continue,
            Err(e) => return Err(e),
        }
    }
    Ok((out, total, sources))
}

/// Simulates every grid point with the rigid-tip replay
/// ([`ProbeSimulator::simulate_sequence_rigid_tip`]: the probe at every frame's measured pose),
/// skipping those that do not reach equilibrium; nothing when the simulator has no rigid tip.
pub fn simulate_rigid_grid(
    sim: &mut dyn ProbeSimulator,
    grid: Vec<RigidPoint>,
    rec: &Recording,
) -> Result<(Vec<Candidate>, usize)> {
    let frames = pose_sequence(rec);
    let exts: Vec<Extension> = grid.iter().map(|(_, e)| *e).collect();
    let mut out = Vec::with_capacity(grid.len());
    let mut total = 0;
    // independent replays, simulated in parallel by the simulator; taken in grid order
    for ((params, _), result) in grid
        .into_iter()
        .zip(sim.simulate_sequences_rigid_tip(&exts, &frames))
    {
        match result {
            Ok(Some(prediction)) => {
                total += 1;
                out.push(Candidate {
                    params,
                    prediction,
                    position_controlled: true,
                });
            }
            Ok(None) => break,
            Err(DiagnoseError::Simulation { .. }) => total += 1,
            Err(e) => return Err(e),
        }
    }
    Ok((out, total))
}

/// The candidates of grid sequences simulated in one batch, taken in grid order: each point's
/// parameters and sequence with its result; points that do not reach equilibrium are skipped,
/// any other error is returned (the first in grid order). Returns the candidates and, aligned
/// with them, their sequences.
pub fn sequence_candidates(
    points: Vec<(Vec<(String, f64)>, Vec<SequenceFrame>)>,
    results: Vec<Result<Field>>,
) -> Result<(Vec<Candidate>, Vec<Vec<SequenceFrame>>)> {
    let mut cands = Vec::with_capacity(points.len());
    let mut frames = Vec::with_capacity(points.len());
    for ((params, seq), result) in points.into_iter().zip(results) {
        match result {
            Ok(prediction) => {
                cands.push(Candidate {
                    params,
                    prediction,
                    position_controlled: false,
                });
                frames.push(seq);
            }
            Err(DiagnoseError::Simulation { .. }) => continue,
            Err(e) => return Err(e),
        }
    }
    Ok((cands, frames))
}

/// A force-driven grid and a rigid-tip replay grid of one hypothesis, simulated
/// ([`Replays::run`]), then confirmed together leave-one-location-out ([`Replays::confirm`]).
/// Candidates in order: the force-driven grid on the fit mesh, its points re-simulated on a refined
/// mesh ([`Replays::add_refined`]), the rigid-tip replays.
pub struct Replays {
    /// Converged force-driven candidates on the fit mesh.
    pub forced: Vec<Candidate>,
    /// The grid point of each force-driven candidate.
    pub sources: Vec<GridPoint>,
    /// Converged force-driven candidates on a refined mesh.
    pub refined: Vec<Candidate>,
    /// The force-driven candidate (index into `forced`) each refined one refines.
    pub refined_from: Vec<usize>,
    /// Per fold (then the full data): the force-driven candidates whose refinements it may choose.
    pub neighbourhoods: Vec<Vec<usize>>,
    /// Converged rigid-tip replays.
    pub rigid: Vec<Candidate>,
    /// Rigid-tip replays of some of `rigid`'s points re-run on the refined mesh or the 10-node
    /// tets ([`Replays::run_coarse_first`]; empty otherwise).
    pub rigid_fine: Vec<Candidate>,
    /// The rigid candidate (index into `rigid`) each of `rigid_fine` refines.
    pub rigid_fine_from: Vec<usize>,
    /// Per fold (then the full data): the rigid candidates whose refinements it may choose.
    pub rigid_neighbourhoods: Vec<Vec<usize>>,
    /// Grid points attempted.
    pub total: usize,
    /// The refined (or 10-node) copy the rigid-tip replays ran on (`None`: they ran on the fit
    /// mesh).
    pub replay_mesh: Option<Box<dyn ProbeSimulator>>,
}

impl Replays {
    /// Simulates the force-driven `grid` on the fit mesh (with `contact_only`, only the contact
    /// frames, for extensions without history) and the rigid-tip replays `rigid` on a copy of the
    /// fit mesh refined around the touched locations (`ProbeSimulator::refined`) when the
    /// simulator has one — side by side — else on the fit mesh. Every rigid point gets the
    /// parameter `refined_mesh` (1 or 0).
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        sim: &mut dyn ProbeSimulator,
        grid: Vec<GridPoint>,
        mut rigid: Vec<RigidPoint>,
        rec: &Recording,
        seg: &Segmentation,
        p: &Prepared,
        contact_only: bool,
    ) -> Result<Self> {
        // The rigid-tip replay on the refined mesh when the simulator has one; it does not depend
        // on the force-driven grid, so the two run side by side on a refined copy.
        let mut fine = if rigid.is_empty() {
            Ok(None)
        } else {
            sim.refined(&touched_balls(rec, seg))
        };
        let refined = matches!(fine, Ok(Some(_)));
        for (params, _) in &mut rigid {
            params.push(("refined_mesh".into(), if refined { 1.0 } else { 0.0 }));
        }
        let (coarse, rigid_side) = match fine.as_mut() {
            Ok(Some(f)) => {
                let replay = f.as_mut();
                let rigid = std::mem::take(&mut rigid);
                let (coarse, side) = rayon::join(
                    || simulate_grid(sim, grid, rec, seg, p, contact_only),
                    || simulate_rigid_grid(replay, rigid, rec),
                );
                (coarse, Some(side))
            }
            _ => (simulate_grid(sim, grid, rec, seg, p, contact_only), None),
        };
        // errors in the serial order: the force-driven grid's, the refinement's, the replays'
        let (forced, total, sources) = coarse?;
        let mut fine = fine?;
        let (rigid_cands, rigid_total) = match rigid_side {
            Some(side) => side?,
            None => {
                let replay: &mut dyn ProbeSimulator = match fine.as_deref_mut() {
                    Some(f) => f,
                    None => sim,
                };
                simulate_rigid_grid(replay, rigid, rec)?
            }
        };
        Ok(Self::unrefined(
            (forced, sources),
            rigid_cands,
            total + rigid_total,
            fine,
        ))
    }

    /// The simulated grids before any refined re-simulation: `forced` with its grid points, the
    /// rigid-tip replays, the points attempted and the mesh the replays ran on.
    fn unrefined(
        (forced, sources): (Vec<Candidate>, Vec<GridPoint>),
        rigid: Vec<Candidate>,
        total: usize,
        replay_mesh: Option<Box<dyn ProbeSimulator>>,
    ) -> Self {
        Self {
            forced,
            sources,
            refined: Vec::new(),
            refined_from: Vec::new(),
            neighbourhoods: Vec::new(),
            rigid,
            rigid_fine: Vec::new(),
            rigid_fine_from: Vec::new(),
            rigid_neighbourhoods: Vec::new(),
            total,
            replay_mesh,
        }
    }

    /// As [`Replays::run`], but the rigid-tip replays are ranked on a cheaper mesh first: every
    /// point of `rigid` is replayed on the ranking mesh (`refined_mesh` = 0) — the fit mesh, or
    /// with `rank_tet_factor` = r > 1 its copy bisected to r × its tets
    /// ([`ProbeSimulator::bisected`]) — each fold (and the full data) ranks them by its training
    /// error ([`lolo_rankings`]) and keeps its `refine_at_most` best, and the points kept most
    /// often — at most `refine_at_most` — are replayed again on the refined copy (`refined_mesh`
    /// = 1, 1 → 8) or, with `quadratic`, on the 10-node tets of the fit mesh
    /// ([`ProbeSimulator::quadratic`]; `quadratic_mesh` = 1 in place of `refined_mesh`), where the
    /// fold decides between them. The ranking is the element's: a rigid
    /// tip's contact error on the fit mesh's linear tets reorders close points (own-rig
    /// plasticity, 648 tets: the 1 → 8 winner ranks 6th of 8 in every fold), while the fit mesh
    /// bisected once (1 → 2, 1,296 tets, ≈ 2× a fit-mesh replay's cost against ≈ 15× for
    /// 1 → 8) ranks it first in every fold, its top 4 in the 1 → 8 order. With `family` =
    /// Some(name), each fold keeps its best point within each value of that parameter, and the
    /// points refined are first each family's most kept. A refined replay is offered only to the
    /// folds that kept its point on the ranking mesh (that ranking was made without the fold's
    /// data); the ranking-mesh replays stay candidates of every fold. Without a refined copy, the
    /// ranking-mesh replays are the rigid candidates, as in [`Replays::run`].
    #[allow(clippy::too_many_arguments)]
    pub fn run_coarse_first(
        sim: &mut dyn ProbeSimulator,
        grid: Vec<GridPoint>,
        mut rigid: Vec<RigidPoint>,
        rec: &Recording,
        seg: &Segmentation,
        p: &Prepared,
        contact_only: bool,
        scored: &dyn Fn(usize, usize) -> bool,
        train_on_scored: bool,
        refine_at_most: usize,
        family: Option<&str>,
        rank_tet_factor: usize,
        quadratic: bool,
    ) -> Result<Self> {
        let points = rigid.clone();
        for (params, _) in &mut rigid {
            params.push(("refined_mesh".into(), 0.0));
        }
        let (forced, total, sources) = simulate_grid(sim, grid, rec, seg, p, contact_only)?;
        // the ranking mesh: the fit mesh, or (rank_tet_factor > 1) its bisected copy
        let (coarse, coarse_total) = match sim.bisected(rank_tet_factor)? {
            Some(mut ranking) => simulate_rigid_grid(ranking.as_mut(), rigid, rec)?,
            None => simulate_rigid_grid(sim, rigid, rec)?,
        };
        let mut replays = Self::unrefined((forced, sources), coarse, total + coarse_total, None);
        if replays.rigid.is_empty() || refine_at_most == 0 {
            return Ok(replays);
        }
        let ranking = Lolo {
            rec,
            seg,
            p,
            scale: ComplianceScale::new(false, 1.0, 1.0),
            scored,
            train_on_scored,
        };
        let kept = lolo_rankings(&replays.rigid, &ranking, refine_at_most, family);
        let flat: Vec<usize> = kept.iter().flatten().copied().collect();
        let keys: Vec<Option<f64>> = replays
            .rigid
            .iter()
            .map(|c| family.and_then(|name| family_key(c, name)))
            .collect();
        let chosen = most_chosen(&flat, &keys, refine_at_most);
        if crate::profile::enabled() {
            let params: Vec<&[(String, f64)]> =
                replays.rigid.iter().map(|c| &c.params[..]).collect();
            crate::profile::ranking(rank_tet_factor, &params, &kept, &chosen);
        }
        let fine = if quadratic {
            sim.quadratic()?
        } else {
            sim.refined(&touched_balls(rec, seg))?
        };
        let Some(mut fine) = fine else {
            return Ok(replays);
        };
        let mesh_param = if quadratic {
            "quadratic_mesh"
        } else {
            "refined_mesh"
        };
        // the chosen points (their parameters without the coarse `refined_mesh` entry)
        let grid: Vec<RigidPoint> = chosen
            .iter()
            .map(|&i| {
                let params = &replays.rigid[i].params;
                let (mut params, ext) = points
                    .iter()
                    .find(|(q, _)| q[..] == params[..params.len() - 1])
                    .cloned()
                    .ok_or_else(|| DiagnoseError::BadRecording {
                        what: "coarse-first replay: a candidate without its grid point".into(),
                    })?;
                params.push((mesh_param.into(), 1.0));
                Ok((params, ext))
            })
            .collect::<Result<_>>()?;
        // which chosen point each converged refined replay refines (the grid points are unique)
        let (fine_cands, fine_total) = simulate_rigid_grid(fine.as_mut(), grid, rec)?;
        for c in &fine_cands {
            let name = &c.params[..c.params.len() - 1];
            if let Some(&i) = chosen
                .iter()
                .find(|&&i| replays.rigid[i].params[..replays.rigid[i].params.len() - 1] == *name)
            {
                replays.rigid_fine_from.push(i);
            }
        }
        replays.total += fine_total;
        replays.rigid_fine = fine_cands;
        replays.rigid_neighbourhoods = kept;
        replays.replay_mesh = Some(fine);
        Ok(replays)
    }

    /// Re-simulates the force-driven grid points `chosen` (indices into `sources`) on `fine` (a
    /// refined copy of the fit mesh), each with the parameter `refined_mesh` = 1; a refined
    /// candidate is offered only to the folds (index `num_folds`: the full data) whose
    /// `neighbourhoods` entry holds the point it refines.
    #[allow(clippy::too_many_arguments)]
    pub fn add_refined(
        &mut self,
        fine: &mut dyn ProbeSimulator,
        chosen: &[usize],
        neighbourhoods: Vec<Vec<usize>>,
        rec: &Recording,
        seg: &Segmentation,
        p: &Prepared,
        contact_only: bool,
    ) -> Result<()> {
        let grid: Vec<GridPoint> = chosen
            .iter()
            .map(|&i| {
                let (mut params, ext, forces) = self.sources[i].clone();
                params.push(("refined_mesh".into(), 1.0));
                (params, ext, forces)
            })
            .collect();
        let (fine_cands, fine_total, fine_sources) =
            simulate_grid(fine, grid, rec, seg, p, contact_only)?;
        // Which coarse candidate each converged refined one refines (the grid points are unique).
        for (params, _, _) in &fine_sources {
            let name = &params[..params.len() - 1];
            if let Some(&i) = chosen.iter().find(|&&i| self.sources[i].0 == name) {
                self.refined_from.push(i);
            }
        }
        self.total += fine_total;
        self.refined.extend(fine_cands);
        self.neighbourhoods = neighbourhoods;
        Ok(())
    }

    /// Leave-one-location-out over every candidate ([`crate::confirm::lolo_confirm_among`]), a
    /// refined candidate offered only to the folds whose neighbourhood holds the point it
    /// refines: which grid points get refined was decided with the other folds' data, which
    /// include this fold's. `what` names the extended model in the method, `cells` the scored
    /// cells.
    pub fn confirm(self, lolo: &Lolo<'_>, what: &str, cells: &str) -> Result<Option<Confirmed>> {
        let n_coarse = self.forced.len();
        // the refined rigid replays come after every other candidate
        let n_before_fine = n_coarse + self.refined.len() + self.rigid.len();
        let nf = lolo.seg.num_folds();
        let (refined_from, neighbourhoods) = (&self.refined_from, &self.neighbourhoods);
        let (rigid_fine_from, rigid_neighbourhoods) =
            (&self.rigid_fine_from, &self.rigid_neighbourhoods);
        let offered = |nbs: &[Vec<usize>], from: usize, fold: Option<usize>| {
            nbs.get(fold.unwrap_or(nf))
                .is_some_and(|nb| nb.contains(&from))
        };
        let eligible = |i: usize, fold: Option<usize>| {
            if let Some(j) = i.checked_sub(n_before_fine) {
                return rigid_fine_from
                    .get(j)
                    .is_some_and(|&from| offered(rigid_neighbourhoods, from, fold));
            }
            match i.checked_sub(n_coarse) {
                Some(j) if j < refined_from.len() => offered(neighbourhoods, refined_from[j], fold),
                _ => true,
            }
        };
        let total = self.total;
        let cands: Vec<Candidate> = self
            .forced
            .into_iter()
            .chain(self.refined)
            .chain(self.rigid)
            .chain(self.rigid_fine)
            .collect();
        let n = cands.len();
        lolo_confirm_among(
            &cands,
            Some(&eligible),
            lolo,
            None,
            format!(
                "re-simulated {what} ({n} of {total} grid points converged), leave-one-location-out on {cells}"
            ),
        )
    }
}

/// The candidates named most often in `choices` (per fold, then the full data), at most `n`:
/// by how many choices name them, ties in the order they are first named.
fn most_chosen(choices: &[usize], family: &[Option<f64>], n: usize) -> Vec<usize> {
    let mut counts: Vec<(usize, usize)> = Vec::new();
    for &c in choices {
        match counts.iter_mut().find(|(i, _)| *i == c) {
            Some((_, k)) => *k += 1,
            None => counts.push((c, 1)),
        }
    }
    // stable: ties keep their first-named order
    counts.sort_by_key(|c| std::cmp::Reverse(c.1));
    let key = |i: usize| family.get(i).copied().flatten();
    // each family's most chosen first (in count order), then the rest by count
    let mut seen: Vec<Option<f64>> = Vec::new();
    let mut chosen: Vec<usize> = Vec::new();
    for &(i, _) in &counts {
        if !seen.contains(&key(i)) {
            seen.push(key(i));
            chosen.push(i);
        }
    }
    chosen.truncate(n);
    for &(i, _) in &counts {
        if chosen.len() >= n {
            break;
        }
        if !chosen.contains(&i) {
            chosen.push(i);
        }
    }
    chosen
}

#[cfg(test)]
mod tests {
    use super::most_chosen;

    #[test]
    fn most_chosen_counts_then_first_named() {
        assert_eq!(most_chosen(&[3, 1, 1, 3, 2, 1, 5], &[], 2), vec![1, 3]);
        assert_eq!(most_chosen(&[4, 2, 2, 4], &[], 1), vec![4]);
        assert_eq!(most_chosen(&[0, 7, 9], &[], 5), vec![0, 7, 9]);
        assert!(most_chosen(&[], &[], 2).is_empty());
    }

    #[test]
    fn most_chosen_takes_each_family_first() {
        // 0, 1: family None; 2, 3: family 0.45
        let family = [None, None, Some(0.45), Some(0.45)];
        // by count alone 2 and 3 (both 0.45); one per family: 2, then 0
        assert_eq!(most_chosen(&[2, 3, 2, 3, 0, 2], &family, 2), vec![2, 0]);
        assert_eq!(most_chosen(&[2, 3, 2, 3, 0, 2], &family, 3), vec![2, 0, 3]);
        assert_eq!(most_chosen(&[2, 3, 2, 3, 0, 2], &family, 1), vec![2]);
    }
}
