//! The baseline: the default model simulated at every frame of the recording under the measured
//! force (bickel2009 §4.1 force boundary condition), with the tangent response T = ∂x/∂f of each
//! converged state, the unloaded state and the gravity response — everything the hypotheses'
//! linearised extensions are built from.

use crate::recording::Recording;
use crate::segment::Segmentation;
use crate::settings::DiagnoseSettings;
use crate::sim::{Field, LoadPoint, ProbeLoad, ProbeSimulator, SimLoad};
use crate::{DiagnoseError, Result};
use indicatif::ProgressBar;
use nalgebra::Vector3;

/// The baseline simulation and everything the extensions are built from.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// Frame times, s.
    pub times_s: Vec<f64>,
    /// Measured force per frame, N.
    pub force_n: Vec<Vector3<f64>>,
    /// Baseline marker prediction per frame, m.
    pub baseline_m: Field,
    /// Tangent response ∂x/∂f per frame (3 columns), m/N.
    pub response: Vec<[Vec<Vector3<f64>>; 3]>,
    /// Marker positions of the unloaded model, m.
    pub rest_model_m: Vec<Vector3<f64>>,
    /// Marker displacement under gravity at ρ = 1000 kg/m³, m (zeros without gravity).
    pub gravity_field_m: Vec<Vector3<f64>>,
    /// Tangential direction of the extra traction per location (unit or zero).
    pub friction_dir: Vec<Vector3<f64>>,
    /// Where the measured force acts on the default model and its response, per frame
    /// (`None` out of contact): the model's side of the force–indentation relation
    /// ([`crate::indentation`]).
    pub load_point: Vec<Option<LoadPoint>>,
}

impl Prepared {
    /// The tangent response of frame `t` to the force `v`: T(t)·v per marker, m.
    pub fn apply(&self, t: usize, v: &Vector3<f64>) -> Vec<Vector3<f64>> {
        let r = &self.response[t];
        (0..r[0].len())
            .map(|m| r[0][m] * v.x + r[1][m] * v.y + r[2][m] * v.z)
            .collect()
    }

    /// The linearised response to an extra load δf(t) per frame: T(t)·δf(t), m.
    pub fn load_field(&self, df: &[Vector3<f64>]) -> Field {
        (0..df.len()).map(|t| self.apply(t, &df[t])).collect()
    }

    /// Number of markers.
    pub fn num_markers(&self) -> usize {
        self.rest_model_m.len()
    }
}

fn tangential_dir(rec: &Recording, seg: &Segmentation, l: usize) -> Vector3<f64> {
    let loc = &seg.locations[l];
    // surface normal: the normal of the marker closest to the contact point
    let normal = rec
        .rest_markers_m
        .iter()
        .zip(&rec.normals)
        .min_by(|a, b| {
            (a.0 - loc.contact_tip_m)
                .norm()
                .total_cmp(&(b.0 - loc.contact_tip_m).norm())
        })
        .map(|x| *x.1)
        .unwrap_or_else(|| -loc.axis);
    let pt = |v: Vector3<f64>| v - normal * normal.dot(&v);
    let travel = pt(loc.peak_tip_m - loc.contact_tip_m);
    let depth = (loc.peak_tip_m - loc.contact_tip_m).norm();
    if travel.norm() > 0.2 * depth && travel.norm() > 1e-6 {
        return travel.normalize();
    }
    pt(loc.axis)
        .try_normalize(0.05)
        .unwrap_or_else(Vector3::zeros)
}

/// Runs the baseline simulation of every frame (one full solve each, with the tangent response),
/// the unloaded state and the gravity response; the frames advance `progress`.
pub fn prepare(
    rec: &Recording,
    seg: &Segmentation,
    sim: &mut dyn ProbeSimulator,
    settings: &DiagnoseSettings,
    progress: &ProgressBar,
) -> Result<Prepared> {
    let nt = rec.frames.len();
    progress.set_length(nt as u64);
    progress.set_position(0);
    progress.set_message("baseline: the default model at every frame");
    let rest = sim.simulate(&SimLoad::default(), false)?.markers_m;
    let gravity_field_m = if rec.gravity_m_s2 != Vector3::zeros() {
        let g = sim.simulate(
            &SimLoad {
                probe: None,
                body_force_n_m3: rec.gravity_m_s2 * settings.reference_density_kg_m3,
            },
            false,
        )?;
        g.markers_m.iter().zip(&rest).map(|(a, b)| a - b).collect()
    } else {
        vec![Vector3::zeros(); rest.len()]
    };
    let mut baseline_m = Vec::with_capacity(nt);
    let mut response: Vec<Option<[Vec<Vector3<f64>>; 3]>> = Vec::with_capacity(nt);
    let mut load_point = Vec::with_capacity(nt);
    for (k, f) in rec.frames.iter().enumerate() {
        if seg.phases[k].in_contact() {
            let out = sim
                .simulate(
                    &SimLoad {
                        probe: Some(ProbeLoad {
                            tip_m: f.tip_m,
                            axis: f.axis,
                            force_n: f.force_n,
                        }),
                        body_force_n_m3: Vector3::zeros(),
                    },
                    true,
                )
                .map_err(|e| match e {
                    DiagnoseError::Simulation { reason, .. } => DiagnoseError::Simulation {
                        frame: f.frame,
                        reason,
                    },
                    e => e,
                })?;
            baseline_m.push(out.markers_m);
            response.push(out.force_response);
            load_point.push(out.load_point);
        } else {
            baseline_m.push(rest.clone());
            response.push(None);
            load_point.push(None);
        }
        progress.inc(1);
    }
    // Frames without a response (out of contact) take the one of the nearest contact frame: the
    // extensions may move load there (time shift, lag).
    let have: Vec<usize> = (0..nt).filter(|&k| response[k].is_some()).collect();
    let zero = [0, 1, 2].map(|_| vec![Vector3::zeros(); rest.len()]);
    let response = (0..nt)
        .map(|k| {
            if let Some(r) = &response[k] {
                return r.clone();
            }
            have.iter()
                .min_by_key(|&&j| j.abs_diff(k))
                .and_then(|&j| response[j].clone())
                .unwrap_or_else(|| zero.clone())
        })
        .collect();
    let friction_dir = (0..seg.num_folds())
        .map(|l| tangential_dir(rec, seg, l))
        .collect();
    Ok(Prepared {
        times_s: rec.times_s(),
        force_n: rec.frames.iter().map(|f| f.force_n).collect(),
        baseline_m,
        response,
        rest_model_m: rest,
        gravity_field_m,
        friction_dir,
        load_point,
    })
}
