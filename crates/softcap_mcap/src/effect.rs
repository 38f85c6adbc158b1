//! The effect catalog: the physics a default model may leave out, as the virtual rig conceals it
//! and the diagnosis names it.
//!
//! One definition where the stages meet (like [`crate::capture::Phase`]): `softcap synth`
//! switches effects on by these names (`effects = ["viscoelasticity"]` in a scenario, and
//! `truth/README.md`), `softcap diagnose` has one hypothesis per [`Effect::CATALOG`] entry and
//! writes [`Effect::name`] as its verdict. The two controls ([`Effect::is_control`]) are
//! heterogeneity and nonlinearity the base model already represents: a rig can conceal them, a
//! diagnosis never names them.

use serde::{Deserialize, Serialize};

/// One effect; serialized by its kebab-case [`Effect::name`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Effect {
    /// Rate dependence: creep / relaxation during holds (generalized Maxwell, Prony series).
    Viscoelasticity,
    /// Permanent set after a location is released.
    Plasticity,
    /// Gravity pre-load: the observed template is the shape sagged under gravity, not the
    /// stress-free rest shape.
    GravityPreload,
    /// Tangential (Coulomb) traction under a tilted probe.
    ProbeFriction,
    /// The attached face slides on its support plane.
    SupportSlip,
    /// A time shift between the force and the camera clocks.
    ClockOffset,
    /// Force sensor first-order lag and hysteresis.
    SensorLag,
    /// Anisotropy (transversely isotropic stiffening).
    Anisotropy,
    /// Inertia and damping: a dynamic, not quasi-static, response.
    InertiaDamping,
    /// Control: a stiff spherical inclusion in an otherwise homogeneous block.
    StiffInclusion,
    /// Control: strain stiffening (second-order Yeoh term).
    StrainStiffening,
}

impl Effect {
    /// Every effect, catalog first, then the controls.
    pub const ALL: [Effect; 11] = [
        Effect::Viscoelasticity,
        Effect::Plasticity,
        Effect::GravityPreload,
        Effect::ProbeFriction,
        Effect::SupportSlip,
        Effect::ClockOffset,
        Effect::SensorLag,
        Effect::Anisotropy,
        Effect::InertiaDamping,
        Effect::StiffInclusion,
        Effect::StrainStiffening,
    ];

    /// The missing-physics catalog a diagnosis names from (issue 8 order): [`Effect::ALL`]
    /// without the controls.
    pub const CATALOG: [Effect; 9] = [
        Effect::Viscoelasticity,
        Effect::Plasticity,
        Effect::GravityPreload,
        Effect::ProbeFriction,
        Effect::SupportSlip,
        Effect::ClockOffset,
        Effect::SensorLag,
        Effect::Anisotropy,
        Effect::InertiaDamping,
    ];

    /// The kebab-case name used in scenario files, `truth/README.md` and diagnosis outputs.
    pub fn name(self) -> &'static str {
        match self {
            Effect::Viscoelasticity => "viscoelasticity",
            Effect::Plasticity => "plasticity",
            Effect::GravityPreload => "gravity-preload",
            Effect::ProbeFriction => "probe-friction",
            Effect::SupportSlip => "support-slip",
            Effect::ClockOffset => "clock-offset",
            Effect::SensorLag => "sensor-lag",
            Effect::Anisotropy => "anisotropy",
            Effect::InertiaDamping => "inertia-damping",
            Effect::StiffInclusion => "stiff-inclusion",
            Effect::StrainStiffening => "strain-stiffening",
        }
    }

    /// The catalog entry named `s` ([`Effect::CATALOG`] only: a control is not a diagnosis).
    pub fn from_name(s: &str) -> Option<Self> {
        Self::CATALOG.into_iter().find(|e| e.name() == s)
    }

    /// True for the controls (heterogeneity / nonlinearity the base model can represent through
    /// its per-element, strain-dependent material).
    pub fn is_control(self) -> bool {
        matches!(self, Effect::StiffInclusion | Effect::StrainStiffening)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_through_serde_and_the_catalog_excludes_the_controls() {
        for e in Effect::ALL {
            let json = serde_json::to_string(&e).unwrap();
            assert_eq!(json, format!("\"{}\"", e.name()));
            assert_eq!(serde_json::from_str::<Effect>(&json).unwrap(), e);
            assert_eq!(Effect::from_name(e.name()).is_some(), !e.is_control());
        }
        assert_eq!(
            Effect::CATALOG.to_vec(),
            Effect::ALL
                .into_iter()
                .filter(|e| !e.is_control())
                .collect::<Vec<_>>()
        );
        assert_eq!(Effect::from_name("friction"), None);
    }
}
