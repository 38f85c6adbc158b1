//! `probe-friction`: the Coulomb traction under the tip that a shaft-axis force sensor cannot see.
//!
//! The hand-held probe measures the force along its shaft only (bickel2009 §7: "we only measure
//! the force in direction of the probe's shaft without measuring tangential forces and friction
//! behavior"; thesis §6.4 models the indenter as a surface with high friction and estimates the
//! in-plane forces in the simulation). When the tip also travels along the surface while pressed
//! in, friction drags the surface: the object carries the measured force **plus** a tangential
//! traction t that nobody measured.
//!
//! The traction history is the Coulomb law written as a return mapping (rate-independent
//! friction as 1-D plasticity: elastic stick predictor, slip corrector; Wriggers, *Computational
//! Contact Mechanics* §5.2), with the normal force LAGGED from the measurement (Li et al. 2020,
//! IPC §5.2: the friction bound μ f_n uses a normal force held fixed while the tangential problem
//! is solved — here the FSR's reading of the same frame, so the law is explicit):
//!
//! ```text
//! t_trial,k = t_{k−1} + k_t Π_n (x_tip,k − x_tip,k−1)         (stick predictor)
//! t_k       = t_trial,k                       if ‖t_trial,k‖ ≤ μ f_n,k
//!           = μ f_n,k t_trial,k / ‖t_trial,k‖  otherwise        (slip: Coulomb cone)
//! ```
//!
//! with Π_n = I − n nᵀ the projection on the surface's tangent plane at the location, f_n,k =
//! |f_k · n| the measured normal force and k_t the tangential stiffness of the stuck patch (the
//! tissue's shear compliance under the tip, in series with the tip; a grid around the recording's
//! indentation stiffness K = max‖f‖ / max depth). t = 0 outside contact. Small travel sticks
//! (t = k_t Δs), long travel slides at μ f_n along the travel, and a retracting tip first unloads
//! the stick and then slides back (the traction reverses).
//!
//! The extended model re-simulated by the confirmation is the default model under the measured
//! force plus t_k over the contact patch (bickel2009 §4.1 force boundary condition), for a grid
//! of (μ, k_t) — and, for a traction that keeps its sense while the probe retracts (a tilted
//! probe's shear, or friction that never slips back), μ‖f‖ŝ along the location's tangential tip
//! travel ŝ with and without reversal while unloading.

use crate::hypothesis::Prepared;
use crate::recording::Recording;
use crate::segment::{Location, Phase, Segmentation};
use nalgebra::Vector3;

/// Fraction of the indentation depth the tip must travel tangentially for a location to carry a
/// travel-driven friction traction (below it the tangential "travel" is tip-tracking noise).
pub const MIN_TRAVEL_FRACTION: f64 = 0.2;

/// Outward surface normal at `point_m`: the rest-state normal of the closest marker (`None`
/// without markers).
pub fn surface_normal_near(rec: &Recording, point_m: &Vector3<f64>) -> Option<Vector3<f64>> {
    rec.rest_markers_m
        .iter()
        .zip(&rec.normals)
        .min_by(|a, b| (a.0 - point_m).norm().total_cmp(&(b.0 - point_m).norm()))
        .and_then(|x| x.1.try_normalize(1e-12))
}

/// Tangential tip travel of a location, first contact → peak, projected on the tangent plane of
/// `normal`, m; `None` when it is shorter than [`MIN_TRAVEL_FRACTION`] × depth.
pub fn tangential_travel(loc: &Location, normal: &Vector3<f64>) -> Option<Vector3<f64>> {
    let d = loc.peak_tip_m - loc.contact_tip_m;
    let travel = d - normal * normal.dot(&d);
    let depth = d.norm();
    (travel.norm() > MIN_TRAVEL_FRACTION * depth && travel.norm() > 1e-6).then_some(travel)
}

/// One Coulomb return-mapping step (module docs): the traction after the tip moved by `slip_m`
/// (already in the tangent plane) from traction `t_prev_n`, with tangential stiffness
/// `stiffness_n_per_m` and friction bound `bound_n` = μ f_n.
pub fn coulomb_step(
    t_prev_n: &Vector3<f64>,
    slip_m: &Vector3<f64>,
    stiffness_n_per_m: f64,
    bound_n: f64,
) -> Vector3<f64> {
    let trial = t_prev_n + slip_m * stiffness_n_per_m;
    let norm = trial.norm();
    if norm <= bound_n.max(0.0) {
        trial
    } else {
        trial * (bound_n.max(0.0) / norm)
    }
}

