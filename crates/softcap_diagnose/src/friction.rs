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
//! These kernels serve the drag signature ([`crate::signatures`](mod@crate::signatures)) and the
//! probe-friction hypothesis ([`crate::hypotheses::probe_friction`]: its screen and its
//! confirmation grid).

use crate::recording::Recording;
use crate::segment::{Location, Segmentation};
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

    /// The drag signature reads the loading and hold frames only: a stuck patch holds the surface
    /// forward (+x) through the unloading while the stiff-patch sliding direction has turned to
    /// −x (frame 7), so counting that frame would lower the mean below the drag a of the frames
    /// before it; a patch that slides back (−x at frame 7) reads the same.
    #[test]
    fn drag_signature_reads_the_frames_before_the_tip_turns_back() {
        use crate::segment::Phase;
        use crate::signatures::drag_signature_m;
        let (rec, seg) = drag_recording(1.5);
        assert_eq!(seg.phases[7], Phase::Unloading);
        let a = 1e-4;
        let field = |unload: f64| -> crate::residual::Residuals {
            (0..rec.frames.len())
                .map(|k| {
                    let along = match seg.phases[k] {
                        Phase::Loading | Phase::Hold => a,
                        Phase::Unloading => unload,
                        _ => 0.0,
                    };
                    vec![Some(Vector3::x() * along)]
                })
                .collect()
        };
        for unload in [a, -a] {
            let drag = drag_signature_m(&rec, &seg, &field(unload));
            assert!((drag - a).abs() < 1e-12, "unloading {unload}: drag {drag}");
        }
    }

    #[test]
    fn a_vertical_press_carries_no_travel_traction() {
        let (rec, seg) = drag_recording(0.0);
        let forces: Vec<Vector3<f64>> = rec.frames.iter().map(|f| f.force_n).collect();
        let t = traction_history(&rec, &seg, &forces, 0.8, 500.0);
        assert!(t.iter().all(|v| *v == Vector3::zeros()));
    }
}
