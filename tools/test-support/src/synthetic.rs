//! Exact normal grids of analytic scenes, for tests, benchmarks and demos.
//!
//! A [`SyntheticScene`] is a floor plus upright boxes (any yaw) and upright cylinders standing on it.
//! Seen from straight above, the observed solid is everything below the top-most surface, so each
//! primitive is extended downwards (a prism) and the scene's signed distance is the minimum of the
//! primitives' signed distances. That is exact in free space (where grasps are computed) and a close
//! lower bound of the depth inside; the grid stores it clamped to [−1, 1] in units of the truncation
//! distance. Normals are the normalised gradient (pointing to free space) in the truncation band and
//! zero outside it, like the grids fusion produces.
use nalgebra::{Point2, Vector3};
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::Workspace;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// An upright object standing on the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Primitive {
    /// A box with a vertical axis.
    Box {
        /// Centre of the footprint (workspace x, y).
        center_xy: Point2<f32>,
        /// Size along its local x, y and height z, metres.
        size_m: Vector3<f32>,
        /// Rotation about the vertical axis, radians.
        yaw_rad: f32,
    },
    /// A cylinder with a vertical axis.
    Cylinder {
        /// Axis position (workspace x, y).
        center_xy: Point2<f32>,
        /// Radius, metres.
        radius_m: f32,
        /// Height above the floor, metres.
        height_m: f32,
    },
}

/// A floor at height `floor_z_m` with primitives standing on it.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticScene {
    /// Height of the floor surface in the workspace frame.
    pub floor_z_m: f32,
    /// The objects.
    pub objects: Vec<Primitive>,
}

/// How far below the floor the primitives' prisms reach (they only need to reach under the floor).
const PRISM_DEPTH_M: f64 = 1.0;

impl Primitive {
    /// Signed distance of `p` to the downward-extended primitive standing on `floor_z`.
    fn signed_distance(&self, p: &Vector3<f64>, floor_z: f64) -> f64 {
        match *self {
            Primitive::Box {
                center_xy,
                size_m,
                yaw_rad,
            } => {
                let (s, c) = (yaw_rad as f64).sin_cos();
                let (dx, dy) = (p.x - center_xy.x as f64, p.y - center_xy.y as f64);
                // Into the box frame (rotate by −yaw).
                let lx = c * dx + s * dy;
                let ly = -s * dx + c * dy;
                let top = floor_z + size_m.z as f64;
                let bottom = floor_z - PRISM_DEPTH_M;
                let zc = 0.5 * (top + bottom);
                let q = Vector3::new(
                    lx.abs() - 0.5 * size_m.x as f64,
                    ly.abs() - 0.5 * size_m.y as f64,
                    (p.z - zc).abs() - 0.5 * (top - bottom),
                );
                let outside = Vector3::new(q.x.max(0.0), q.y.max(0.0), q.z.max(0.0)).norm();
                outside + q.x.max(q.y).max(q.z).min(0.0)
            }
            Primitive::Cylinder {
                center_xy,
                radius_m,
                height_m,
            } => {
                let r = ((p.x - center_xy.x as f64).powi(2) + (p.y - center_xy.y as f64).powi(2))
                    .sqrt()
                    - radius_m as f64;
                let top = floor_z + height_m as f64;
                let bottom = floor_z - PRISM_DEPTH_M;
                let zc = 0.5 * (top + bottom);
                let h = (p.z - zc).abs() - 0.5 * (top - bottom);
                let outside = (r.max(0.0).powi(2) + h.max(0.0).powi(2)).sqrt();
                outside + r.max(h).min(0.0)
            }
        }
    }
}

impl SyntheticScene {
    /// An empty floor.
    pub fn floor(floor_z_m: f32) -> Self {
        Self {
            floor_z_m,
            objects: Vec::new(),
        }
    }

    /// Adds an object (builder style).
    pub fn with(mut self, object: Primitive) -> Self {
        self.objects.push(object);
        self
    }