/// The Coulomb traction on the object (N, world frame) over one contact run (module docs):
/// `tips_m[0]` is where the tip entered the contact (the frame before the run), `tips_m[1..]` and
/// `forces_n` are the run's frames; the traction lies in the tangent plane of `normal`.
pub fn coulomb_traction(
    tips_m: &[Vector3<f64>],
    forces_n: &[Vector3<f64>],
    normal: &Vector3<f64>,
    mu: f64,
    stiffness_n_per_m: f64,
) -> Vec<Vector3<f64>> {
    let n = normal.try_normalize(1e-12).unwrap_or_else(Vector3::z);
    let mut t = Vector3::zeros();
    forces_n
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let (Some(a), Some(b)) = (tips_m.get(i), tips_m.get(i + 1)) else {
                return t;
            };
            let d = b - a;
            let slip = d - n * n.dot(&d);
            t = coulomb_step(&t, &slip, stiffness_n_per_m, mu * f.dot(&n).abs());
            t
        })
        .collect()
}

/// The traction of every frame of the recording (zero outside contact and at locations without
/// tangential travel, [`tangential_travel`]) for friction coefficient `mu` and tangential
/// stiffness `stiffness_n_per_m`, with the normal force from `forces_n` (the measured forces).
///
/// The tip enters a run at the frame before its first contact frame when that frame hovers over
/// the contact point (tangentially within a tip radius of it), else at the first contact frame.
pub fn traction_history(
    rec: &Recording,
    seg: &Segmentation,
    forces_n: &[Vector3<f64>],
    mu: f64,
    stiffness_n_per_m: f64,
) -> Vec<Vector3<f64>> {
    let mut out = vec![Vector3::zeros(); rec.frames.len()];
    for loc in &seg.locations {
        let Some(normal) = surface_normal_near(rec, &loc.contact_tip_m) else {
            continue;
        };
        if tangential_travel(loc, &normal).is_none() {
            continue;
        }
        // maximal runs of consecutive contact frames of this location
        let cf = &loc.contact_frames;
        let mut i = 0;
        while i < cf.len() {
            let mut j = i + 1;
            while j < cf.len() && cf[j] == cf[j - 1] + 1 {
                j += 1;
            }
            let run = &cf[i..j];
            let first = run[0];
            let entry = match first.checked_sub(1) {
                Some(k) => {
                    let d = rec.frames[first].tip_m - rec.frames[k].tip_m;
                    let lateral = (d - normal * normal.dot(&d)).norm();
                    if lateral <= rec.tip_radius_m.max(1e-4) {
                        rec.frames[k].tip_m
                    } else {
                        rec.frames[first].tip_m
                    }
                }
                None => rec.frames[first].tip_m,
            };
            let tips: Vec<Vector3<f64>> = std::iter::once(entry)
                .chain(run.iter().map(|&k| rec.frames[k].tip_m))
                .collect();
            let forces: Vec<Vector3<f64>> = run.iter().map(|&k| forces_n[k]).collect();
            for (&k, t) in run.iter().zip(coulomb_traction(
                &tips,
                &forces,
                &normal,
                mu,
                stiffness_n_per_m,
            )) {
                out[k] = t;
            }
            i = j;
        }
    }
    out
}

/// Unit direction of the sliding traction of every frame (zero outside contact, at locations
/// without tangential travel, and where the traction vanishes): the Coulomb history of
/// [`traction_history`] with a stiff patch (4 × the indentation stiffness `k_ind_n_per_m`), so
/// the direction follows the tip's travel and reverses when it slides back. The linearised
/// screening fits μ on μ f_n × this direction.
pub fn sliding_direction(
    rec: &Recording,
    seg: &Segmentation,
    forces_n: &[Vector3<f64>],
    k_ind_n_per_m: f64,
) -> Vec<Vector3<f64>> {
    traction_history(rec, seg, forces_n, 1.0, 4.0 * k_ind_n_per_m)
        .into_iter()
        .map(|t| t.try_normalize(1e-12).unwrap_or_else(Vector3::zeros))
        .collect()
}

/// Indentation stiffness of the recording K = max‖f‖ / max depth along the probe axis from
/// the first contact frame to the peak (N/m), the scale of the tangential stiffness grid.
pub fn indentation_stiffness_n_per_m(seg: &Segmentation) -> f64 {
    let peak_n = seg.peak_force_n();
    let depth_m = seg
        .locations
        .iter()
        .map(|l| (l.peak_tip_m - l.contact_tip_m).dot(&l.axis).abs())
        .fold(0.0, f64::max)
        .max(1e-5);
    peak_n / depth_m
}

