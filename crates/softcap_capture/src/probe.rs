//! Probe pose from the shaft markers and FSR voltage → force (bickel2009 §5, thesis §6.2.1).

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::session::FsrConfig;

/// How FSR voltages are converted to force.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum FsrConversion {
    /// Monotone piecewise-cubic (Fritsch–Carlson PCHIP) interpolation of the calibration table.
    #[default]
    MonotoneInterpolation,
    /// Least-squares fit of the FSR law `R = k·F^(−n)` through the divider equation.
    PowerLaw,
}

/// Voltage → force map built from `rig/fsr.toml`.
#[derive(Debug, Clone, PartialEq)]
pub enum FsrModel {
    /// PCHIP through `(voltage_v, force_n)` knots with slopes `m`.
    Interpolated {
        /// Knot voltages, increasing.
        voltage_v: Vec<f64>,
        /// Knot forces.
        force_n: Vec<f64>,
        /// Knot slopes dF/dV.
        slope: Vec<f64>,
    },
    /// `R_fsr = k·F^(−n)`, `v = supply·divider/(divider + R_fsr)`.
    PowerLaw {
        /// Supply, V.
        supply_v: f64,
        /// Divider, ohm.
        divider_ohm: f64,
        /// Coefficient k, ohm·N^n.
        k: f64,
        /// Exponent n.
        n: f64,
    },
}

impl FsrModel {
    /// Builds the model from the calibration table (already checked to increase in both columns).
    pub fn new(cfg: &FsrConfig, conversion: FsrConversion) -> Self {
        match conversion {
            FsrConversion::MonotoneInterpolation => {
                let v: Vec<f64> = cfg.calibration.iter().map(|p| p[1]).collect();
                let f: Vec<f64> = cfg.calibration.iter().map(|p| p[0]).collect();
                let slope = pchip_slopes(&v, &f);
                FsrModel::Interpolated {
                    voltage_v: v,
                    force_n: f,
                    slope,
                }
            }
            FsrConversion::PowerLaw => {
                // log R = log k − n log F over points with F > 0 and 0 < v < supply, weighted
                // least squares: a relative voltage error ε moves log R by ε·S/(S − v), so each
                // point gets the weight ((S − v)/S)².
                let pts: Vec<(f64, f64, f64)> = cfg
                    .calibration
                    .iter()
                    .filter(|p| p[0] > 0.0 && p[1] > 0.0 && p[1] < cfg.supply_v)
                    .map(|p| {
                        let w = ((cfg.supply_v - p[1]) / cfg.supply_v).powi(2);
                        (
                            p[0].ln(),
                            (cfg.divider_ohm * (cfg.supply_v - p[1]) / p[1]).ln(),
                            w,
                        )
                    })
                    .collect();
                let sw: f64 = pts.iter().map(|p| p.2).sum();
                let (mx, my) = pts.iter().fold((0.0, 0.0), |a, p| {
                    (a.0 + p.2 * p.0 / sw, a.1 + p.2 * p.1 / sw)
                });
                let (sxy, sxx) = pts.iter().fold((0.0, 0.0), |a, p| {
                    (
                        a.0 + p.2 * (p.0 - mx) * (p.1 - my),
                        a.1 + p.2 * (p.0 - mx).powi(2),
                    )
                });
                let slope = if sxx > 0.0 { sxy / sxx } else { -1.0 };
                FsrModel::PowerLaw {
                    supply_v: cfg.supply_v,
                    divider_ohm: cfg.divider_ohm,
                    k: (my - slope * mx).exp(),
                    n: -slope,
                }
            }
        }
    }

    /// Force (N, ≥ 0) for a divider voltage.
    pub fn force_n(&self, v: f64) -> f64 {
        match self {
            FsrModel::Interpolated {
                voltage_v,
                force_n,
                slope,
            } => {
                let n = voltage_v.len();
                if v <= voltage_v[0] {
                    return force_n[0].max(0.0);
                }
                if v >= voltage_v[n - 1] {
                    return (force_n[n - 1] + slope[n - 1] * (v - voltage_v[n - 1])).max(0.0);
                }
                let i = voltage_v.partition_point(|&x| x <= v) - 1;
                let h = voltage_v[i + 1] - voltage_v[i];
                let t = (v - voltage_v[i]) / h;
                let (h00, h10, h01, h11) = (
                    (1.0 + 2.0 * t) * (1.0 - t).powi(2),
                    t * (1.0 - t).powi(2),
                    t * t * (3.0 - 2.0 * t),
                    t * t * (t - 1.0),
                );
                (h00 * force_n[i]
                    + h10 * h * slope[i]
                    + h01 * force_n[i + 1]
                    + h11 * h * slope[i + 1])
                    .max(0.0)
            }
            FsrModel::PowerLaw {
                supply_v,
                divider_ohm,
                k,
                n,
            } => {
                if v <= 0.0 {
                    return 0.0;
                }
                let r = divider_ohm * (supply_v - v).max(1e-12) / v;
                (k / r).powf(1.0 / n)
            }
        }
    }
}

