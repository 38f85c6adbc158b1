//! `support-slip`: the object slides on its support instead of being bonded to it.
//!
//! Screen: a rigid translation of the whole body along the support plane, c·P_t f (elastic) +
//! c_p·P_t f at the running maximum (stick-slip), c, c_p ≥ 0 (P_t the projection on the support
//! plane, or on the plane across gravity without a support). Effect cells: contact frames,
//! markers away from the active contact. Signature: the attached markers move in contact, or the
//! markers away from the probe follow an oblique push
//! ([`crate::signatures::far_field_push`]), above 3σ. Confirmation: the default model on a `softcap_fem::SupportPlane` with tangential springs
//! under the attached face instead of fixed nodes, the total stiffness k on a √2 log grid around
//! the indentation stiffness (the compliance scale d makes the family (material stiffness / d,
//! k / d)).

use super::Effect;
use super::contract::{Context, Hypothesis};
use crate::Result;
use crate::cells::{EffectCells, contact_cells};
use crate::confirm::{ComplianceScale, Confirmed};
use crate::recording::Recording;
use crate::resim::{GridPoint, Replays};
use crate::screen::{Basis, Refit, Variant};
use crate::segment::Segmentation;
use crate::signatures::Signatures;
use crate::sim::{Extension, ProbeSimulator};
use nalgebra::Vector3;

/// The support-slip hypothesis.
pub struct SupportSlip;

/// Name of the effect cells.
const CELLS: &str = "contact/away-from-probe";

impl Hypothesis for SupportSlip {
    fn effect(&self) -> Effect {
        Effect::SupportSlip
    }

    fn term(&self) -> &'static str {
        "rigid support translation slip_compliance P_t f + stick_slip_compliance P_t f_max"
    }

    fn variants(&self, cx: &Context<'_>) -> Vec<Variant> {
        let (rec, p) = (cx.rec, cx.prepared);
        let f = &p.force_n;
        let (nt, nm) = (p.times_s.len(), p.num_markers());
        let n = match (&rec.support, rec.gravity_dir()) {
            (Some(s), _) => s.normal,
            (None, g) if g != Vector3::zeros() => g,
            _ => return vec![],
        };
        let pt = |v: &Vector3<f64>| v - n * n.dot(v);
        let mut elastic = Vec::with_capacity(nt);
        let mut stick = Vec::with_capacity(nt);
        let mut best = Vector3::zeros();
        for k in 0..nt {
            let ft = pt(&f[k]);
            if ft.norm() > best.norm() {
                best = ft;
            }
            elastic.push(vec![ft; nm]);
            stick.push(vec![best; nm]);
        }
        vec![Variant {
            fixed: vec![],
            offset: None,
            bases: vec![
                Basis {
                    name: "slip_compliance_m_per_n",
                    nonneg: true,
                    field: elastic,
                },
                Basis {
                    name: "stick_slip_compliance_m_per_n",
                    nonneg: true,
                    field: stick,
                },
            ],
        }]
    }

    fn not_applicable_reason(&self) -> &'static str {
        "no support plane and no gravity direction"
    }

    fn effect_cells(&self, rec: &Recording, seg: &Segmentation) -> Option<EffectCells> {
        Some(EffectCells {
            name: CELLS,
            mask: contact_cells(rec, seg, false),
        })
    }

    fn signature_support(&self, s: &Signatures) -> f64 {
        if s.attached_motion_m > s.three_sigma_m() || s.far_field_push_m > s.three_sigma_m() {
            1.0
        } else {
            -1.0
        }
    }

    fn confirm(
        &self,
        cx: &Context<'_>,
        _: &Refit,
        scored: &dyn Fn(usize, usize) -> bool,
        sim: &mut dyn ProbeSimulator,
    ) -> Result<Option<Confirmed>> {
        let (rec, seg, p) = (cx.rec, cx.seg, cx.prepared);
        // the indentation stiffness: peak force over the deepest travel from first contact
        let depth_m = seg
            .locations
            .iter()
            .map(|l| (l.peak_tip_m - l.contact_tip_m).norm())
            .fold(0.0, f64::max)
            .max(1e-5);
        let k_ind = seg.peak_force_n() / depth_m;
        // Slip ≈ rigid translation F_t / k: a log grid in steps of √2 around k_ind.
        let grid: Vec<GridPoint> = (-6..=4)
            .map(|i| {
                let k = k_ind * 2f64.powf(0.5 * i as f64);
                (
                    vec![("support_tangential_stiffness_n_per_m".into(), k)],
                    Extension::SupportSprings {
                        stiffness_n_per_m: k,
                    },
                    p.force_n.clone(),
                )
            })
            .collect();
        let replays = Replays::run(sim, grid, Vec::new(), rec, seg, p, false)?;
        replays.confirm(
            rec,
            seg,
            p,
            ComplianceScale::new(true, 0.1, 10.0),
            scored,
            false,
            "SupportPlane springs",
            CELLS,
        )
    }
}