/// Probe force plus the constant-sense traction μ‖f‖ŝ_l along the location's tangential travel
/// (`Prepared::friction_dir`), reversed while unloading when `reverse`.
pub fn constant_sense_forces(
    seg: &Segmentation,
    p: &Prepared,
    mu: f64,
    reverse: bool,
) -> Vec<Vector3<f64>> {
    p.force_n
        .iter()
        .enumerate()
        .map(|(k, f)| match seg.fold_of_frame[k] {
            Some(l) if seg.phases[k].in_contact() => {
                let sign = if reverse && seg.phases[k] == Phase::Unloading {
                    -1.0
                } else {
                    1.0
                };
                f + p.friction_dir[l] * (sign * mu * f.norm())
            }
            _ => *f,
        })
        .collect()
}

/// The drag signature (`Signatures::contact_drag_m`): the mean of r · d̂_k over the contact
/// frames k with a sliding direction d̂_k ([`sliding_direction`] of the measured forces) and the
/// observed markers within [`crate::spatial::contact_radius_m`] of the tip, where r is the
/// baseline residual (measured − model), m. Friction drags the surface along with the tip, so
/// the markers around the patch lead the model along d̂ (> 0); an effect without a preferred
/// tangential sense averages out. 0 when no location has tangential travel.
pub fn drag_signature_m(rec: &Recording, seg: &Segmentation, res: &crate::Residuals) -> f64 {
    let forces: Vec<Vector3<f64>> = rec.frames.iter().map(|f| f.force_n).collect();
    let dir = sliding_direction(rec, seg, &forces, indentation_stiffness_n_per_m(seg));
    let radius = crate::spatial::contact_radius_m(rec);
    let (mut acc, mut n) = (0.0, 0usize);
    for (k, row) in res.iter().enumerate() {
        if !seg.phases[k].in_contact() || dir[k] == Vector3::zeros() {
            continue;
        }
        for (m, r) in row.iter().enumerate() {
            if let Some(r) = r
                && (rec.frames[k].tip_m - rec.rest_markers_m[m]).norm() <= radius
            {
                acc += r.dot(&dir[k]);
                n += 1;
            }
        }
    }
    if n > 0 { acc / n as f64 } else { 0.0 }
}

/// Friction coefficients of the confirmation grid (rubber / skin-like contacts span 0.2–1;
/// the material's compliance scale refitted with the traction lets the effective μ go higher).
pub const MU_GRID: [f64; 8] = [0.2, 0.35, 0.5, 0.65, 0.8, 1.0, 1.25, 1.5];
/// Friction coefficients the frictional rigid-tip replay starts from (`Extension::ProbeFriction`;
/// each point re-simulates the recording with frictional contact on the refined fit mesh, ≈ 1 min
/// in the test profile on the suite session, so the grid is coarse): log-spaced by
/// [`RIGID_MU_STEP`] across rubber on skin, μ 0.5–1. `spatial::confirm` extends it by the same
/// step until the optimum is bracketed (`spatial::bracket_friction`).
pub const RIGID_MU_GRID: [f64; 3] = [0.5, 0.5 * std::f64::consts::SQRT_2, 1.0];
/// Ratio between neighbouring μ of the frictional rigid-tip replay.
pub const RIGID_MU_STEP: f64 = std::f64::consts::SQRT_2;
/// At most this many μ added beyond the ends of [`RIGID_MU_GRID`] (down to 0.18, up to 2.8).
pub const RIGID_MU_EXTENSIONS: usize = 3;
/// μ the bracketing search stays within: a near-frictionless tip to a tacky one.
pub const RIGID_MU_RANGE: (f64, f64) = (0.1, 3.0);
/// Tangential stiffness of the stuck patch as multiples of the indentation stiffness K.
pub const STIFFNESS_GRID: [f64; 4] = [0.25, 0.5, 1.0, 2.0];

