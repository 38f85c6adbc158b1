//! `gravity-preload`: the observed rest shape is the shape sagged under gravity, not the
//! stress-free one the model starts from.
//!
//! Screen: the default model's response to the body force ρg (wang2015 eq. 7) at the reference
//! density, scaled by ρ/ρ_ref ≥ 0 — a constant offset field on every frame. Signature: the rest
//! frames' residual along gravity above 3σ. Confirmation: the default model re-simulated under
//! the measured force plus the body force of each fold's density, scored on the held-out
//! location's frames.

use super::Effect;
use super::contract::{Context, Hypothesis, param};
use crate::Result;
use crate::baseline::Prepared;
use crate::confirm::Confirmed;
use crate::recording::Recording;
use crate::residual::residuals;
use crate::screen::{Basis, Refit, Variant};
use crate::signatures::Signatures;
use crate::sim::{Field, ProbeLoad, ProbeSimulator, SimLoad};
use nalgebra::Vector3;

/// The gravity-preload hypothesis.
pub struct GravityPreload;

impl Hypothesis for GravityPreload {
    fn effect(&self) -> Effect {
        Effect::GravityPreload
    }

    fn term(&self) -> &'static str {
        "body force rho g (wang2015 eq. 7)"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let p = cx.prepared;
        if p.gravity_field_m.iter().all(|v| *v == Vector3::zeros()) {
            return vec![];
        }
        vec![Variant {
            fixed: vec![],
            offset: None,
            bases: vec![Basis {
                name: "density_per_1000_kg_m3",
                nonneg: true,
                field: vec![p.gravity_field_m.clone(); p.times_s.len()],
            }],
        }]
    }

    fn not_applicable_reason(&self) -> &'static str {
        "no gravity in the session"
    }

    fn signature_support(&self, s: &Signatures) -> f64 {
        if s.rest_gravity_m.abs() > s.three_sigma_m() {
            1.0
        } else {
            0.0
        }
    }

    /// Each fold's density applied to its own frames (held out), the full-data density for the
    /// prediction.
    fn confirm(
        &self,
        cx: &Context<'_>,
        r: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        let rho_ref = cx.settings.reference_density_kg_m3;
        let (mut e, mut n, mut ea, mut na) = (0.0, 0usize, 0.0, 0usize);
        let (mut fold_rss_m2, mut fold_n) = (Vec::new(), Vec::new());
        for (l, fp) in r.fold_params.iter().enumerate() {
            let (e0, n0) = (e, n);
            let in_l = |k: usize| seg.fold_of_frame[k] == Some(l);
            let pred = resimulate(fp, rec, p, sim, rho_ref, &in_l)?;
            for (k, row_res) in residuals(rec, &pred).iter().enumerate() {
                if seg.fold_of_frame[k] == Some(l) {
                    for (m, x) in row_res.iter().enumerate() {
                        if let Some(x) = x {
                            ea += x.norm_squared();
                            na += 1;
                            if scored(k, m) {
                                e += x.norm_squared();
                                n += 1;
                            }
                        }
                    }
                }
            }
            fold_rss_m2.push(e - e0);
            fold_n.push(n - n0);
        }
        if na == 0 {
            return Ok(None);
        }
        let prediction = resimulate(&r.params, rec, p, sim, rho_ref, &|_| true)?;
        Ok(Some(Confirmed {
            after_scored_m: (e / n.max(1) as f64).sqrt(),
            after_all_m: (ea / na as f64).sqrt(),
            params: r.params.clone(),
            prediction,
            method:
                "re-simulated with the default model under the extended load, leave-one-location-out"
                    .into(),
            fold_rss_m2,
            fold_n,
            force: None,
        }))
    }
}

/// The default model under the measured force and the body force ρg of the density in `params`
/// (`density_per_1000_kg_m3` × `rho_ref_kg_m3`) at the frames `keep` selects; the baseline
/// elsewhere.
fn resimulate(
    params: &[(String, f64)],
    rec: &Recording,
    p: &Prepared,
    sim: &mut dyn ProbeSimulator,
    rho_ref_kg_m3: f64,
    keep: &dyn Fn(usize) -> bool,
) -> Result<Field> {
    let d = param(params, "density_per_1000_kg_m3").unwrap_or(0.0);
    let body = rec.gravity_m_s2 * rho_ref_kg_m3 * d;
    let forces = &p.force_n;
    let mut out = Vec::with_capacity(rec.frames.len());
    for (k, f) in rec.frames.iter().enumerate() {
        if !keep(k) {
            out.push(p.baseline_m[k].clone());
            continue;
        }
        let probe = (forces[k].norm() > 1e-9).then_some(ProbeLoad {
            tip_m: f.tip_m,
            axis: f.axis,
            force_n: forces[k],
        });
        let o = sim.simulate(
            &SimLoad {
                probe,
                body_force_n_m3: body,
            },
            false,
        )?;
        out.push(o.markers_m);
    }
    Ok(out)
}
