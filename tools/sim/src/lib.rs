//! Synthetic bin scenes for psgrasp: an object library (procedural objects and meshes), dropping
//! objects into a bin with rapier3d, depth rendering by ray casting against the exact shapes
//! (parry BVH), and the "dex" depth-noise model.
//!
//! ```no_run
//! use psgrasp_geometry::{BinModel, CameraIntrinsics};
//! let bin = BinModel::default();
//! let scene = psgrasp_sim::procedural_scene(42, 10, &bin).unwrap();
//! let camera = psgrasp_sim::default_camera(&bin, CameraIntrinsics::default_640x480());
//! let clean = scene.render_depth(&camera);
//! let noisy = psgrasp_sim::add_dex_noise(&clean, 42, &psgrasp_sim::NoiseConfig::default());
//! # let _ = noisy;
//! ```
//!
//! Determinism: every random process takes a seed; the same seed gives the same scene on the same
//! build and platform (rapier is not built with cross-platform determinism).
#![warn(missing_docs)]

pub mod convert;
pub mod execute;
pub mod mesh;
pub mod noise;
pub mod objects;
pub mod physics;
pub mod scene;

pub use mesh::{MeshAsset, MeshLibrary};
pub use noise::{add_dex_noise, NoiseConfig};
pub use objects::{LibraryObject, ObjectKind, ObjectLibrary, ObjectSpec, Part, Primitive, Split};
pub use physics::{drop_and_settle, spawn_xy, SettleConfig, SettleReport};
pub use scene::{
    HitTarget, RayHit, Rendering, Scene, SceneDescription, SceneObject, WallZone, WallZones,
    NEAR_WALL_M, SEGMENT_BIN, SEGMENT_OBJECT0,
};

use nalgebra::Point3;
use psgrasp_geometry::{BinModel, CameraIntrinsics, CameraModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Errors of the simulator.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SimError {
    /// An object description has unusable geometry.
    #[error("invalid object: {reason}")]
    InvalidObject {
        /// What is wrong.
        reason: &'static str,
    },
    /// The bin has non-positive or non-finite dimensions.
    #[error("invalid bin: sizes and wall thickness must be positive and finite")]
    InvalidBin,
    /// A configuration value is out of range.
    #[error("invalid configuration: {reason}")]
    InvalidConfig {
        /// What is wrong.
        reason: &'static str,
    },
    /// A scene references a mesh that is not in the mesh library.
    #[error(
        "mesh '{key}' is not loaded (run scripts/fetch_objects.sh and pass the mesh directory)"
    )]
    MeshNotLoaded {
        /// The missing key.
        key: String,
    },
    /// A mesh could not be loaded or used.
    #[error("mesh '{key}': {reason}")]
    InvalidMesh {
        /// The mesh key or file.
        key: String,
        /// What went wrong.
        reason: String,
    },
    /// No object is available for the requested selection.
    #[error("the object pool is empty for this selection")]
    EmptyObjectPool,
    /// A named setting is out of its valid range (grasp execution).
    #[error("invalid setting `{field}`: {reason}")]
    InvalidSetting {
        /// Name of the field.
        field: &'static str,
        /// What the valid range is.
        reason: &'static str,
    },
    /// A grasp command cannot be executed (non-finite pose, bad opening, bad gripper).
    #[error("invalid grasp command: {0}")]
    InvalidGrasp(&'static str),
}

impl From<psgrasp_geometry::OutOfRange> for SimError {
    fn from(e: psgrasp_geometry::OutOfRange) -> Self {
        Self::InvalidSetting {
            field: e.field,
            reason: e.reason,
        }
    }
}

/// How to build one scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SceneRecipe {
    /// Smallest number of objects dropped.
    pub min_objects: usize,
    /// Largest number of objects dropped.
    pub max_objects: usize,
    /// Range of the uniform random scale applied to each object.
    pub scale_range: [f32; 2],
    /// An object whose drawn scale makes the second-smallest side of its bounding box wider
    /// than this is scaled down to it, so that every object fits the hand's opening in at least
    /// one horizontal direction whichever face it rests on (the paper scales its objects
    /// randomly to fit the hand); `None` = no limit.
    pub fit_width_m: Option<f32>,
    /// Probability of using the small bin ([`BinModel::small`]) instead of the default one.
    pub small_bin_probability: f32,
    /// Physics settings.
    pub settle: SettleConfig,
}