    /// A seeded clutter of `count` boxes and cylinders (30–70 mm across, 30–120 mm tall) dropped at
    /// random positions inside `[min_xy, max_xy]`; objects may overlap (the top-most surface wins).
    pub fn random_clutter(
        floor_z_m: f32,
        min_xy: Point2<f32>,
        max_xy: Point2<f32>,
        count: usize,
        seed: u64,
    ) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut scene = Self::floor(floor_z_m);
        for _ in 0..count {
            let center_xy = Point2::new(
                rng.random_range(min_xy.x..=max_xy.x),
                rng.random_range(min_xy.y..=max_xy.y),
            );
            let object = if rng.random_bool(0.6) {
                Primitive::Box {
                    center_xy,
                    size_m: Vector3::new(
                        rng.random_range(0.03..0.07),
                        rng.random_range(0.03..0.09),
                        rng.random_range(0.03..0.12),
                    ),
                    yaw_rad: rng.random_range(0.0..std::f32::consts::PI),
                }
            } else {
                Primitive::Cylinder {
                    center_xy,
                    radius_m: rng.random_range(0.015..0.035),
                    height_m: rng.random_range(0.03..0.12),
                }
            };
            scene.objects.push(object);
        }
        scene
    }

    /// Signed distance (metres, positive in free space) of a workspace point to the observed surface.
    pub fn signed_distance(&self, p: &Vector3<f64>) -> f64 {
        let floor_z = self.floor_z_m as f64;
        self.objects
            .iter()
            .map(|o| o.signed_distance(p, floor_z))
            .fold(p.z - floor_z, f64::min)
    }

    /// The normal grid of the scene on `workspace` with truncation distance `truncation_m`.
    pub fn normal_grid(&self, workspace: Workspace, truncation_m: f32) -> NormalGrid {
        let n = workspace.voxel_count();
        let trunc = truncation_m as f64;
        let mut tsdf = vec![0f32; n];
        let mut normals = vec![0f32; 3 * n];
        let h = 1e-5;
        for (idx, value) in tsdf.iter_mut().enumerate() {
            let [i, j, k] = workspace.unindex(idx);
            let c = workspace.voxel_center(i, j, k);
            let p = Vector3::new(c.x as f64, c.y as f64, c.z as f64);
            let d = self.signed_distance(&p);
            *value = (d / trunc).clamp(-1.0, 1.0) as f32;
            if d.abs() < trunc {
                let g = Vector3::from_fn(|a, _| {
                    let mut e = Vector3::zeros();
                    e[a] = h;
                    self.signed_distance(&(p + e)) - self.signed_distance(&(p - e))
                });
                if g.norm() > 1e-12 {
                    let g = g.normalize();
                    for a in 0..3 {
                        normals[a * n + idx] = g[a] as f32;
                    }
                }
            }
        }
        NormalGrid {
            workspace,
            normals,
            tsdf,
            truncation_m,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_on_floor_has_exact_distances_and_outward_normals() {
        let scene = SyntheticScene::floor(0.02).with(Primitive::Box {
            center_xy: Point2::new(0.1, 0.1),
            size_m: Vector3::new(0.04, 0.06, 0.05),
            yaw_rad: 0.0,
        });
        // 1 cm beside the +x face at mid height, 1 cm above the top, 1 cm above the floor far away.
        assert!((scene.signed_distance(&Vector3::new(0.13, 0.1, 0.045)) - 0.01).abs() < 1e-6);
        assert!((scene.signed_distance(&Vector3::new(0.1, 0.1, 0.08)) - 0.01).abs() < 1e-6);
        assert!((scene.signed_distance(&Vector3::new(0.3, 0.3, 0.03)) - 0.01).abs() < 1e-6);
        // Inside: 5 mm behind the −y face.
        assert!((scene.signed_distance(&Vector3::new(0.1, 0.075, 0.045)) + 0.005).abs() < 1e-6);

        let ws = Workspace {
            dims: [24, 24, 16],
            voxel_size_m: 0.009,
        };
        let grid = scene.normal_grid(ws, 0.027);
        let n = ws.voxel_count();
        // The voxel centred at (0.1305, 0.1035, 0.0405) is 1.05 cm in front of the +x face.
        let idx = ws.index(14, 11, 4);
        assert!((grid.tsdf[idx] - (0.0105 / 0.027)).abs() < 1e-4);
        assert!((grid.normals[idx] - 1.0).abs() < 1e-4 && grid.normals[n + idx].abs() < 1e-4);
        // Far above everything: +1 and no normal.
        let top = ws.index(2, 2, 15);
        assert_eq!(grid.tsdf[top], 1.0);
        assert_eq!(
            [
                grid.normals[top],
                grid.normals[n + top],
                grid.normals[2 * n + top]
            ],
            [0.0; 3]
        );
    }

    #[test]
    fn random_clutter_is_seeded() {
        let a = SyntheticScene::random_clutter(
            0.02,
            Point2::new(0.1, 0.1),
            Point2::new(0.4, 0.4),
            8,
            7,
        );
        let b = SyntheticScene::random_clutter(
            0.02,
            Point2::new(0.1, 0.1),
            Point2::new(0.4, 0.4),
            8,
            7,
        );
        let c = SyntheticScene::random_clutter(
            0.02,
            Point2::new(0.1, 0.1),
            Point2::new(0.4, 0.4),
            8,
            8,
        );
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_eq!(a.objects.len(), 8);
    }
}
