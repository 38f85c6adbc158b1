//! `inertia-damping`: the response is dynamic, not quasi-static — M ü + C u̇ act on the body.
//!
//! Screen: x = x₀ − c u̇₀ − m ü₀ with the baseline's marker velocity and acceleration (central
//! differences over the frame times), c, m ≥ 0. No signature and no extended FEM model: the
//! verdict rests on the linearised screen.

use super::Effect;
use super::contract::{Context, Hypothesis};
use crate::Result;
use crate::confirm::Confirmed;
use crate::screen::{Basis, Refit, Variant};
use crate::signal::derivative;
use crate::signatures::Signatures;
use crate::sim::{Field, ProbeSimulator};
use nalgebra::Vector3;

/// The inertia-damping hypothesis.
pub struct InertiaDamping;

impl Hypothesis for InertiaDamping {
    fn effect(&self) -> Effect {
        Effect::InertiaDamping
    }

    fn term(&self) -> &'static str {
        "x = x0 - damping_s dx0/dt - mass_s2 d2x0/dt2"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let p = cx.prepared;
        let t = &p.times_s;
        let (nt, nm) = (t.len(), p.num_markers());
        let per_marker: Vec<Vec<Vector3<f64>>> = (0..nm)
            .map(|m| (0..nt).map(|k| p.baseline_m[k][m]).collect())
            .collect();
        let v: Vec<Vec<Vector3<f64>>> = per_marker.iter().map(|x| derivative(t, x)).collect();
        let a: Vec<Vec<Vector3<f64>>> = v.iter().map(|x| derivative(t, x)).collect();
        let tr = |g: &Vec<Vec<Vector3<f64>>>| -> Field {
            (0..nt)
                .map(|k| (0..nm).map(|m| -g[m][k]).collect())
                .collect()
        };
        vec![Variant {
            fixed: vec![],
            offset: None,
            bases: vec![
                Basis {
                    name: "damping_s",
                    nonneg: true,
                    field: tr(&v),
                },
                Basis {
                    name: "mass_s2",
                    nonneg: true,
                    field: tr(&a),
                },
            ],
        }]
    }

    fn signature_support(&self, _: &Signatures) -> f64 {
        0.0
    }

    /// No extended FEM model: linearised only.
    fn confirm(
        &self,
        _: &Context<'_>,
        _: &Refit,
        _: &dyn Fn(usize, usize) -> bool,
        _: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        Ok(None)
    }
}
