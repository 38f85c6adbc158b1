//! Where errors are scored: the focus cells the locate step finds (the (region, phase) cells where
//! the default model's error stands out), and the effect cells of the hypotheses whose effect
//! lives in known observations (under or away from the active contact, after release near a
//! touched location).

use crate::recording::Recording;
use crate::residual::Residuals;
use crate::segment::{Phase, Region, Segmentation};
use crate::settings::DiagnoseSettings;
use std::collections::BTreeMap;

/// The observations (frame k, marker m) where one hypothesis's effect lives, and their name
/// (JSON `evidence.scored_cells`). Only frames of a location fold are ever in them.
#[derive(Clone, Debug, PartialEq)]
pub struct EffectCells {
    /// Name, e.g. `contact/under-probe`.
    pub name: &'static str,
    /// `mask[k][m]`: observation (k, m) is scored.
    pub mask: Vec<Vec<bool>>,
}

/// Radius around a contact point within which a marker is "under the contact" for the
/// effect cells, m: 2.5 tip radii, at least 5 mm.
pub fn contact_radius_m(rec: &Recording) -> f64 {
    (2.5 * rec.tip_radius_m).max(0.005)
}

/// Where the replays need the finer mesh (`ProbeSimulator::refined`): a ball of
/// [`contact_radius_m`] around the tip of every contact frame of every location. Beyond ≈ 2.5 tip
/// radii the field depends on the resultant only (Saint-Venant), which the coarse mesh carries;
/// inside, the footprint, the stuck patch and the plastic dent must span several nodes.
pub fn touched_balls(rec: &Recording, seg: &Segmentation) -> Vec<softcap_mesh::RefineBall> {
    let radius_m = contact_radius_m(rec);
    seg.locations
        .iter()
        .flat_map(|l| &l.contact_frames)
        .map(|&f| softcap_mesh::RefineBall {
            centre_m: rec.frames[f].tip_m,
            radius_m,
        })
        .collect()
}

/// The contact frames of the location folds, markers within [`contact_radius_m`] of the tip
/// (`under_probe`) or beyond it (`!under_probe`).
pub fn contact_cells(rec: &Recording, seg: &Segmentation, under_probe: bool) -> Vec<Vec<bool>> {
    let r = contact_radius_m(rec);
    (0..rec.frames.len())
        .map(|k| {
            (0..rec.num_markers())
                .map(|m| {
                    let near = (rec.frames[k].tip_m - rec.rest_markers_m[m]).norm() <= r;
                    seg.fold_of_frame[k].is_some()
                        && seg.phases[k].in_contact()
                        && near == under_probe
                })
                .collect()
        })
        .collect()
}

/// The affected cells: (region, phase) cells over the location frames whose baseline RMS is at
/// least `focus_noise_factor` × √3σ and `focus_fraction_of_max` × the largest cell's RMS. Empty
/// when focus scoring is off or no cell stands out (then every observation is scored).
pub fn focus_cells(
    seg: &Segmentation,
    res: &Residuals,
    noise_sigma_m: f64,
    settings: &DiagnoseSettings,
) -> Vec<(Region, Phase)> {
    if !settings.score_on_focus {
        return Vec::new();
    }
    let mut acc: BTreeMap<(Region, Phase), (f64, usize)> = BTreeMap::new();
    for (k, row) in res.iter().enumerate() {
        if seg.fold_of_frame[k].is_none() {
            continue;
        }
        for (m, r) in row.iter().enumerate() {
            if let Some(r) = r {
                let e = acc
                    .entry((seg.regions[m], seg.phases[k]))
                    .or_insert((0.0, 0));
                e.0 += r.norm_squared();
                e.1 += 1;
            }
        }
    }
    let rms: Vec<((Region, Phase), f64)> = acc
        .into_iter()
        .map(|(c, (s, n))| (c, (s / n.max(1) as f64).sqrt()))
        .collect();
    let max = rms.iter().map(|x| x.1).fold(0.0, f64::max);
    let floor = settings.focus_noise_factor * 3f64.sqrt() * noise_sigma_m;
    let lim = floor.max(settings.focus_fraction_of_max * max);
    rms.into_iter()
        .filter(|(_, v)| *v >= lim && *v > 0.0)
        .map(|(c, _)| c)
        .collect()
}
