//! What the two force-channel hypotheses (sensor-lag, clock-offset) share: their extended model is
//! the default model under corrected forces AND the material refitted to them — the tissue fit
//! saw the distorted forces, so its material is biased by the same effect.

use crate::baseline::Prepared;
use crate::confirm::{ComplianceScale, Confirmed, Lolo, lolo_confirm};
use crate::indentation::{ForceCandidate, ForceObservations};
use crate::recording::Recording;
use crate::resim::sequence_candidates;
use crate::segment::Segmentation;
use crate::sim::{
    Extension, Field, MaterialRefitOutcome, ProbeLoad, ProbeSimulator, SequenceFrame, SequenceJob,
    SimLoad,
};
use crate::{DiagnoseError, Result};
use nalgebra::Vector3;
use softcap_probing::{ObservedMarker, ProbeExample};

/// A force-channel model that replaces the reading by a corrected force (`crate::indentation`):
/// y ≈ a (f_corr · axis) + o / c, the nuisance's columns with the corrected axial force in place
/// of the reading, named by `params`.
pub(super) fn corrected_force_candidate(
    obs: &ForceObservations,
    params: Vec<(String, f64)>,
    forces: &[Vector3<f64>],
    rec: &Recording,
) -> ForceCandidate {
    let mut cols = obs.nuisance();
    cols[0].values = forces
        .iter()
        .zip(&rec.frames)
        .map(|(f, fr)| f.dot(&fr.axis))
        .collect();
    (params, cols)
}

/// The sequence to simulate under per-frame probe forces `forces`: a frame carries a probe load
/// when its force exceeds `threshold_n` (shifted / de-lagged forces may move load into frames the
/// measured force called out of contact), at that frame's tip and axis.
pub(super) fn frames_with_forces(
    rec: &Recording,
    forces: &[Vector3<f64>],
    threshold_n: f64,
) -> Vec<SequenceFrame> {
    rec.frames
        .iter()
        .zip(forces)
        .map(|(f, fe)| SequenceFrame {
            time_s: f.time_s,
            load: SimLoad {
                probe: (fe.norm() > threshold_n).then_some(ProbeLoad {
                    tip_m: f.tip_m,
                    axis: f.axis,
                    force_n: *fe,
                }),
                body_force_n_m3: Vector3::zeros(),
            },
        })
        .collect()
}

/// Confirms a force-channel hypothesis by re-simulating its grid of corrected forces (`grid`:
/// named parameters and the sequence under those forces, [`frames_with_forces`]) with
/// leave-one-location-out selection: with the material refit on the corrected forces when the
/// simulator can refit ([`material_refit`]; `corrected` names the correction in the method), else
/// with the compliance scale only (`fit_scale`; `model` names the extended model).
#[allow(clippy::too_many_arguments)]
pub(super) fn confirm(
    grid: Vec<(Vec<(String, f64)>, Vec<SequenceFrame>)>,
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
    sim: &mut dyn ProbeSimulator,
    fit_scale: bool,
    scored: &dyn Fn(usize, usize) -> bool,
    corrected: &str,
    model: &str,
) -> Result<Option<Confirmed>> {
    let total = grid.len();
    let jobs: Vec<SequenceJob> = grid
        .iter()
        .map(|(_, seq)| (Extension::Elastic, seq.clone()))
        .collect();
    // independent sequences, simulated in parallel by the simulator; taken in grid order
    let results = sim.simulate_sequences(&jobs);
    let (cands, frames) = sequence_candidates(grid, results)?;
    let n = cands.len();
    let bounds = |fit| ComplianceScale::new(fit, 0.1, 10.0);
    let lolo = |scale| Lolo {
        rec,
        seg,
        p,
        scale,
        scored,
        train_on_scored: false,
    };
    if n > 0 {
        let method = format!(
            "re-simulated: {corrected} with the material refit on the corrected forces (homogeneous (lambda, alpha), bickel2009 §6), grid of {n} points, leave-one-location-out",
        );
        let run = material_refit(rec, seg, &frames, sim);
        let c = lolo_confirm(&cands, &lolo(bounds(true)), Some(&run), method)?;
        if c.is_some() {
            return Ok(c);
        }
    }
    lolo_confirm(
        &cands,
        &lolo(bounds(fit_scale)),
        None,
        format!(
            "re-simulated extended model ({n} grid points of {total}, {model}), compliance scale, leave-one-location-out"
        ),
    )
}