/// The confirmation grid of `probe-friction` (module docs): per point its parameters and the
/// per-frame force on the object (measured force + traction). Coulomb return mapping over
/// [`MU_GRID`] × [`STIFFNESS_GRID`], then the constant-sense traction over [`MU_GRID`] with and
/// without reversal while unloading.
pub fn confirmation_grid(
    rec: &Recording,
    seg: &Segmentation,
    p: &Prepared,
) -> Vec<(Vec<(String, f64)>, Vec<Vector3<f64>>)> {
    let k_ind = indentation_stiffness_n_per_m(seg);
    let mut grid = Vec::new();
    for c in STIFFNESS_GRID {
        for mu in MU_GRID {
            let t = traction_history(rec, seg, &p.force_n, mu, c * k_ind);
            if t.iter().all(|v| *v == Vector3::zeros()) {
                continue;
            }
            let forces = p.force_n.iter().zip(&t).map(|(f, t)| f + t).collect();
            grid.push((
                vec![
                    ("mu".into(), mu),
                    ("tangential_stiffness_n_per_m".into(), c * k_ind),
                ],
                forces,
            ));
        }
    }
    for reverse in [false, true] {
        for mu in MU_GRID {
            grid.push((
                vec![
                    ("mu".into(), mu),
                    ("constant_sense".into(), 1.0),
                    ("reverse_on_unloading".into(), f64::from(u8::from(reverse))),
                ],
                constant_sense_forces(seg, p, mu, reverse),
            ));
        }
    }
    grid
}

#[cfg(test)]
mod tests {
    use super::*;

    #[allow(non_snake_case)]
    fn N() -> Vector3<f64> {
        Vector3::z()
    }

    #[test]
    fn small_travel_sticks_elastically() {
        // Δs = 0.1 mm, k_t = 1000 N/m, μ f_n = 0.8 N: t = k_t Δs = 0.1 N along the travel.
        let tips = [Vector3::zeros(), Vector3::new(1e-4, 0.0, -1e-3)];
        let f = [Vector3::new(0.0, 0.0, -1.0)];
        let t = coulomb_traction(&tips, &f, &N(), 0.8, 1000.0);
        assert!(
            (t[0] - Vector3::new(0.1, 0.0, 0.0)).norm() < 1e-12,
            "{}",
            t[0]
        );
    }

    #[test]
    fn long_travel_slides_at_the_coulomb_bound() {
        // 3 mm of travel at k_t = 1000 N/m would need 3 N; the cone caps it at μ f_n = 0.6 N
        // along the travel, whatever the depth component.
        let tips = [
            Vector3::zeros(),
            Vector3::new(0.0, 1.5e-3, -1e-3),
            Vector3::new(0.0, 3e-3, -2e-3),
        ];
        let f = [Vector3::new(0.0, 0.0, -0.5), Vector3::new(0.0, 0.0, -1.0)];
        let t = coulomb_traction(&tips, &f, &N(), 0.6, 1000.0);
        assert!(
            (t[0] - Vector3::new(0.0, 0.3, 0.0)).norm() < 1e-12,
            "{}",
            t[0]
        );
        assert!(
            (t[1] - Vector3::new(0.0, 0.6, 0.0)).norm() < 1e-12,
            "{}",
            t[1]
        );
    }

    #[test]
    fn retracting_tip_unloads_the_stick_then_slides_back() {
        // Slide +x at μ f_n = 1 N, hold (traction kept), then move back 0.5 mm: 1 − 1000·5e-4 =
        // 0.5 N (stick unloading), then back 2 mm more: slides at −μ f_n = −0.5 N (f_n halved).
        let tips = [
            Vector3::zeros(),
            Vector3::new(3e-3, 0.0, 0.0),
            Vector3::new(3e-3, 0.0, 0.0),
            Vector3::new(2.5e-3, 0.0, 0.0),
            Vector3::new(0.5e-3, 0.0, 0.0),
        ];
        let f = [
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(0.0, 0.0, -0.5),
        ];
        let t = coulomb_traction(&tips, &f, &N(), 1.0, 1000.0);
        let tx: Vec<f64> = t.iter().map(|v| v.x).collect();
        let want = [1.0, 1.0, 0.5, -0.5];
        for (a, b) in tx.iter().zip(want) {
            assert!((a - b).abs() < 1e-12, "{tx:?}");
        }
        assert!(t.iter().all(|v| v.y == 0.0 && v.z == 0.0));
    }

    #[test]
    fn the_normal_force_bound_follows_a_tilted_surface() {
        // Surface normal tilted 30° about y; travel along the tangent t̂; force along −n with 2 N:
        // bound μ f_n = 0.5 × 2 N, direction t̂, no component along n.
        let a = 30f64.to_radians();
        let n = Vector3::new(a.sin(), 0.0, a.cos());
        let tangent = Vector3::new(a.cos(), 0.0, -a.sin());
        let tips = [Vector3::zeros(), tangent * 5e-3 + n * 1e-3];
        let f = [-n * 2.0];
        let t = coulomb_traction(&tips, &f, &n, 0.5, 1e4);
        assert!((t[0] - tangent).norm() < 1e-12, "{}", t[0]);
        assert!(t[0].dot(&n).abs() < 1e-12);
    }

