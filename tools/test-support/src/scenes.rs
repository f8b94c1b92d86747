//! Simulator scenes for tests and benchmarks: hand-placed objects on the bin floor, and a
//! procedural scene rendered by one top-down camera and fused into a normal grid.
use nalgebra::{Isometry3, Point3};
use psgrasp_fusion::{fuse_normal_grid, FusionConfig, NormalGrid};
use psgrasp_geometry::{BinModel, CameraIntrinsics, CameraModel, Workspace};
use psgrasp_sim::{ObjectKind, ObjectSpec, Part, Primitive, Scene, SceneDescription, SceneObject};

/// An object of one part, `primitive`, at the object origin.
pub fn single_part(name: &str, kind: ObjectKind, primitive: Primitive) -> ObjectSpec {
    ObjectSpec {
        name: name.into(),
        kind,
        parts: vec![Part {
            object_from_part: Isometry3::identity(),
            primitive,
        }],
    }
}

/// A box (named `box`) with half extents `half`, metres.
pub fn cuboid(half: [f32; 3]) -> ObjectSpec {
    single_part(
        "box",
        ObjectKind::Box,
        Primitive::Cuboid { half_extents: half },
    )
}

/// `spec` upright on the floor of `bin`: its origin `half_height` above the floor, offset
/// `[dx, dy]` from the floor centre.
pub fn on_floor(
    bin: &BinModel,
    spec: ObjectSpec,
    [dx, dy]: [f32; 2],
    half_height: f32,
) -> SceneObject {
    let c = bin.floor_center;
    SceneObject {
        spec,
        workspace_from_object: Isometry3::translation(c.x + dx, c.y + dy, c.z + half_height),
    }
}

/// Boxes `(half extents, [dx, dy])` resting on the floor of the default bin, centred at the given
/// offsets from the floor centre.
pub fn boxes_on_floor(items: &[([f32; 3], [f32; 2])]) -> Scene {
    let bin = BinModel::default();
    let objects = items
        .iter()
        .map(|(half, offset)| on_floor(&bin, cuboid(*half), *offset, half[2]))
        .collect();
    Scene::new(SceneDescription { bin, objects }).unwrap()
}

/// The one view of the fused-scene tests and benchmarks: 640 × 480, looking straight down from
/// 0.6 m above the rim of the default bin, over the centre of the default workspace.
pub fn top_down_camera() -> CameraModel {
    CameraModel::top_down(
        CameraIntrinsics::default_640x480(),
        Point3::new(0.288, 0.288, 0.018 + 0.28 + 0.6),
    )
}

/// `scene`'s exact depth from [`top_down_camera`], fused into `workspace` with the default
/// fusion settings.
pub fn fused_top_down(scene: &Scene, workspace: &Workspace) -> NormalGrid {
    let camera = top_down_camera();
    let depth = scene.render_depth(&camera);
    fuse_normal_grid(&depth, &camera, workspace, &FusionConfig::default()).expect("fusion")
}
