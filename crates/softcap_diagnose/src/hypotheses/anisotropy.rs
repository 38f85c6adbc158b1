//! `anisotropy`: the material is stiffer along a fibre direction (transversely isotropic).
//!
//! Screen: the baseline displacement's component along a fibre direction a scaled, −κ a (a·u₀),
//! for 13 directions covering the hemisphere ([`fibre_directions`]). Effect cells: contact frames,
//! markers away from the active contact (the fibre redirects the whole field; under the probe the
//! default model's patch-force error dominates). Signature: a body-fixed lateral shift of the
//! probed markers under every press, consistent across the locations
//! ([`crate::signatures::lateral_shift`], [`LATERAL_CONSISTENCY`]); it sends the hypothesis to
//! re-simulation after the screen's candidates even when its screen (a poor proxy for the
//! redirected field) does not qualify. Confirmation: `softcap_fem::AnisotropicModel` (thesis
//! eq. 8.5) with the screened fibre and its mirror across the probe axis ([`mirrored_fibres`]),
//! fibre ratio and both Poisson ratios on a grid, and, when the in-plane ellipse signature is
//! present ([`spreads_elliptically`]), two HGO fibre families at ±θ in the plane across the probe
//! axis (`Extension::FibreFamilies`, HGO 2000 §4.2 linearized; [`family_grid`]): their
//! orientation (φ, θ) on one ratio first, the other ratios only at the full data's choice when it
//! is a pair of families; each fold's choice and its fibre-ratio neighbours
//! (`ratio_neighbourhood`) re-simulated on the fit mesh refined 1 → 8
//! (`ProbeSimulator::refined`), offered only to the folds whose choice they refine.

use super::Effect;
use super::contract::{Context, Hypothesis, SignatureRoute, param};
use crate::Result;
use crate::cells::{EffectCells, contact_cells, touched_balls};
use crate::confirm::{ComplianceScale, Confirmed, Lolo, lolo_choices};
use crate::recording::Recording;
use crate::resim::{GridPoint, Replays, simulate_grid};
use crate::screen::{Basis, Refit, Variant};
use crate::segment::Segmentation;
use crate::signatures::Signatures;
use crate::sim::{Extension, ProbeSimulator};
use nalgebra::Vector3;
use softcap_fem::symmetric_fibre_pair;

/// The anisotropy hypothesis.
pub struct Anisotropy;

/// Name of the effect cells.
const CELLS: &str = "contact/away-from-probe";

/// Least consistency |Σ_l v_l| / Σ_l |v_l| of the per-location lateral shifts for the anisotropy
/// signature ([`crate::signatures::lateral_shift`]): 1 when every location shifts the same way,
/// ≈ 1/√L for directions at random.
pub const LATERAL_CONSISTENCY: f64 = 0.8;

/// The lateral-shift signature is present: a mean shift above 3σ (σ the marker noise per
/// coordinate) that is consistent across the locations (≥ [`LATERAL_CONSISTENCY`]).
pub fn shifts_laterally(sig: &Signatures) -> bool {
    sig.lateral_shift_m > 3.0 * sig.noise_sigma_m
        && sig.lateral_shift_consistency >= LATERAL_CONSISTENCY
}

/// Least consistency |Σ_l h_l| / Σ_l |h_l| of the per-location in-plane ellipses
/// ([`crate::signatures::in_plane_ellipse`]) for the two-family signature.
pub const ELLIPSE_CONSISTENCY: f64 = 0.8;

/// The in-plane ellipse signature of two fibre families is present: a second harmonic of the
/// in-plane radial residual above 3σ whose axes are the same at every location
/// (≥ [`ELLIPSE_CONSISTENCY`]).
pub fn spreads_elliptically(sig: &Signatures) -> bool {
    sig.in_plane_ellipse_m > 3.0 * sig.noise_sigma_m
        && sig.in_plane_ellipse_consistency >= ELLIPSE_CONSISTENCY
}

