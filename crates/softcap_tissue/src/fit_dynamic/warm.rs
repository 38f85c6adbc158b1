//! Modal warm start (wang2015 §6.3): the natural frequencies √λ_i of K φ = λ M φ scale with
//! √E, so the modulus whose first modes ring at the frequencies seen in the tracked motion is a
//! start in the valley of eq. 9. The tracked displacements u_t = x̂_t − x_s are projected on the
//! M-orthonormal modes, q_i(t) = φ_iᵀ M u_t; a damped sinusoid
//! q(t) ≈ e^{−σt}(a cos ω_d t + b sin ω_d t) + c is fitted to each free segment of the
//! dominant coordinates (grid over (ω_d, σ), linear least squares for (a, b, c), then
//! Nelder–Mead), giving the natural frequency ω = √(ω_d² + σ²) and the damping ratio ζ = σ/ω.
//! The paper samples fifty E and keeps the best match; here E ← E (ω_measured/ω_model)² is
//! iterated with the rest shape re-solved at each E (exact for a homogeneous linear body, a
//! few passes otherwise). α and β come from the damping ratios of the measured modes,
//! ζ_i = α/(2ω_i) + βω_i/2 in least squares ([`damping_from_modes`]), or, with one mode (or
//! modes too close in frequency to separate them), half of ζ each.

use nalgebra::Vector3;
use softcap_core::{NelderMeadSettings, nelder_mead};
use softcap_fem::{ModalSettings, Modes, QuadraticSolver, RayleighDamping, lanczos_modes};

use super::forward::{FitModel, Forward};
use super::sequence::Segment;

/// A damped oscillation fitted to one modal coordinate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModalFit {
    /// Mode index (ascending frequency).
    pub mode: usize,
    /// Natural angular frequency ω = √(ω_d² + σ²), rad/s.
    pub omega_rad_s: f64,
    /// Damping ratio ζ = σ/ω.
    pub zeta: f64,
    /// Fraction of the coordinate's variance the sinusoid explains.
    pub explained: f64,
    /// RMS amplitude of the coordinate (M-weighted metres·√kg).
    pub amplitude: f64,
}

/// Modes of the linearized body at its rest shape (support dofs fixed), `count` smallest:
/// shift-invert Lanczos for linear tets, subspace iteration for quadratic ones.
pub fn modes(forward: &Forward, model: &FitModel, count: usize) -> crate::Result<Modes> {
    modes_to(forward, model, count, 1e-6)
}

/// [`modes`] to a relative residual `tolerance` (linear tets; quadratic tets: their solver's).
pub fn modes_to(
    forward: &Forward,
    model: &FitModel,
    count: usize,
    tolerance: f64,
) -> crate::Result<Modes> {
    let dofs = forward.support_dofs();
    match model {
        FitModel::Linear(model) => {
            let m = lanczos_modes(
                model,
                forward.masses_kg(),
                &dofs,
                &ModalSettings {
                    num_modes: count,
                    tolerance,
                    ..ModalSettings::default()
                },
            )?;
            Ok(m.modes)
        }
        FitModel::Quadratic(model) => {
            Ok(
                QuadraticSolver::new(model, forward.masses_kg().to_vec(), &dofs)?
                    .modes(model, count)?,
            )
        }
    }
}

/// Modal coordinate q(t) = φᵀ M (x̂_t − x_s) over the frames of a segment.
fn modal_coordinate(
    forward: &Forward,
    static_m: &[Vector3<f64>],
    shape: &[Vector3<f64>],
    seg: &Segment,
) -> (Vec<f64>, Vec<f64>) {
    let seq = forward.sequence();
    let masses = forward.masses_kg();
    let t: Vec<f64> = (seg.start..=seg.end)
        .map(|j| seq.times_s[j] - seq.times_s[seg.start])
        .collect();
    let q: Vec<f64> = (seg.start..=seg.end)
        .map(|j| {
            seq.positions_m[j]
                .iter()
                .zip(static_m)
                .zip(shape)
                .zip(masses)
                .map(|(((x, s), p), m)| m * p.dot(&(x - s)))
                .sum()
        })
        .collect();
    (t, q)
}

/// Residual sum of squares of the best e^{−σt}(a cos ωt + b sin ωt) + c for fixed (ω, σ).
fn sinusoid_rss(t: &[f64], q: &[f64], omega: f64, sigma: f64) -> f64 {
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut atb = Vector3::<f64>::zeros();
    let rows: Vec<Vector3<f64>> = t
        .iter()
        .map(|&ti| {
            let e = (-sigma * ti).exp();
            Vector3::new(e * (omega * ti).cos(), e * (omega * ti).sin(), 1.0)
        })
        .collect();
    for (r, &qi) in rows.iter().zip(q) {
        ata += r * r.transpose();
        atb += r * qi;
    }
    let Some(c) = ata.try_inverse().map(|i| i * atb) else {
        return f64::INFINITY;
    };
    rows.iter()
        .zip(q)
        .map(|(r, qi)| (r.dot(&c) - qi).powi(2))
        .sum()
}

