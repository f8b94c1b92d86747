//! The order picks are handed out in, and how far apart they must lie: a cell controller wants
//! its next pick on another object (or at least clearly elsewhere), not the same grasp a few
//! millimetres over.
use nalgebra::Point3;
use psgrasp_geometry::{BinModel, GraspConfiguration};
use serde::{Deserialize, Serialize};

/// Which picks come first ([`crate::SelectionConfig::pick_order`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PickOrder {
    /// Highest antipodal quality first (the paper's order).
    #[default]
    Quality,
    /// Highest grasp centre first: clears a pile from the top.
    Topmost,
    /// Grasp centre nearest the middle of the bin floor (in plan view) first: away from the
    /// walls.
    CentreFirst,
    /// Antipodal quality times the baseline's confidence: the probability, under the predicted
    /// Power-Spherical distribution PS(ν, κ), that the true baseline lies within
    /// [`crate::SelectionConfig::baseline_tolerance_deg`] of ν ([`baseline_confidence`]).
    /// Configurations without a distribution (κ ≤ 0: analytic, VGN-style, oracle) keep their
    /// quality, and a constant κ (the wo κ ablation) keeps the quality order.
    ConfidentQuality,
    /// Configurations whose concentration κ lies above their floor first (the model card's κ0
    /// that each configuration carries, [`GraspConfiguration::kappa_floor`], or
    /// [`crate::SelectionConfig::confident_kappa_above`] where set), each tier by antipodal
    /// quality: a κ clamped at its floor is the network saying it does not know the baseline,
    /// and such picks hold less often. Configurations without a distribution (κ = floor = 0) and
    /// a constant κ (the wo κ ablation, κ = κ0 everywhere) all fall in one tier and keep the
    /// quality order.
    ConfidentFirst,
}

/// The order's parameters taken from [`crate::SelectionConfig`] once per selection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrderSettings {
    /// cos(tolerance / 2) for [`PickOrder::ConfidentQuality`].
    pub cos_half_tolerance: f32,
    /// κ strictly above this is confident for [`PickOrder::ConfidentFirst`]; `None`: above the
    /// configuration's own [`GraspConfiguration::kappa_floor`].
    pub confident_kappa_above: Option<f32>,
}

impl PickOrder {
    /// The priority of configuration `c` in `bin` (higher first; not finite → last).
    pub fn priority(self, c: &GraspConfiguration, bin: &BinModel, settings: OrderSettings) -> f32 {
        let p = grasp_centre(c);
        let v = match self {
            PickOrder::Quality => c.quality,
            PickOrder::ConfidentQuality => {
                c.quality * baseline_confidence(c.kappa, settings.cos_half_tolerance)
            }
            // Quality lies in [0, 1], so the confident tier's priorities lie above all others.
            PickOrder::ConfidentFirst => {
                let floor = settings.confident_kappa_above.unwrap_or(c.kappa_floor);
                let tier = if c.kappa > floor { CONFIDENT_TIER } else { 0.0 };
                tier + c.quality
            }
            PickOrder::Topmost => p.z,
            PickOrder::CentreFirst => -(p.x - bin.floor_center.x).hypot(p.y - bin.floor_center.y),
        };
        if v.is_finite() {
            v
        } else {
            f32::NEG_INFINITY
        }
    }
}

/// What [`PickOrder::ConfidentFirst`] adds to a confident configuration's quality (qualities lie
/// in [0, 1]).
const CONFIDENT_TIER: f32 = 2.0;

/// P(angle(x, ν) ≤ θ) for x ~ PS(ν, κ) on S², with `cos_half_tolerance` = cos(θ/2): the
/// marginal of t = ν·x has density ∝ (1 + t)^κ on [−1, 1], so the probability is
/// 1 − ((1 + cos θ)/2)^(κ+1) = 1 − cos²(θ/2)^(κ+1). κ ≤ 0 (no distribution) gives 1.
pub fn baseline_confidence(kappa: f32, cos_half_tolerance: f32) -> f32 {
    if kappa > 0.0 {
        1.0 - (cos_half_tolerance * cos_half_tolerance).powf(kappa + 1.0)
    } else {
        1.0
    }
}