impl Hypothesis for Anisotropy {
    fn effect(&self) -> Effect {
        Effect::Anisotropy
    }

    fn term(&self) -> &'static str {
        "displacement along fibre a scaled by (1 - kappa)"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let p = cx.prepared;
        let (nt, nm) = (p.times_s.len(), p.num_markers());
        fibre_directions()
            .into_iter()
            .map(|a| {
                let field = (0..nt)
                    .map(|k| {
                        (0..nm)
                            .map(|m| -a * a.dot(&(p.baseline_m[k][m] - p.rest_model_m[m])))
                            .collect()
                    })
                    .collect();
                Variant {
                    fixed: vec![("fibre_x", a.x), ("fibre_y", a.y), ("fibre_z", a.z)],
                    offset: None,
                    bases: vec![Basis {
                        name: "kappa",
                        nonneg: false,
                        field,
                    }],
                }
            })
            .collect()
    }

    fn effect_cells(&self, rec: &Recording, seg: &Segmentation) -> Option<EffectCells> {
        Some(EffectCells {
            name: CELLS,
            mask: contact_cells(rec, seg, false),
        })
    }

    fn signature_support(&self, s: &Signatures) -> f64 {
        if shifts_laterally(s) || spreads_elliptically(s) {
            1.0
        } else {
            0.0
        }
    }

    fn signature_route(&self, s: &Signatures) -> Option<SignatureRoute> {
        (shifts_laterally(s) || spreads_elliptically(s)).then_some(SignatureRoute::AfterScreen)
    }

    fn confirm(
        &self,
        cx: &Context<'_>,
        refit: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        let param = |name| param(&refit.params, name).unwrap_or(0.0);
        let a = Vector3::new(param("fibre_x"), param("fibre_y"), param("fibre_z"));
        let a = a.try_normalize(1e-9).unwrap_or_else(Vector3::x);
        // The screened fibre AND its mirror in the plane across the mean probe axis: a press
        // along n cannot tell a from a − 2(a·n)n in the linearised field, the re-simulation can.
        // The fitted isotropic Poisson ratio is biased by the anisotropy: ν_t, ν_a refitted.
        // Ratios log-spaced by 2 from a mild fibre to a tendon-like one.
        let mut grid: Vec<GridPoint> = Vec::new();
        for a in mirrored_fibres(&a, &mean_probe_axis(rec, seg)) {
            for ratio in [2.5, 5.0, 10.0, 20.0] {
                for nu_transverse in [0.2, 0.35, 0.45] {
                    for nu_fibre in [0.1, 0.3] {
                        grid.push((
                            vec![
                                ("fibre_x".into(), a.x),
                                ("fibre_y".into(), a.y),
                                ("fibre_z".into(), a.z),
                                ("fibre_ratio".into(), ratio),
                                ("nu_transverse".into(), nu_transverse),
                                ("nu_fibre".into(), nu_fibre),
                            ],
                            Extension::TransverselyIsotropic {
                                fibre: a,
                                ratio,
                                nu_transverse,
                                nu_fibre,
                            },
                            p.force_n.clone(),
                        ));
                    }
                }
            }
        }
        // Two HGO fibre families at ±θ in the plane across the probe axis (HGO 2000 §4.2), only
        // when their signature, the in-plane ellipse, is present: their in-plane orientation φ
        // and angle θ first, at one ratio; the ratios only around the full data's choice when it
        // is a pair of families.
        let axis = mean_probe_axis(rec, seg);
        if spreads_elliptically(cx.signatures) {
            grid.extend(family_grid(
                &axis,
                &FAMILY_ORIENTATIONS,
                &[FAMILY_FIRST_RATIO],
                &[None],
                p,
            ));
        }
        let lolo = Lolo {
            rec,
            seg,
            p,
            scale: ComplianceScale::new(true, 0.1, 10.0),
            scored,
            train_on_scored: false,
        };
        let mut replays = Replays::run(sim, grid, Vec::new(), rec, seg, p, true)?;
        let choices = lolo_choices(&replays.forced, &lolo);
        if let Some(&full) = choices.last()
            && replays.sources[full]
                .0
                .iter()
                .any(|(n, _)| n == "family_theta_deg")
        {
            let src = &replays.sources[full].0;
            let value = |name: &str| super::contract::param(src, name).unwrap_or(0.0);
            let orientation = [(value("family_phi_deg"), value("family_theta_deg"))];
            let mut more = family_grid(&axis, &orientation, &FAMILY_MORE_RATIOS, &[None], p);
            let poissons = FAMILY_MATRIX_POISSON.map(Some);
            more.extend(family_grid(
                &axis,
                &orientation,
                &FAMILY_POISSON_RATIOS,
                &poissons,
                p,
            ));
            let (forced, total, sources) = simulate_grid(sim, more, rec, seg, p, true)?;
            replays.forced.extend(forced);
            replays.sources.extend(sources);
            replays.total += total;
        }
        // Each fold's choice and its neighbours along the fibre ratio re-simulated on the
        // refined fit mesh — only where the template does not already resolve the tip
        // (`ProbeSimulator::resolves_footprint`): there the refined mesh changes the field under
        // the footprint and nothing else.
        let balls = touched_balls(rec, seg);
        let tips: Vec<Vector3<f64>> = balls.iter().map(|b| b.centre_m).collect();
        if !sim.resolves_footprint(rec.tip_radius_m, &tips)
            && let Some(mut fine) = sim.refined(&balls)?
        {
            let choices = lolo_choices(&replays.forced, &lolo);
            let neighbourhoods: Vec<Vec<usize>> = choices
                .iter()
                .map(|&i| ratio_neighbourhood(&replays.sources, i))
                .collect();
            let mut chosen: Vec<usize> = neighbourhoods.concat();
            chosen.sort_unstable();
            chosen.dedup();
            replays.add_refined(fine.as_mut(), &chosen, neighbourhoods, rec, seg, p, true)?;
        }
        replays.confirm(&lolo, "AnisotropicModel", CELLS)
    }
}

