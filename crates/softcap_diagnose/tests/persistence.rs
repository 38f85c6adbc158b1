//! The persistence of the released set (`softcap_diagnose::signatures`): a permanent set against a
//! recovering one, and its propagated standard error against a seeded Monte-Carlo.

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use softcap_diagnose::residual::{Residuals, rest_mean};
use softcap_diagnose::segment::{Location, Phase, Region, Segmentation};
use softcap_diagnose::signatures::{released_set_persistence, released_set_persistence_se};
use softcap_diagnose::{Frame, Recording};

/// Nine top-surface markers 5 mm apart on a line; `n_rest` rest frames, then three presses 20 mm
/// apart (x = 0, 20, 40 mm), each one hold frame followed by `n_released` released frames.
struct ThreePresses {
    rest: Vec<Vector3<f64>>,
    tips: Vec<Vector3<f64>>,
    n_rest: usize,
    per_press: usize,
    rec: Recording,
    seg: Segmentation,
}

impl ThreePresses {
    fn new(n_rest: usize, n_released: usize) -> Self {
        let rest: Vec<Vector3<f64>> = (0..9)
            .map(|i| Vector3::new(0.005 * i as f64, 0.0, 0.02))
            .collect();
        let nm = rest.len();
        let tips: Vec<Vector3<f64>> = [0.0, 0.02, 0.04]
            .iter()
            .map(|&x| Vector3::new(x, 0.0, 0.02))
            .collect();
        let per_press = 1 + n_released;
        let mut t = ThreePresses {
            rest,
            tips,
            n_rest,
            per_press,
            rec: Recording {
                marker_ids: (0..nm).map(|m| m.to_string()).collect(),
                rest_markers_m: Vec::new(),
                normals: vec![Vector3::z(); nm],
                gravity_m_s2: Vector3::zeros(),
                support: None,
                tip_radius_m: 0.002,
                frames: Vec::new(),
            },
            seg: Segmentation {
                phases: Vec::new(),
                fold_of_frame: Vec::new(),
                locations: Vec::new(),
                regions: vec![Region::Probed; nm],
                near_radius_m: 0.008,
            },
        };
        let nt = n_rest + 3 * per_press;
        t.rec.rest_markers_m = t.rest.clone();
        t.rec.frames = (0..nt)
            .map(|k| Frame {
                frame: k as u64,
                time_s: k as f64,
                tip_m: t.tips[t.frame(k).1.unwrap_or(0)],
                axis: -Vector3::z(),
                force_n: Vector3::z()
                    * if t.frame(k).0 == Phase::Hold {
                        -0.5
                    } else {
                        0.0
                    },
                markers_m: t.rest.iter().map(|p| Some(*p)).collect(),
            })
            .collect();
        t.seg.phases = (0..nt).map(|k| t.frame(k).0).collect();
        t.seg.fold_of_frame = (0..nt).map(|k| t.frame(k).1).collect();
        t.seg.locations = (0..3)
            .map(|l| Location {
                index: l,
                peak_tip_m: t.tips[l],
                contact_tip_m: t.tips[l],
                axis: -Vector3::z(),
                peak_frame: n_rest + l * per_press,
                peak_force_n: 0.5,
                contact_frames: vec![n_rest + l * per_press],
            })
            .collect();
        t
    }

    /// (phase, location) of frame k.
    fn frame(&self, k: usize) -> (Phase, Option<usize>) {
        if k < self.n_rest {
            return (Phase::Rest, None);
        }
        let (l, i) = (
            (k - self.n_rest) / self.per_press,
            (k - self.n_rest) % self.per_press,
        );
        (if i == 0 { Phase::Hold } else { Phase::Released }, Some(l))
    }
}

/// One rest frame, three presses each followed by one released frame; the markers within the
/// contact radius (5 mm) of the first press carry a set after it, which at the two later releases
/// is still all there (plastic: 1) or has decayed to a fifth (creep recovery: 0.2). A template
/// offset, the same at rest and after release, cancels; one press has no later release to compare.
#[test]
fn released_set_persistence_tells_a_permanent_set_from_a_recovering_one() {
    let t = ThreePresses::new(1, 1);
    let (rest, tips, nm) = (&t.rest, &t.tips, t.rest.len());
    let offset = Vector3::new(2e-5, 0.0, 1e-5);
    let res = |later: f64| -> Residuals {
        (0..7)
            .map(|k| {
                (0..nm)
                    .map(|m| {
                        let set = Vector3::new(0.0, 0.0, -3e-4) * (1.0 - m as f64 / 2.0);
                        let under_first = (rest[m] - tips[0]).norm() <= 0.005;
                        Some(match k {
                            2 if under_first => offset + set,
                            4 | 6 if under_first => offset + set * later,
                            _ => offset,
                        })
                    })
                    .collect()
            })
            .collect()
    };
    let (rec, seg) = (&t.rec, &t.seg);
    let permanent = res(1.0);
    let p = released_set_persistence(rec, seg, &permanent, &rest_mean(&permanent, seg, nm));
    assert!((p.unwrap() - 1.0).abs() < 1e-12, "{p:?}");
    let recovering = res(0.2);
    let p = released_set_persistence(rec, seg, &recovering, &rest_mean(&recovering, seg, nm));
    assert!((p.unwrap() - 0.2).abs() < 1e-12, "{p:?}");
    let mut one = seg.clone();
    one.phases.truncate(3);
    one.fold_of_frame.truncate(3);
    let short = Recording {
        frames: rec.frames[..3].to_vec(),
        ..rec.clone()
    };
    let r3: Residuals = permanent[..3].to_vec();
    assert_eq!(
        released_set_persistence(&short, &one, &r3, &rest_mean(&permanent, seg, nm)),
        None
    );
}