/// Fritsch–Carlson monotone slopes (Fritsch & Carlson 1980; as in SciPy's `PchipInterpolator`).
fn pchip_slopes(x: &[f64], y: &[f64]) -> Vec<f64> {
    let n = x.len();
    let h: Vec<f64> = (0..n - 1).map(|i| x[i + 1] - x[i]).collect();
    let d: Vec<f64> = (0..n - 1).map(|i| (y[i + 1] - y[i]) / h[i]).collect();
    let mut m = vec![0.0; n];
    if n == 2 {
        return vec![d[0], d[0]];
    }
    for i in 1..n - 1 {
        if d[i - 1] * d[i] > 0.0 {
            let (w1, w2) = (2.0 * h[i] + h[i - 1], h[i] + 2.0 * h[i - 1]);
            m[i] = (w1 + w2) / (w1 / d[i - 1] + w2 / d[i]);
        }
    }
    let end = |h0: f64, h1: f64, d0: f64, d1: f64| {
        let s = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1);
        if s.signum() != d0.signum() {
            0.0
        } else if d0.signum() != d1.signum() && s.abs() > 3.0 * d0.abs() {
            3.0 * d0
        } else {
            s
        }
    };
    m[0] = end(h[0], h[1], d[0], d[1]);
    m[n - 1] = end(h[n - 2], h[n - 3], d[n - 2], d[n - 3]);
    m
}

/// Probe pose at one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbePose {
    /// Tip centre (disk face centre / sphere contact point), world, m.
    pub tip_m: Point3<f64>,
    /// Unit shaft axis pointing from the shaft markers toward the tip (the pushing direction).
    pub axis: Vector3<f64>,
}

/// Probe pose from two shaft markers at distances `d_near < d_far` from the tip:
/// `axis = (p_near − p_far)/|p_near − p_far|`, `tip = p_near + d_near·axis`.
pub fn probe_pose(p_near: &Point3<f64>, d_near_m: f64, p_far: &Point3<f64>) -> Option<ProbePose> {
    let d = p_near - p_far;
    let len = d.norm();
    (len > 1e-9).then(|| {
        let axis = d / len;
        ProbePose {
            tip_m: p_near + axis * d_near_m,
            axis,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> FsrConfig {
        // Exact divider + power law R = 9168 F^-0.9.
        let law = |f: f64| {
            if f <= 0.0 {
                0.0
            } else {
                5.0 * 1e4 / (1e4 + 9168.0 * f.powf(-0.9))
            }
        };
        FsrConfig {
            supply_v: 5.0,
            divider_ohm: 1e4,
            calibration: [0.0, 0.05, 0.1, 0.2, 0.4, 0.8, 1.2, 1.6, 2.0]
                .iter()
                .map(|&f| [f, law(f)])
                .collect(),
        }
    }

    #[test]
    fn interpolation_passes_through_knots_and_is_monotone() {
        let c = cfg();
        let m = FsrModel::new(&c, FsrConversion::MonotoneInterpolation);
        for p in &c.calibration {
            assert!((m.force_n(p[1]) - p[0]).abs() < 1e-12);
        }
        let mut prev = -1.0;
        for i in 0..=400 {
            let f = m.force_n(i as f64 * 0.01);
            assert!(f >= prev - 1e-12);
            prev = f;
        }
    }

    #[test]
    fn power_law_recovers_the_generating_law() {
        let m = FsrModel::new(&cfg(), FsrConversion::PowerLaw);
        let FsrModel::PowerLaw { k, n, .. } = m else {
            panic!()
        };
        assert!(
            (k - 9168.0).abs() < 1e-6 * 9168.0 && (n - 0.9).abs() < 1e-9,
            "{k} {n}"
        );
        let v = 5.0 * 1e4 / (1e4 + 9168.0 * 1.3f64.powf(-0.9));
        assert!((m.force_n(v) - 1.3).abs() < 1e-9);
    }

    #[test]
    fn pose_from_vertical_shaft() {
        let p = probe_pose(
            &Point3::new(0.0, 0.0, 0.086),
            0.06,
            &Point3::new(0.0, 0.0, 0.146),
        )
        .unwrap();
        assert!((p.tip_m - Point3::new(0.0, 0.0, 0.026)).norm() < 1e-12);
        assert!((p.axis - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
    }
}