/// The (φ, θ) of the two-family grid, degrees: in-plane orientation φ of the bisector and
/// half-angle θ; θ = 0 is one in-plane family, θ = 45° is the same pair for φ and φ + 90°.
pub const FAMILY_ORIENTATIONS: [(f64, f64); 10] = [
    (0.0, 0.0),
    (45.0, 0.0),
    (90.0, 0.0),
    (135.0, 0.0),
    (0.0, 30.0),
    (45.0, 30.0),
    (90.0, 30.0),
    (135.0, 30.0),
    (0.0, 45.0),
    (45.0, 45.0),
];

/// The ratio 4 k1 / E of each family on which the orientation is chosen (a fibre-dominated
/// tissue, the HGO arterial fits' k1 ≫ μ) and the ratios tried around the chosen orientation.
pub const FAMILY_FIRST_RATIO: f64 = 8.0;
/// See [`FAMILY_FIRST_RATIO`].
pub const FAMILY_MORE_RATIOS: [f64; 3] = [2.0, 4.0, 16.0];

/// The matrix Poisson ratios tried at the chosen orientation (the fibres carry stiffness the
/// isotropic fit took as a lower ν; soft-tissue matrices are nearly incompressible), each at
/// [`FAMILY_POISSON_RATIOS`].
pub const FAMILY_MATRIX_POISSON: [f64; 2] = [0.45, 0.49];
/// See [`FAMILY_MATRIX_POISSON`].
pub const FAMILY_POISSON_RATIOS: [f64; 3] = [2.0, 4.0, 8.0];