    #[test]
    fn coulomb_step_stays_inside_the_cone() {
        let mut t = Vector3::zeros();
        for i in 0..50 {
            let slip = Vector3::new((i as f64 * 0.7).sin(), (i as f64 * 1.3).cos(), 0.0) * 1e-3;
            let bound = 0.2 + 0.1 * (i % 5) as f64;
            t = coulomb_step(&t, &slip, 2000.0, bound);
            assert!(t.norm() <= bound * (1.0 + 1e-12));
        }
    }

    /// One location pressed 2 mm deep in 4 frames while the tip travels `ratio` × depth along +x,
    /// held 2 frames, and retracted along the same path; one marker at the contact point.
    fn drag_recording(ratio: f64) -> (Recording, Segmentation) {
        use crate::recording::Frame;
        use crate::segment::SegmentSettings;
        let c = Vector3::new(0.02, 0.02, 0.01);
        let profile = [0.0, 0.25, 0.5, 0.75, 1.0, 1.0, 1.0, 0.5, 0.0, 0.0];
        let frames = profile
            .iter()
            .enumerate()
            .map(|(k, &p)| {
                let depth = 0.002 * p;
                Frame {
                    frame: k as u64,
                    time_s: 0.05 * k as f64,
                    tip_m: c - Vector3::z() * depth + Vector3::x() * (ratio * depth),
                    axis: -Vector3::z(),
                    force_n: -Vector3::z() * (1.0 * p),
                    markers_m: vec![Some(c)],
                }
            })
            .collect();
        let rec = Recording {
            marker_ids: vec!["m0".into()],
            rest_markers_m: vec![c],
            normals: vec![Vector3::z()],
            gravity_m_s2: Vector3::zeros(),
            support: None,
            tip_radius_m: 0.006,
            frames,
        };
        let seg = Segmentation::new(&rec, &SegmentSettings::default());
        (rec, seg)
    }

    #[test]
    fn traction_history_follows_the_tip_travel_and_reverses() {
        // k_t = 500 N/m: each 0.75 mm travel step adds 0.375 N, capped at μ f_n = 0.5 f_n;
        // retracting by 1.5 mm at half force swings the traction to −0.25 N.
        let (rec, seg) = drag_recording(1.5);
        assert_eq!(seg.num_folds(), 1);
        // K = 1 N over the 1.5 mm from the first contact frame (0.5 mm deep) to the peak
        let k_ind = indentation_stiffness_n_per_m(&seg);
        assert!((k_ind - 1.0 / 1.5e-3).abs() < 1e-6, "{k_ind}");
        let forces: Vec<Vector3<f64>> = rec.frames.iter().map(|f| f.force_n).collect();
        let t = traction_history(&rec, &seg, &forces, 0.5, 500.0);
        let tx: Vec<f64> = t.iter().map(|v| v.x).collect();
        // frame 1: min(0.375, 0.125) = 0.125; 2: min(0.5, 0.25); 3: min(0.625, 0.375);
        // 4..6: 0.5 (slide, then hold); 7: 0.5 − 0.75 = −0.25 = −μ f_n; 8, 9: out of contact.
        let want = [0.0, 0.125, 0.25, 0.375, 0.5, 0.5, 0.5, -0.25, 0.0, 0.0];
        for (k, (a, b)) in tx.iter().zip(want).enumerate() {
            if seg.phases[k].in_contact() {
                assert!((a - b).abs() < 1e-9, "frame {k}: {tx:?}");
            } else {
                assert_eq!(*a, 0.0, "frame {k} out of contact: {tx:?}");
            }
        }
        assert!(t.iter().all(|v| v.y == 0.0 && v.z == 0.0));
        let dir = sliding_direction(&rec, &seg, &forces, k_ind);
        assert_eq!(dir[4], Vector3::x());
        assert_eq!(dir[7], -Vector3::x());
    }

    #[test]
    fn a_vertical_press_carries_no_travel_traction() {
        let (rec, seg) = drag_recording(0.0);
        let forces: Vec<Vector3<f64>> = rec.frames.iter().map(|f| f.force_n).collect();
        let t = traction_history(&rec, &seg, &forces, 0.8, 500.0);
        assert!(t.iter().all(|v| *v == Vector3::zeros()));
    }
}
