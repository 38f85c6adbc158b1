//! Registration weights of thesis §6.2.2 (markers away from the probe count more); the weighted
//! absolute orientation itself is [`softcap_core::rigid::horn_weighted`] (Horn 1987).

pub use softcap_core::rigid::horn_weighted;

/// Registration weight of a marker at distance `d` from the probe tip: `1 − exp(−(d/σ)²)`,
/// small near the probe where the object deforms, → 1 far from it.
pub fn weight_away_from_probe(distance_m: f64, sigma_m: f64) -> f64 {
    1.0 - (-(distance_m / sigma_m).powi(2)).exp()
}