impl Default for SceneRecipe {
    fn default() -> Self {
        Self {
            min_objects: 1,
            max_objects: 20,
            scale_range: [0.8, 1.2],
            fit_width_m: None,
            small_bin_probability: 0.0,
            settle: SettleConfig::default(),
        }
    }
}

/// Picks objects from `pool`, scales them and drops them into `bin` (or the small bin, per the
/// recipe). Deterministic for `seed`.
pub fn generate_scene(
    seed: u64,
    pool: &[&LibraryObject],
    bin: &BinModel,
    meshes: &MeshLibrary,
    recipe: &SceneRecipe,
) -> Result<(Scene, SettleReport), SimError> {
    if pool.is_empty() {
        return Err(SimError::EmptyObjectPool);
    }
    let [s0, s1] = recipe.scale_range;
    if !(s0.is_finite() && s1.is_finite() && s0 > 0.0 && s1 >= s0)
        || recipe.min_objects > recipe.max_objects
        || recipe
            .fit_width_m
            .is_some_and(|w| !(w.is_finite() && w > 0.0))
    {
        return Err(SimError::InvalidConfig {
            reason:
                "scale_range must be 0 < lo <= hi, min_objects <= max_objects and fit_width_m > 0",
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = rng.random_range(recipe.min_objects..=recipe.max_objects);
    let bin = if rng.random::<f32>() < recipe.small_bin_probability {
        BinModel {
            inner_size_m: BinModel::small().inner_size_m,
            ..*bin
        }
    } else {
        *bin
    };
    let specs: Vec<ObjectSpec> = (0..n)
        .map(|_| {
            let obj = pool[rng.random_range(0..pool.len())];
            let s = if s1 > s0 {
                rng.random_range(s0..=s1)
            } else {
                s0
            };
            let s = match recipe.fit_width_m {
                Some(w) if obj.fit_extent_m * s > w => w / obj.fit_extent_m,
                _ => s,
            };
            obj.spec.scaled(s)
        })
        .collect();
    let (desc, report) = drop_and_settle(&bin, &specs, meshes, &recipe.settle, &mut rng)?;
    Ok((Scene::with_meshes(desc, meshes)?, report))
}

/// `n_objects` procedural objects (from the whole procedural library, random scale 0.8–1.2)
/// dropped into `bin` and settled. Deterministic for `seed`. Objects that bounce out of the bin
/// are removed, so the scene can hold fewer than `n_objects`.
pub fn procedural_scene(seed: u64, n_objects: usize, bin: &BinModel) -> Result<Scene, SimError> {
    let library = ObjectLibrary::procedural();
    let pool = library.select(None, false);
    let recipe = SceneRecipe {
        min_objects: n_objects,
        max_objects: n_objects,
        ..Default::default()
    };
    generate_scene(seed, &pool, bin, &MeshLibrary::default(), &recipe).map(|(scene, _)| scene)
}

/// Camera height above the bin rim limits (metres).
pub const DEFAULT_CAMERA_HEIGHT_RANGE_M: [f32; 2] = [0.6, 1.0];

/// A top-down camera above the bin centre: high enough (0.6–1.0 m above the rim) that the
/// whole rim fits in the image when the field of view allows, looking straight down.
pub fn default_camera(bin: &BinModel, intrinsics: CameraIntrinsics) -> CameraModel {
    let half_x = 0.5 * bin.inner_size_m[0] + bin.wall_thickness_m;
    let half_y = 0.5 * bin.inner_size_m[1] + bin.wall_thickness_m;
    // Distance at which the rim's half extents fit the half image (with a 5 % margin).
    let need = |half: f32, pixels: f32, f: f32| {
        if pixels > 0.0 {
            1.05 * half * f / pixels
        } else {
            0.0
        }
    };
    let (w, h) = (intrinsics.width as f32, intrinsics.height as f32);
    let fit = need(half_x, intrinsics.cx.min(w - intrinsics.cx), intrinsics.fx).max(need(
        half_y,
        intrinsics.cy.min(h - intrinsics.cy),
        intrinsics.fy,
    ));
    let [lo, hi] = DEFAULT_CAMERA_HEIGHT_RANGE_M;
    let height = if fit.is_finite() {
        fit.clamp(lo, hi)
    } else {
        hi
    };
    let eye = Point3::new(bin.floor_center.x, bin.floor_center.y, bin.rim_z() + height);
    CameraModel::top_down(intrinsics, eye)
}

#[cfg(test)]
mod tests {
    use super::*;
    use psgrasp_geometry::depth::is_valid_depth;

    #[test]
    fn procedural_scene_is_deterministic_and_settled_inside_the_bin() {
        let bin = BinModel::default();
        let a = procedural_scene(11, 8, &bin).unwrap();
        let b = procedural_scene(11, 8, &bin).unwrap();
        assert_eq!(a.description(), b.description());
        let c = procedural_scene(12, 8, &bin).unwrap();
        assert_ne!(a.description(), c.description());
        assert!(
            a.object_count() >= 6,
            "only {} of 8 objects stayed in the bin",
            a.object_count()
        );
        for o in a.objects() {
            let p = o.workspace_from_object.translation.vector;
            assert!(
                p.z > bin.floor_center.z && p.z < bin.rim_z(),
                "object {} at z {}",
                o.spec.name,
                p.z
            );
        }
        // Objects rest on the floor or each other: nothing floats high above the floor.
        let lowest = a
            .objects()
            .iter()
            .map(|o| o.workspace_from_object.translation.z)
            .fold(f32::INFINITY, f32::min);
        assert!(lowest < bin.floor_center.z + 0.08);
    }

    #[test]
    fn objects_are_released_over_the_drop_region_and_fewer_end_against_the_walls() {
        let bin = BinModel::default();
        let [lx, ly, _] = bin.inner_size_m;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for (fraction, r) in [(0.5f32, 0.02f32), (1.0, 0.05), (0.25, 0.0)] {
            for _ in 0..500 {
                let (x, y) = physics::spawn_xy(&bin, r, fraction, &mut rng);
                let (dx, dy) = (
                    (x - bin.floor_center.x).abs(),
                    (y - bin.floor_center.y).abs(),
                );
                assert!(dx <= 0.5 * lx * fraction + 1e-6 && dy <= 0.5 * ly * fraction + 1e-6);
                assert!(dx <= 0.5 * lx - r + 1e-6 && dy <= 0.5 * ly - r + 1e-6);
            }
        }
        // The same medium scenes, released anywhere over the floor or over its central half.
        let library = ObjectLibrary::procedural();
        let pool = library.select(Some(Split::Test), false);
        let zones = |fraction: f32| {
            let recipe = SceneRecipe {
                min_objects: 10,
                max_objects: 10,
                settle: SettleConfig {
                    drop_region_fraction: fraction,
                    ..Default::default()
                },
                ..Default::default()
            };
            let mut total = WallZones::default();
            for seed in 0..6 {
                let (scene, _) =
                    generate_scene(seed, &pool, &bin, &MeshLibrary::default(), &recipe).unwrap();
                total += scene.wall_zones();
            }
            total
        };
        let (anywhere, central) = (zones(1.0), zones(0.5));
        assert!(anywhere.in_corner <= anywhere.near_wall && central.in_corner <= central.near_wall);
        assert!(
            central.near_wall < anywhere.near_wall,
            "central drops {central:?} vs anywhere {anywhere:?}"
        );
        let bad = SettleConfig {
            drop_region_fraction: 0.0,
            ..Default::default()
        };
        let recipe = SceneRecipe {
            settle: bad,
            ..Default::default()
        };
        assert!(generate_scene(0, &pool, &bin, &MeshLibrary::default(), &recipe).is_err());
    }

    #[test]
    fn default_camera_sees_the_whole_bin_floor() {
        let bin = BinModel::default();
        let k = CameraIntrinsics::default_640x480();
        let cam = default_camera(&bin, k);
        let h = cam.eye().z - bin.rim_z();
        assert!((0.6..=1.0).contains(&h), "height {h}");
        let scene = Scene::new(SceneDescription {
            bin,
            objects: vec![],
        })
        .unwrap();
        let depth = scene.render_depth(&cam);
        // Floor centre depth = eye height above the floor.
        let centre = depth.at(320, 240);
        assert!((centre - (cam.eye().z - bin.floor_center.z)).abs() < 1e-4);
        // Every floor corner projects into the image and is rendered as floor (not occluded).
        let to_cam = cam.workspace_from_camera.inverse();
        for sx in [-1.0f32, 1.0] {
            for sy in [-1.0f32, 1.0] {
                let p = bin.floor_center + nalgebra::Vector3::new(sx * 0.29, sy * 0.19, 0.0);
                let (u, v) = k.project(&(to_cam * p)).unwrap();
                assert!(u > 0.0 && u < 640.0 && v > 0.0 && v < 480.0);
                let d = depth.at(u as u32, v as u32);
                assert!(is_valid_depth(d));
            }
        }
    }
}