/// `signatures::released_set_persistence_se` against a seeded Monte-Carlo: four rest frames, then
/// three presses 20 mm apart each followed by three released frames; every press leaves a set of
/// 2.5–8σ on the markers within its contact radius (seven earlier/later pairs, the scale of the
/// in-memory weak plastic set), of which the part `kept` is still there after the next press
/// (1: permanent, 0.6: recovering). Over 4000 noise draws each (σ = 10 µm per coordinate, every
/// frame and marker) the standard deviation of the persistence equals the propagated standard
/// error within 10 % (measured: 0.1011 vs 0.1085, 0.0867 vs 0.0914; the Monte-Carlo's own
/// error 1.1 %, the rest the delta method's second-order terms). Checked to fail: without the
/// later set's term of the gradient the error is 0.0698 at kept 0.6 (−20 %), without the frame
/// counts n_i 0.1849 at kept 1 (+83 %). The rest mean's term is 3–9 % here (it cancels between a
/// marker's earlier and later sets near p = 1), inside the tolerance. The mean persistence sits
/// below the truth by the noise's attenuation of the slope (0.95 for 1), a second-order bias the
/// standard error does not carry.
#[test]
fn persistence_standard_error_matches_a_monte_carlo() {
    let (n_rest, n_released) = (4usize, 3usize);
    let t = ThreePresses::new(n_rest, n_released);
    let (rest, tips, nm) = (&t.rest, &t.tips, t.rest.len());
    let (rec, seg) = (&t.rec, &t.seg);
    let nt = rec.frames.len();
    let frame_of = |k: usize| t.frame(k);
    let sigma = 1e-5;
    // the permanent set each marker carries from the release after the press near it on
    let set_of = |m: usize| -> (usize, Vector3<f64>) {
        let l = (0..3)
            .find(|&l| (rest[m] - tips[l]).norm() <= 0.005 + 1e-12)
            .unwrap_or(usize::MAX);
        (
            l,
            Vector3::new(0.5, 0.0, -1.0 - 0.3 * m as f64) * 2.5 * sigma,
        )
    };
    let noise = Normal::new(0.0, sigma).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(37);
    // `kept`: the part of a set still there after the next press (1 permanent, 0.6 recovering)
    for kept in [1.0, 0.6] {
        let (mut ps, mut ses) = (Vec::new(), Vec::new());
        for _ in 0..4000 {
            let res: Residuals = (0..nt)
                .map(|k| {
                    (0..nm)
                        .map(|m| {
                            let (l_set, set) = set_of(m);
                            let scale = match frame_of(k) {
                                (Phase::Released, Some(l)) if l == l_set => 1.0,
                                (_, Some(l)) if l > l_set => kept,
                                _ => 0.0,
                            };
                            let e = Vector3::from_fn(|_, _| noise.sample(&mut rng));
                            Some(set * scale + e)
                        })
                        .collect()
                })
                .collect();
            let mean = rest_mean(&res, seg, nm);
            ps.push(released_set_persistence(rec, seg, &res, &mean).unwrap());
            ses.push(released_set_persistence_se(rec, seg, &res, &mean, sigma).unwrap());
        }
        let n = ps.len() as f64;
        let mean_p = ps.iter().sum::<f64>() / n;
        let sd = (ps.iter().map(|p| (p - mean_p).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        let se = ses.iter().sum::<f64>() / n;
        eprintln!(
            "kept {kept}: persistence {mean_p:.4}, Monte-Carlo SD {sd:.4}, propagated SE {se:.4}"
        );
        assert!(
            (se / sd - 1.0).abs() < 0.1,
            "kept {kept}: propagated {se:.4}, Monte-Carlo {sd:.4}"
        );
    }
}
