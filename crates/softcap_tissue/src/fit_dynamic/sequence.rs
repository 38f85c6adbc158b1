//! A tracked sequence as the fitter sees it: node trajectories x̂_t of the template mesh, the
//! supported nodes, gravity, density, and the intervals with unknown external forces; split into
//! free-motion segments, each started from the tracked state and velocity at its first frame
//! (wang2015 eq. 6/9: the simulated trajectory starts "from the same initial state").

use nalgebra::Vector3;

/// Node trajectories of a tet mesh and what acted on the body.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackedSequence {
    /// Frame times, s (strictly increasing).
    pub times_s: Vec<f64>,
    /// Node positions per frame, m, in the mesh's node order.
    pub positions_m: Vec<Vec<Vector3<f64>>>,
    /// Whether each frame may be used (the tracker trusted it).
    pub usable: Vec<bool>,
    /// Nodes held by the support (prescribed to their tracked positions).
    pub support_nodes: Vec<usize>,
    /// Gravity, m/s².
    pub gravity_m_s2: Vector3<f64>,
    /// Density, kg/m³.
    pub density_kg_m3: f64,
    /// Intervals [t₀, t₁] of camera time with unknown external forces (interactions.csv).
    pub interactions_s: Vec<[f64; 2]>,
    /// Node velocities per frame, m/s, where they are known besides the positions (a synthetic
    /// truth's, as an oracle for the start states): each segment then starts with them instead
    /// of the polynomial estimate of [`smoothed_state`]. `None` for a tracked sequence.
    pub velocities_m_s: Option<Vec<Vec<Vector3<f64>>>>,
}

/// A run of free-motion frames simulated from its first frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Segment {
    /// First frame (the initial state).
    pub start: usize,
    /// Last frame (inclusive).
    pub end: usize,
}

/// Position and velocity of every node at a frame, from the local least-squares polynomial
/// x(t) ≈ Σ_d c_d (t − t_k)^d of degree `degree` over the usable frames within `half_window` of
/// frame k (a Savitzky–Golay estimate that also handles uneven frame times and the ends of the
/// sequence; with fewer frames the degree drops). The degree matters: for a vibration at ω the
/// central difference (degree 2 over ±1 frame) returns sin(ωΔt)/(ωΔt) of the velocity, 10 % low
/// at 3.7 Hz and 30 Hz, a degree-4 fit over ±2–3 frames about 1 % low.
pub fn smoothed_state(
    seq: &TrackedSequence,
    k: usize,
    half_window: usize,
    degree: usize,
) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let lo = k.saturating_sub(half_window);
    let hi = (k + half_window).min(seq.times_s.len() - 1);
    let frames: Vec<usize> = (lo..=hi).filter(|&j| seq.usable[j]).collect();
    let degree = degree.min(frames.len().saturating_sub(1));
    let n = seq.positions_m[k].len();
    if degree == 0 {
        return (seq.positions_m[k].clone(), vec![Vector3::zeros(); n]);
    }
    // Normal equations of the weighted polynomial fit in τ = t − t_k (scaled by the frame span).
    let tk = seq.times_s[k];
    let scale = frames
        .iter()
        .map(|&j| (seq.times_s[j] - tk).abs())
        .fold(0.0f64, f64::max)
        .max(1e-12);
    let m = degree + 1;
    let mut ata = nalgebra::DMatrix::<f64>::zeros(m, m);
    for &j in &frames {
        let tau = (seq.times_s[j] - tk) / scale;
        for a in 0..m {
            for b in 0..m {
                ata[(a, b)] += tau.powi((a + b) as i32);
            }
        }
    }
    let Some(inv) = ata.try_inverse() else {
        return (seq.positions_m[k].clone(), vec![Vector3::zeros(); n]);
    };
    // Rows 0 and 1 of (AᵀA)⁻¹Aᵀ: the value and slope at τ = 0 as weights on the frames.
    let weights: Vec<(usize, f64, f64)> = frames
        .iter()
        .map(|&j| {
            let tau = (seq.times_s[j] - tk) / scale;
            let (mut w0, mut w1) = (0.0, 0.0);
            for b in 0..m {
                let p = tau.powi(b as i32);
                w0 += inv[(0, b)] * p;
                w1 += inv[(1, b)] * p;
            }
            (j, w0, w1 / scale)
        })
        .collect();
    let mut x = vec![Vector3::zeros(); n];
    let mut v = vec![Vector3::zeros(); n];
    for &(j, w0, w1) in &weights {
        for i in 0..n {
            x[i] += seq.positions_m[j][i] * w0;
            v[i] += seq.positions_m[j][i] * w1;
        }
    }
    // The support is prescribed: keep its tracked position.
    for &i in &seq.support_nodes {
        x[i] = seq.positions_m[k][i];
    }
    (x, v)
}

impl TrackedSequence {
    /// Number of frames.
    pub fn frames(&self) -> usize {
        self.times_s.len()
    }