/// Fits the damped sinusoid jointly to the segments' coordinates (shared ω, σ): grid over
/// ω ∈ [max(π/duration, `omega_range.0`), `omega_range.1`], then Nelder–Mead on (ω, σ). Returns
/// (ω_d, σ, explained fraction).
fn fit_damped_sinusoid(
    series: &[(Vec<f64>, Vec<f64>)],
    omega_range: (f64, f64),
) -> Option<(f64, f64, f64)> {
    let omega_max = omega_range.1;
    let total_var: f64 = series
        .iter()
        .map(|(_, q)| {
            let mean = q.iter().sum::<f64>() / q.len() as f64;
            q.iter().map(|v| (v - mean).powi(2)).sum::<f64>()
        })
        .sum();
    if total_var.is_nan() || total_var <= 0.0 {
        return None;
    }
    let duration = series
        .iter()
        .map(|(t, _)| t.last().copied().unwrap_or(0.0))
        .fold(0.0f64, f64::max);
    let omega_min = (std::f64::consts::PI / duration.max(1e-6)).max(omega_range.0);
    if omega_min >= omega_max {
        return None;
    }
    let rss =
        |w: f64, s: f64| -> f64 { series.iter().map(|(t, q)| sinusoid_rss(t, q, w, s)).sum() };
    let mut best = (f64::INFINITY, omega_min, 0.0);
    let nw = 200;
    for i in 0..nw {
        let w = omega_min * (omega_max / omega_min).powf(i as f64 / (nw - 1) as f64);
        for j in 0..12 {
            let s = w * [
                0.0, 0.005, 0.01, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3, 0.45, 0.6,
            ][j];
            let v = rss(w, s);
            if v < best.0 {
                best = (v, w, s);
            }
        }
    }
    let report = nelder_mead(
        |p| {
            if !(omega_min..=omega_max).contains(&p[0]) || p[1] < 0.0 {
                f64::INFINITY
            } else {
                rss(p[0], p[1])
            }
        },
        &[best.1, best.2.max(1e-3 * best.1)],
        None,
        &NelderMeadSettings {
            max_evaluations: 400,
            f_tolerance: 1e-14 * total_var,
            x_tolerance: 1e-9,
            ..NelderMeadSettings::default()
        },
    )
    .ok()?;
    let (w, s) = if report.value < best.0 {
        (report.params[0], report.params[1])
    } else {
        (best.1, best.2)
    };
    Some((w, s, 1.0 - rss(w, s) / total_var))
}

/// Damped-sinusoid fits of the modal coordinates of the `modes` over the free segments, sorted
/// by amplitude (the dominant first). A mode is fitted on the segments whose frame rate resolves
/// it (its model frequency below 0.8 of their Nyquist frequency; a sequence joined from a slow
/// and a fast recording measures its high modes on the fast one only). With `band` = Some(r)
/// (the model's E already matched to the dominant mode) each mode's frequency is searched within
/// a factor r of the model's, so that a weakly excited mode is not read off a stronger one's
/// leakage; with `None` over everything the frame rate resolves.
pub fn measure_modes(
    forward: &Forward,
    static_m: &[Vector3<f64>],
    modes: &Modes,
    band: Option<f64>,
) -> Vec<ModalFit> {
    let seq = forward.sequence();
    let omegas = modes.angular_frequencies_rad_s();
    // Smallest frame interval of each segment.
    let nyquist: Vec<f64> = forward
        .segments()
        .iter()
        .map(|s| {
            let dt = seq.times_s[s.start..=s.end]
                .windows(2)
                .map(|w| w[1] - w[0])
                .fold(f64::INFINITY, f64::min);
            std::f64::consts::PI / dt.max(1e-9)
        })
        .collect();
    let mut fits: Vec<ModalFit> = Vec::new();
    for (i, shape) in modes.shapes.iter().enumerate() {
        let model_omega = omegas.get(i).copied().unwrap_or(0.0);
        let resolving: Vec<usize> = (0..nyquist.len())
            .filter(|&k| model_omega <= 0.8 * nyquist[k])
            .collect();
        let Some(omega_max) = resolving
            .iter()
            .map(|&k| 0.95 * nyquist[k])
            .reduce(f64::min)
        else {
            continue;
        };
        let series: Vec<(Vec<f64>, Vec<f64>)> = resolving
            .iter()
            .map(|&k| modal_coordinate(forward, static_m, shape, &forward.segments()[k]))
            .collect();
        let n: usize = series.iter().map(|(t, _)| t.len()).sum();
        let amplitude = (series
            .iter()
            .flat_map(|(_, q)| q.iter().map(|v| v * v))
            .sum::<f64>()
            / n.max(1) as f64)
            .sqrt();
        let range = match band {
            Some(r) if model_omega > 0.0 => (model_omega / r, omega_max.min(model_omega * r)),
            _ => (0.0, omega_max),
        };
        if let Some((wd, s, explained)) = fit_damped_sinusoid(&series, range) {
            let omega = (wd * wd + s * s).sqrt();
            fits.push(ModalFit {
                mode: i,
                omega_rad_s: omega,
                zeta: s / omega,
                explained,
                amplitude,
            });
        }
    }
    fits.sort_by(|a, b| {
        b.amplitude
            .total_cmp(&a.amplitude)
            .then(a.mode.cmp(&b.mode))
    });
    fits
}

