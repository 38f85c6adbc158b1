//! The effect catalog: the physics a default model may leave out (issue 8, names exact).

use serde::{Deserialize, Serialize};

/// A catalog entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Effect {
    /// Rate dependence and creep (generalized Maxwell / Prony).
    Viscoelasticity,
    /// Plastic set.
    Plasticity,
    /// Gravity pre-load: rest shape ≠ observed shape.
    GravityPreload,
    /// Tangential traction under the probe.
    ProbeFriction,
    /// The object slides on its support.
    SupportSlip,
    /// Camera–force clock offset.
    ClockOffset,
    /// Force sensor lag.
    SensorLag,
    /// Anisotropy (transversely isotropic stiffening).
    Anisotropy,
    /// Inertia and damping.
    InertiaDamping,
}

impl Effect {
    /// The catalog, in issue order.
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

    /// The catalog name (issue 8, exact).
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
        }
    }

    /// Parses a catalog name.
    pub fn from_name(s: &str) -> Option<Self> {
        Self::CATALOG.into_iter().find(|h| h.name() == s)
    }
}
