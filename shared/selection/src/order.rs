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
}

impl PickOrder {
    /// The priority of configuration `c` in `bin` (higher first; not finite → last).
    pub fn priority(self, c: &GraspConfiguration, bin: &BinModel) -> f32 {
        let p = grasp_centre(c);
        let v = match self {
            PickOrder::Quality => c.quality,
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

/// The TCP of every grasp of `c`, whatever its approach: midway between the two contacts.
pub fn grasp_centre(c: &GraspConfiguration) -> Point3<f32> {
    c.contact + c.baseline * (0.5 * c.width)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn at(x: f32, y: f32, z: f32, quality: f32) -> GraspConfiguration {
        GraspConfiguration {
            contact: Point3::new(x, y, z),
            baseline: Vector3::x(),
            collision_scores: [1.0; psgrasp_geometry::N_APPROACHES],
            width: 0.04,
            quality,
            kappa: 0.0,
        }
    }

    #[test]
    fn each_order_ranks_by_its_own_key() {
        let bin = BinModel::default();
        let c = bin.floor_center;
        let high_poor = at(c.x + 0.1, c.y, c.z + 0.2, 0.6);
        let low_good_central = at(c.x - 0.02, c.y, c.z + 0.05, 0.9);
        let p = |o: PickOrder, g: &GraspConfiguration| o.priority(g, &bin);
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
        ] {
            assert_eq!(o.priority(&nan, &bin), f32::NEG_INFINITY);
        }
    }
}