/// Rayleigh (α, β) from the damping ratios of the measured modes (module docs): the
/// least-squares solution of ζ_i = α/(2ω_i) + β ω_i/2 over the well-explained modes (variance
/// explained > 0.8), when their frequencies span a factor of 1.3 or more; else the dominant mode's ζ split evenly
/// (half from α, half from β). Two modes close in frequency (a bar's two bending directions)
/// have nearly the same ζ for a whole line of (α, β) pairs and cannot separate them: α and β
/// need a mode well above the others, such as a torsion or a second bending mode.
pub fn damping_from_modes(fits: &[ModalFit]) -> Option<RayleighDamping> {
    let good: Vec<&ModalFit> = fits.iter().filter(|f| f.explained > 0.8).collect();
    let first = good.first()?;
    let (lo, hi) = good.iter().fold((f64::INFINITY, 0.0f64), |(a, b), f| {
        (a.min(f.omega_rad_s), b.max(f.omega_rad_s))
    });
    if hi > 1.3 * lo {
        // Rows ζ_i = α/(2ω_i) + β ω_i/2.
        let mut ata = nalgebra::Matrix2::<f64>::zeros();
        let mut atb = nalgebra::Vector2::<f64>::zeros();
        for f in &good {
            let row = nalgebra::Vector2::new(0.5 / f.omega_rad_s, 0.5 * f.omega_rad_s);
            ata += row * row.transpose();
            atb += row * f.zeta;
        }
        if let Some(ab) = ata.try_inverse().map(|i| i * atb)
            && ab[0] > 0.0
            && ab[1] > 0.0
        {
            return Some(RayleighDamping {
                alpha_per_s: ab[0],
                beta_s: ab[1],
            });
        }
    }
    Some(RayleighDamping {
        alpha_per_s: (first.zeta * first.omega_rad_s).max(1e-4),
        beta_s: (first.zeta / first.omega_rad_s).max(1e-7),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mode(mode: usize, omega_rad_s: f64, d: RayleighDamping) -> ModalFit {
        ModalFit {
            mode,
            omega_rad_s,
            zeta: d.alpha_per_s / (2.0 * omega_rad_s) + d.beta_s * omega_rad_s / 2.0,
            explained: 0.99,
            amplitude: 1.0 / (mode + 1) as f64,
        }
    }

    /// Two bending modes close in frequency and a torsion mode well above them: the least
    /// squares over all three gives α and β exactly; the two bending modes alone (ω within a
    /// factor 1.3) do not try to separate them.
    #[test]
    fn rayleigh_from_modes_needs_a_mode_well_apart() {
        let truth = RayleighDamping {
            alpha_per_s: 0.8,
            beta_s: 1.0e-3,
        };
        let fits = [
            mode(0, 20.5, truth),
            mode(1, 24.0, truth),
            mode(2, 80.0, truth),
        ];
        let d = damping_from_modes(&fits).unwrap();
        assert!((d.alpha_per_s / 0.8 - 1.0).abs() < 1e-9, "{d:?}");
        assert!((d.beta_s / 1.0e-3 - 1.0).abs() < 1e-9, "{d:?}");
        // Close modes only: the dominant ζ split evenly (ζ ω from α, ζ/ω from β).
        let d = damping_from_modes(&fits[..2]).unwrap();
        let z = fits[0].zeta;
        assert!((d.alpha_per_s - z * 20.5).abs() < 1e-12 && (d.beta_s - z / 20.5).abs() < 1e-12);
    }
}