/// Grid points of [`Extension::FibreFamilies`]: for each (φ, θ) of `orientations` (degrees), each
/// matrix Poisson ratio of `poissons` (`None`: the default model's) and each ratio, the two fibres
/// at ±θ about the in-plane direction φ of the plane across the unit probe axis `axis` (φ from
/// world x projected into that plane, or y when x is along the axis).
pub fn family_grid(
    axis: &Vector3<f64>,
    orientations: &[(f64, f64)],
    ratios: &[f64],
    poissons: &[Option<f64>],
    p: &crate::baseline::Prepared,
) -> Vec<GridPoint> {
    let reference = if axis.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let mut out = Vec::new();
    for &(phi, theta) in orientations {
        let rotation = nalgebra::Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(*axis),
            phi.to_radians(),
        );
        let Some(pair) = symmetric_fibre_pair(&(rotation * reference), axis, theta.to_radians())
        else {
            continue;
        };
        for &poisson in poissons {
            for &ratio in ratios {
                let mut params = vec![
                    ("family_phi_deg".into(), phi),
                    ("family_theta_deg".into(), theta),
                    ("family_ratio".into(), ratio),
                ];
                if let Some(nu) = poisson {
                    params.push(("family_poisson".into(), nu));
                }
                out.push((
                    params,
                    Extension::FibreFamilies {
                        fibres: pair.map(|a| a.into_inner()),
                        ratio,
                        poisson,
                    },
                    p.force_n.clone(),
                ));
            }
        }
    }
    out
}

/// Thirteen directions covering the hemisphere (axes, face and space diagonals).
pub fn fibre_directions() -> Vec<Vector3<f64>> {
    let mut d = vec![Vector3::x(), Vector3::y(), Vector3::z()];
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        for s in [1.0, -1.0] {
            let mut v = Vector3::zeros();
            v[a] = 1.0;
            v[b] = s;
            d.push(v.normalize());
        }
    }
    for (sy, sz) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
        d.push(Vector3::new(1.0, sy, sz).normalize());
    }
    d
}

/// Unit mean probe axis (handle → tip) over the contact frames of the location folds; −z when
/// there is none.
pub fn mean_probe_axis(rec: &Recording, seg: &Segmentation) -> Vector3<f64> {
    rec.frames
        .iter()
        .enumerate()
        .filter(|(k, _)| seg.fold_of_frame[*k].is_some() && seg.phases[*k].in_contact())
        .fold(Vector3::zeros(), |s, (_, f)| s + f.axis)
        .try_normalize(1e-9)
        .unwrap_or_else(|| -Vector3::z())
}

/// The fibre `a` and its mirror image in the plane across the unit probe axis `n`,
/// a' = a − 2(a·n)n (a fibre is a line: a and −a are the same). Only `a` when the mirror is the
/// same line (a ∥ n or a ⊥ n, within 1°).
pub fn mirrored_fibres(a: &Vector3<f64>, n: &Vector3<f64>) -> Vec<Vector3<f64>> {
    let mirror = a - n * (2.0 * a.dot(n));
    if a.dot(&mirror).abs() >= 1.0_f64.to_radians().cos() * a.norm() * mirror.norm() {
        vec![*a]
    } else {
        vec![*a, mirror]
    }
}