/// Probe examples of location `l` (bickel2009 §4.1) under per-frame forces `forces`: its frame
/// of largest force and the frame before it whose force is nearest half of that (the two force
/// levels the tissue fit uses per location), with every observed marker.
pub(super) fn location_examples(
    rec: &Recording,
    seg: &Segmentation,
    l: usize,
    forces: &[Vector3<f64>],
) -> Vec<ProbeExample> {
    let cf = &seg.locations[l].contact_frames;
    let Some(&pk) = cf
        .iter()
        .max_by(|&&a, &&b| forces[a].norm().total_cmp(&forces[b].norm()))
    else {
        return Vec::new();
    };
    let half = 0.5 * forces[pk].norm();
    let mid = cf.iter().copied().filter(|&k| k < pk).min_by(|&a, &b| {
        (forces[a].norm() - half)
            .abs()
            .total_cmp(&(forces[b].norm() - half).abs())
    });
    [mid, Some(pk)]
        .into_iter()
        .flatten()
        .filter(|&k| forces[k].norm() > 0.0)
        .map(|k| frame_example(rec, k, forces))
        .collect()
}

/// The probe example of location `l` where the force channel's timing does not bias the force:
/// the hold frame (the segmentation's hold, from the tip's depth — the camera's clock) of largest
/// force under `forces`, or without hold frames the location's frame of largest force; none when
/// that force is zero. A force reading shifted in time or lagging (clock-offset, sensor-lag) is
/// off by about its rate times the delay on a ramp, and the last frame of largest reading can lie
/// past the hold: on the in-memory rig's 0.25 s ramps a reading 0.1 s late is two ramp levels
/// off on the ramp, and its last full reading lies two frames into the unloading, at half the
/// force. Inside the hold the reading is steady but within the delay of its ends, and a lagging
/// one is nearest the force at its largest.
pub(super) fn hold_example(
    rec: &Recording,
    seg: &Segmentation,
    l: usize,
    forces: &[Vector3<f64>],
) -> Vec<ProbeExample> {
    let loc = &seg.locations[l];
    let hold = seg.hold_frames(loc);
    let frames = if hold.is_empty() {
        &loc.contact_frames
    } else {
        &hold
    };
    frames
        .iter()
        .copied()
        .max_by(|&a, &b| forces[a].norm().total_cmp(&forces[b].norm()))
        .filter(|&k| forces[k].norm() > 0.0)
        .map(|k| frame_example(rec, k, forces))
        .into_iter()
        .collect()
}

/// The probe example of frame `k` under per-frame forces `forces`, with every observed marker.
fn frame_example(rec: &Recording, k: usize, forces: &[Vector3<f64>]) -> ProbeExample {
    let f = &rec.frames[k];
    ProbeExample {
        frame: f.frame,
        time_s: f.time_s,
        tip_m: f.tip_m,
        axis: f.axis,
        force_n: forces[k],
        observed: f
            .markers_m
            .iter()
            .enumerate()
            .filter_map(|(m, y)| {
                y.map(|position_m| ObservedMarker {
                    marker: m,
                    position_m,
                })
            })
            .collect(),
    }
}

/// The refit closure of a force-channel hypothesis for [`lolo_confirm`]: the complete extended
/// model is the corrected forces AND the material refit to them (the tissue fit saw the distorted
/// forces). For candidate i (re-simulated over
/// `frames[i]`, which carry its corrected forces) without location `skip`: a homogeneous (λ, α)
/// refit on the other locations' examples under those forces (`ProbeSimulator::refit_homogeneous`,
/// bickel2009 §6), then the re-simulated sequence. `None` when the simulator cannot refit its
/// material or a refit simulation fails.
fn material_refit<'a>(
    rec: &'a Recording,
    seg: &'a Segmentation,
    frames: &'a [Vec<SequenceFrame>],
    sim: &'a dyn ProbeSimulator,
) -> impl Fn(usize, Option<usize>) -> Result<Option<Field>> + Sync + 'a {
    move |i, skip| {
        let Some(seq) = frames.get(i) else {
            return Ok(None);
        };
        let forces: Vec<Vector3<f64>> = seq
            .iter()
            .map(|f| {
                f.load
                    .probe
                    .map(|q| q.force_n)
                    .unwrap_or_else(Vector3::zeros)
            })
            .collect();
        let examples: Vec<ProbeExample> = (0..seg.num_folds())
            .filter(|&l| Some(l) != skip)
            .flat_map(|l| location_examples(rec, seg, l, &forces))
            .collect();
        let MaterialRefitOutcome::Refitted(mut refit) =
            sim.refit_homogeneous(&examples, &Extension::Elastic, None)?
        else {
            return Ok(None);
        };
        match refit.sim.simulate_sequence(&Extension::Elastic, seq) {
            Ok(x) => Ok(Some(x)),
            Err(DiagnoseError::Simulation { .. }) => Ok(None),
            Err(e) => Err(e),
        }
    }
}