    /// This sequence followed by `other`, a second recorded motion of the same body (same nodes,
    /// support, gravity and density): `other`'s times shifted to start `gap_s` after this one's
    /// end and the gap marked as an interaction, so that no segment spans the two. A joint fit
    /// sees the modes both motions excite (wang2015 §7's "one more shape"). `None` when the
    /// bodies differ.
    pub fn joined(&self, other: &TrackedSequence, gap_s: f64) -> Option<TrackedSequence> {
        let same_body = self.positions_m.first()?.len() == other.positions_m.first()?.len()
            && self.support_nodes == other.support_nodes
            && self.gravity_m_s2 == other.gravity_m_s2
            && self.density_kg_m3 == other.density_kg_m3;
        if !same_body || gap_s.is_nan() || gap_s <= 0.0 {
            return None;
        }
        let end = *self.times_s.last()?;
        let shift = end + gap_s - other.times_s[0];
        let mut out = self.clone();
        out.times_s.extend(other.times_s.iter().map(|t| t + shift));
        out.positions_m.extend(other.positions_m.iter().cloned());
        out.usable.extend(&other.usable);
        out.velocities_m_s = match (&self.velocities_m_s, &other.velocities_m_s) {
            (Some(a), Some(b)) => Some(a.iter().chain(b).cloned().collect()),
            _ => None,
        };
        out.interactions_s.push([end, end + gap_s]);
        out.interactions_s.extend(
            other
                .interactions_s
                .iter()
                .map(|[a, b]| [a + shift, b + shift]),
        );
        Some(out)
    }

    /// True if no interaction interval overlaps the open interval (t_a, t_b).
    fn is_free(&self, ta: f64, tb: f64) -> bool {
        self.interactions_s
            .iter()
            .all(|&[t0, t1]| t1 <= ta || t0 >= tb)
    }

    /// Free-motion segments of at most `max_frames` intervals: maximal runs of usable frames
    /// whose consecutive intervals are free of interactions, cut into pieces of `max_frames`
    /// (a remainder shorter than `min_frames` intervals is dropped). A segment starts only where
    /// the `lead` frames before it are free too, so the fit of its initial velocity does not
    /// straddle the end of an interaction.
    pub fn segments(&self, max_frames: usize, min_frames: usize, lead: usize) -> Vec<Segment> {
        let max_frames = max_frames.max(1);
        let mut out = Vec::new();
        let n = self.frames();
        let mut start = 0usize;
        while start + 1 < n {
            let lead_start = start.saturating_sub(lead);
            if !self.usable[start] || !self.is_free(self.times_s[lead_start], self.times_s[start]) {
                start += 1;
                continue;
            }
            let mut end = start;
            while end + 1 < n
                && end - start < max_frames
                && self.usable[end + 1]
                && self.is_free(self.times_s[end], self.times_s[end + 1])
            {
                end += 1;
            }
            if end - start >= min_frames.max(1) {
                out.push(Segment { start, end });
            }
            start = end.max(start + 1);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seq(times: Vec<f64>, f: impl Fn(f64) -> f64) -> TrackedSequence {
        TrackedSequence {
            positions_m: times
                .iter()
                .map(|&t| vec![Vector3::new(f(t), 0.0, 0.0)])
                .collect(),
            usable: vec![true; times.len()],
            times_s: times,
            support_nodes: vec![],
            gravity_m_s2: Vector3::zeros(),
            density_kg_m3: 1000.0,
            interactions_s: vec![],
            velocities_m_s: None,
        }
    }

    #[test]
    fn quadratic_fit_recovers_position_and_velocity_of_a_parabola() {
        let times: Vec<f64> = (0..10).map(|k| k as f64 / 30.0).collect();
        let s = seq(times, |t| 0.1 + 2.0 * t - 3.0 * t * t);
        for k in [0, 4, 9] {
            let t = s.times_s[k];
            let (x, v) = smoothed_state(&s, k, 2, 2);
            assert!((x[0].x - (0.1 + 2.0 * t - 3.0 * t * t)).abs() < 1e-12);
            assert!((v[0].x - (2.0 - 6.0 * t)).abs() < 1e-9, "{k}: {}", v[0].x);
        }
    }

    #[test]
    fn segments_avoid_interactions_and_unusable_frames() {
        let times: Vec<f64> = (0..20).map(|k| k as f64 * 0.1).collect();
        let mut s = seq(times, |t| t);
        s.interactions_s = vec![[0.15, 0.45]];
        s.usable[12] = false;
        let segs = s.segments(5, 2, 0);
        assert_eq!(s.segments(5, 2, 1)[0], Segment { start: 6, end: 11 });
        // 0→1 is free but one interval only; 4→5 overlaps [0.15, 0.45]; 5..10 is full; 10→11
        // is one interval before the unusable frame 12; 13..18 full; 18→19 too short.
        assert_eq!(
            segs,
            vec![
                Segment { start: 5, end: 10 },
                Segment { start: 13, end: 18 }
            ]
        );
    }
}