/// Grid point `i` and its neighbours along the fibre ratio (the grid points that differ from it
/// in `fibre_ratio` or `family_ratio` only, the next lower and higher ratio), in grid order.
fn ratio_neighbourhood(points: &[GridPoint], i: usize) -> Vec<usize> {
    let is_ratio = |n: &str| n == "fibre_ratio" || n == "family_ratio";
    let ratio_of = |j: usize| {
        points[j]
            .0
            .iter()
            .find(|(n, _)| is_ratio(n))
            .map(|&(_, v)| v)
    };
    let Some(r0) = ratio_of(i) else {
        return vec![i];
    };
    let others = |j: usize| {
        points[j]
            .0
            .iter()
            .filter(|(n, _)| !is_ratio(n))
            .eq(points[i].0.iter().filter(|(n, _)| !is_ratio(n)))
    };
    let (mut below, mut above): (Option<(usize, f64)>, Option<(usize, f64)>) = (None, None);
    for j in 0..points.len() {
        let Some(r) = ratio_of(j) else { continue };
        if j == i || !others(j) {
            continue;
        }
        if r < r0 && below.is_none_or(|(_, b)| r > b) {
            below = Some((j, r));
        }
        if r > r0 && above.is_none_or(|(_, a)| r < a) {
            above = Some((j, r));
        }
    }
    let mut out: Vec<usize> = [below.map(|b| b.0), Some(i), above.map(|a| a.0)]
        .into_iter()
        .flatten()
        .collect();
    out.sort_unstable();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thirteen_distinct_fibre_directions() {
        let d = fibre_directions();
        assert_eq!(d.len(), 13);
        for i in 0..13 {
            assert!((d[i].norm() - 1.0).abs() < 1e-12);
            for j in 0..i {
                assert!(d[i].dot(&d[j]).abs() < 0.999, "{i} {j} parallel");
            }
        }
    }

    #[test]
    fn the_lateral_shift_rule_needs_3_sigma_and_consistency() {
        let mut sig = crate::signatures::Signatures {
            noise_sigma_m: 1e-5,
            lateral_shift_m: 5e-5,
            lateral_shift_consistency: 0.96,
            ..Default::default()
        };
        assert!(shifts_laterally(&sig));
        sig.lateral_shift_consistency = 0.5;
        assert!(!shifts_laterally(&sig));
        sig.lateral_shift_consistency = 0.96;
        sig.lateral_shift_m = 2e-5;
        assert!(!shifts_laterally(&sig));
    }

    /// The ratio neighbourhood of a grid point: the same fibre and Poisson ratios at the next
    /// lower and higher fibre ratio (none below the grid's first, none above its last).
    #[test]
    fn ratio_neighbourhood_spans_the_adjacent_fibre_ratios() {
        let mut points: Vec<GridPoint> = Vec::new();
        for nu in [0.2, 0.45] {
            for ratio in [2.5, 5.0, 10.0, 20.0] {
                points.push((
                    vec![("fibre_ratio".into(), ratio), ("nu_transverse".into(), nu)],
                    Extension::Elastic,
                    Vec::new(),
                ));
            }
        }
        assert_eq!(ratio_neighbourhood(&points, 2), vec![1, 2, 3]);
        assert_eq!(ratio_neighbourhood(&points, 4), vec![4, 5]);
        assert_eq!(ratio_neighbourhood(&points, 7), vec![6, 7]);
    }

    #[test]
    fn mirrored_fibres_recover_the_oblique_truth() {
        // session 6: the screen's fibre [1, 0, −1]/√2 under a vertical press is the mirror of
        // the suite truth's [1, 0, 1]/√2.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let down = -Vector3::z();
        let f = mirrored_fibres(&Vector3::new(s, 0.0, -s), &down);
        assert_eq!(f.len(), 2);
        assert!((f[1] - Vector3::new(s, 0.0, s)).norm() < 1e-15);
        // a tilted probe: the mirror lies in the plane across that axis, same angle to it
        let n = Vector3::new(0.3, 0.0, -1.0).normalize();
        let a = Vector3::new(0.2, 0.5, 0.8).normalize();
        let m = &mirrored_fibres(&a, &n)[1];
        assert!((m.norm() - 1.0).abs() < 1e-12);
        assert!((m.dot(&n) + a.dot(&n)).abs() < 1e-12);
        assert!(((m - n * m.dot(&n)) - (a - n * a.dot(&n))).norm() < 1e-12);
        // in the surface plane or along the axis the mirror is the same line
        assert_eq!(mirrored_fibres(&Vector3::x(), &down).len(), 1);
        assert_eq!(mirrored_fibres(&Vector3::z(), &down).len(), 1);
    }
}