/// The TCP of every grasp of `c`, whatever its approach: midway between the two contacts.
pub fn grasp_centre(c: &GraspConfiguration) -> Point3<f32> {
    c.contact + c.baseline * (0.5 * c.width)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn settings(cos_half_tolerance: f32) -> OrderSettings {
        OrderSettings {
            cos_half_tolerance,
            confident_kappa_above: None,
        }
    }

    fn at(x: f32, y: f32, z: f32, quality: f32) -> GraspConfiguration {
        GraspConfiguration {
            contact: Point3::new(x, y, z),
            baseline: Vector3::x(),
            collision_scores: [1.0; psgrasp_geometry::N_APPROACHES],
            width: 0.04,
            quality,
            kappa: 0.0,
            kappa_floor: 0.0,
        }
    }

    #[test]
    fn each_order_ranks_by_its_own_key() {
        let bin = BinModel::default();
        let c = bin.floor_center;
        let high_poor = at(c.x + 0.1, c.y, c.z + 0.2, 0.6);
        let low_good_central = at(c.x - 0.02, c.y, c.z + 0.05, 0.9);
        let p = |o: PickOrder, g: &GraspConfiguration| o.priority(g, &bin, settings(0.98));
        assert!(p(PickOrder::Quality, &low_good_central) > p(PickOrder::Quality, &high_poor));
        assert!(p(PickOrder::Topmost, &high_poor) > p(PickOrder::Topmost, &low_good_central));
        assert!(
            p(PickOrder::CentreFirst, &low_good_central) > p(PickOrder::CentreFirst, &high_poor)
        );
        assert_eq!(grasp_centre(&low_good_central).x, c.x);
        let nan = at(f32::NAN, f32::NAN, f32::NAN, f32::NAN);
        for o in [
            PickOrder::Quality,
            PickOrder::Topmost,
            PickOrder::CentreFirst,
            PickOrder::ConfidentQuality,
            PickOrder::ConfidentFirst,
        ] {
            assert_eq!(o.priority(&nan, &bin, settings(0.98)), f32::NEG_INFINITY);
        }
    }

    #[test]
    fn baseline_confidence_is_the_power_spherical_mass_within_the_tolerance() {
        let theta = 20f32.to_radians();
        let cos_half = (0.5 * theta).cos();
        // κ → 0: uniform on the sphere, the cap's share (1 − cos θ)/2.
        let uniform = baseline_confidence(1e-6, cos_half);
        assert!(
            (uniform - 0.5 * (1.0 - theta.cos())).abs() < 1e-5,
            "{uniform}"
        );
        // κ = 25, 60: numerical integration of the marginal density (1 + t)^κ.
        for kappa in [25.0f64, 60.0] {
            let n = 200_000;
            let mass = |lo: f64| {
                let h = (1.0 - lo) / n as f64;
                (0..n)
                    .map(|i| (1.0 + lo + (i as f64 + 0.5) * h).powf(kappa) * h)
                    .sum::<f64>()
            };
            let expected = mass((theta as f64).cos()) / mass(-1.0);
            let got = baseline_confidence(kappa as f32, cos_half) as f64;
            assert!(
                (got - expected).abs() < 1e-4,
                "κ {kappa}: {got} vs {expected}"
            );
        }
        // More concentrated: more mass inside; no distribution: no discount.
        assert!(baseline_confidence(100.0, cos_half) > baseline_confidence(25.0, cos_half));
        assert_eq!(baseline_confidence(0.0, cos_half), 1.0);
    }

    #[test]
    fn confident_quality_ranks_by_quality_times_confidence() {
        let bin = BinModel::default();
        let c = bin.floor_center;
        let cos_half = 10f32.to_radians().cos();
        let with = |q: f32, kappa: f32| GraspConfiguration {
            kappa,
            ..at(c.x, c.y, c.z + 0.05, q)
        };
        let p = |g: &GraspConfiguration| {
            PickOrder::ConfidentQuality.priority(g, &bin, settings(cos_half))
        };
        // Same quality: the sharper baseline first.
        assert!(p(&with(0.8, 80.0)) > p(&with(0.8, 25.0)));
        // A slightly lower quality with a far sharper baseline wins; a much lower one does not.
        assert!(p(&with(0.75, 100.0)) > p(&with(0.8, 25.0)));
        assert!(p(&with(0.4, 100.0)) < p(&with(0.8, 25.0)));
        // One κ for all (the wo κ ablation) or none (analytic, VGN, oracle): the quality order.
        assert!(p(&with(0.9, 25.0)) > p(&with(0.8, 25.0)));
        assert_eq!(p(&with(0.7, 0.0)), 0.7);
    }

    #[test]
    fn confident_first_puts_every_kappa_above_the_floor_before_the_floor() {
        let bin = BinModel::default();
        let c = bin.floor_center;
        // As the learned backend sends them: κ with the card's floor κ0 = 25.
        let with = |q: f32, kappa: f32| GraspConfiguration {
            kappa,
            kappa_floor: 25.0,
            ..at(c.x, c.y, c.z + 0.05, q)
        };
        let p =
            |g: &GraspConfiguration| PickOrder::ConfidentFirst.priority(g, &bin, settings(0.98));
        // Just above the floor beats the best quality at the floor.
        assert!(p(&with(0.51, 25.01)) > p(&with(1.0, 25.0)));
        // Within a tier, quality decides.
        assert!(p(&with(0.9, 26.0)) > p(&with(0.8, 90.0)));
        assert!(p(&with(0.9, 25.0)) > p(&with(0.8, 25.0)));
        // Each configuration's own floor: a model with κ0 = 10 is confident at 12.
        let low_floor = |q: f32, kappa: f32| GraspConfiguration {
            kappa_floor: 10.0,
            ..with(q, kappa)
        };
        assert!(p(&low_floor(0.51, 12.0)) > p(&low_floor(1.0, 10.0)));
        // The setting, where given, overrides the configurations' floors.
        let fixed = OrderSettings {
            confident_kappa_above: Some(30.0),
            ..settings(0.98)
        };
        let q = |g: &GraspConfiguration| PickOrder::ConfidentFirst.priority(g, &bin, fixed);
        assert!(q(&with(1.0, 26.0)) < q(&with(0.51, 31.0)));
        assert_eq!(q(&with(1.0, 26.0)), 1.0);
        // No distribution (κ = 0, no floor) or one κ for all: the quality order.
        assert!(p(&at(c.x, c.y, c.z, 0.9)) > p(&at(c.x, c.y, c.z, 0.8)));
        assert_eq!(p(&at(c.x, c.y, c.z, 0.7)), 0.7);
        assert!(p(&with(0.9, 25.0)) > p(&with(0.8, 25.0)));
    }
}
