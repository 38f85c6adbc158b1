//! The hypotheses: one module per catalog entry, each implementing [`Hypothesis`] — its screen
//! (a linearised extension, [`crate::screen`]), where its effect lives, how its signature reads,
//! its confirmation by re-simulating the extended model ([`crate::resim`], [`crate::confirm`])
//! and what the report says about it.
//!
//! | entry | module | screen: extra load / field | parameters | confirmed by re-simulating |
//! |---|---|---|---|---|
//! | viscoelasticity | [`viscoelasticity`] | creep (standard linear solid): f_eff = f + a f + g·LP_τ(f) | τ (grid), a, g ≥ 0 | one Prony branch (Simo & Hughes §10.3) under the measured force; hold-fit ridge on the refined mesh |
//! | plasticity | [`plasticity`] | permanent set ∝ elastic response at each location's peak, above a yield force | f_y (grid), β ≥ 0 | J2 plasticity (Box 3.1–3.2), force-driven and as a rigid-tip replay on the refined mesh |
//! | gravity-preload | [`gravity_preload`] | gravity body-force response of density ρ (wang2015 eq. 7) | ρ ≥ 0 | the default model under ρg, per fold |
//! | probe-friction | [`probe_friction`] | tangential traction μ‖f‖ŝ at the contact patch, or sliding along the travel ([`crate::friction`]) | μ | Coulomb traction of the tip's travel; rigid-tip replay with Coulomb friction |
//! | support-slip | [`support_slip`] | rigid translation c·P_t f (elastic) + c_p·P_t f at the running max (stick-slip) | c, c_p ≥ 0 | tangential support springs, the material refitted with them |
//! | clock-offset | [`clock_offset`] | force trace shifted in time: f_eff(t) = f(t + δ) | δ (grid) | the shifted force, material refitted |
//! | sensor-lag | [`sensor_lag`] | FSR chain, first order: f_true = f + τ ḟ + h sgn(ḟ) f | τ, h ≥ 0 | the inverse FSR chain ([`crate::sensor`]), material refitted |
//! | anisotropy | [`anisotropy`] | displacement along a fibre direction a scaled: −κ a (a·u₀) | a (13 directions), κ | transversely isotropic model (thesis eq. 8.5) |
//! | inertia-damping | [`inertia_damping`] | M ü + C u̇: x = x₀ − c u̇₀ − m ü₀ | c ≥ 0, m ≥ 0 | implicit dynamics M ü + (αM + βK) u̇ + f(u) = f_ext under the measured force (wang2015 eq. 3), ρ, α, β fitted per fold by a compass search |
//!
//! [`crate::diagnose`](mod@crate::diagnose) runs them all through the same phases; nothing outside
//! this folder knows an entry by name except through [`Hypothesis::effect`]. A new entry is its
//! module and, in this file, its `mod` line, its [`Effect`] variant and name and its line in
//! [`catalog()`].

pub mod anisotropy;
pub mod clock_offset;
mod contract;
mod force_channel;
pub mod gravity_preload;
pub mod inertia_damping;
pub mod plasticity;
pub mod probe_friction;
pub mod sensor_lag;
pub mod support_slip;
pub mod viscoelasticity;

pub use contract::{Context, Hypothesis, SignatureRoute};

/// Every catalog entry, in catalog order ([`Effect::CATALOG`]).
pub fn catalog() -> [&'static dyn Hypothesis; 9] {
    [
        &viscoelasticity::Viscoelasticity,
        &plasticity::Plasticity,
        &gravity_preload::GravityPreload,
        &probe_friction::ProbeFriction,
        &support_slip::SupportSlip,
        &clock_offset::ClockOffset,
        &sensor_lag::SensorLag,
        &anisotropy::Anisotropy,
        &inertia_damping::InertiaDamping,
    ]
}

/// The hypothesis of catalog entry `effect`.
pub fn of(effect: Effect) -> Option<&'static dyn Hypothesis> {
    catalog().into_iter().find(|h| h.effect() == effect)
}

/// A catalog entry: the physics a default model may leave out (issue 8, names exact). One
/// definition shared with the virtual rig, in the format crate where the stages meet.
pub use softcap_mcap::Effect;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_catalog_holds_every_entry_once_in_order() {
        let effects: Vec<Effect> = catalog().iter().map(|h| h.effect()).collect();
        assert_eq!(effects, Effect::CATALOG);
        for e in Effect::CATALOG {
            assert_eq!(of(e).map(|h| h.effect()), Some(e));
        }
    }
}
