//! The rapier world of one attempt: integration parameters, the bin and the objects (shared with
//! scene generation: [`crate::physics`]), settling after the attempt and the scene it leaves.
use super::ExecutionConfig;
use crate::physics::{
    body_at_rest, insert_bin, insert_object, physics_world, pose_in_bin, step_until_rest,
    ColliderTags,
};
use crate::SimError;
use crate::{MeshLibrary, SceneDescription, SceneObject};
use rapier3d::prelude::{
    Group, InteractionGroups, InteractionTestMode, PhysicsWorld, RigidBodyHandle,
};

pub(super) const GROUP_HAND: Group = Group::GROUP_1;
pub(super) const GROUP_WORLD: Group = Group::GROUP_2;
/// `user_data` of bin colliders (objects store their index + 1, the hand 0).
pub(super) const USER_BIN: u128 = u128::MAX;
/// `user_data` of hand colliders.
pub(super) const USER_HAND: u128 = 0;

pub(super) fn world_groups() -> InteractionGroups {
    InteractionGroups::new(GROUP_WORLD, Group::ALL, InteractionTestMode::And)
}

pub(super) fn hand_groups() -> InteractionGroups {
    InteractionGroups::new(GROUP_HAND, GROUP_WORLD, InteractionTestMode::And)
}

/// A world with `cfg`'s time step, solver iterations and stiffer contacts.
pub(super) fn execution_world(cfg: &ExecutionConfig) -> PhysicsWorld {
    let mut world = physics_world(cfg.dt_s);
    let ip = &mut world.integration_parameters;
    ip.num_solver_iterations = cfg.solver_iterations;
    ip.contact_softness.natural_frequency = cfg.contact_natural_frequency_hz;
    ip.contact_softness.damping_ratio = cfg.contact_damping_ratio;
    // Recycled contacts keep stale distances: the contact abort needs fresh ones.
    ip.contact_recycling = false;
    ip.static_contact_softness.natural_frequency = ip
        .static_contact_softness
        .natural_frequency
        .max(cfg.contact_natural_frequency_hz);
    world
}

/// The bin (walls padded outward as in scene generation, so that nothing tunnels through them)
/// and the objects of `desc` at their poses; the objects' bodies in scene order.
pub(super) fn insert_scene(
    world: &mut PhysicsWorld,
    desc: &SceneDescription,
    meshes: &MeshLibrary,
    cfg: &ExecutionConfig,
) -> Result<Vec<RigidBodyHandle>, SimError> {
    let bin_tags = ColliderTags {
        groups: world_groups(),
        user_data: USER_BIN,
    };
    insert_bin(world, &desc.bin, &cfg.objects, bin_tags);
    desc.objects
        .iter()
        .enumerate()
        .map(|(i, obj)| insert_scene_object(world, obj, i, meshes, cfg))
        .collect()
}

/// `obj` as a dynamic body, its colliders tagged as the world's object `index`.
fn insert_scene_object(
    world: &mut PhysicsWorld,
    obj: &SceneObject,
    index: usize,
    meshes: &MeshLibrary,
    cfg: &ExecutionConfig,
) -> Result<RigidBodyHandle, SimError> {
    let shape = obj.spec.build_physics_shape(meshes)?;
    let tags = ColliderTags {
        groups: world_groups(),
        user_data: index as u128 + 1,
    };
    Ok(insert_object(
        world,
        shape,
        &obj.workspace_from_object,
        &cfg.objects,
        false,
        tags,
    ))
}

/// Object `index` of `desc` alone (no bin, no other objects), tagged as object 0 of the world.
pub(super) fn insert_lone_object(
    world: &mut PhysicsWorld,
    desc: &SceneDescription,
    index: usize,
    meshes: &MeshLibrary,
    cfg: &ExecutionConfig,
) -> Result<RigidBodyHandle, SimError> {
    let obj = desc.objects.get(index).ok_or(SimError::InvalidSetting {
        field: "object",
        reason: "the scene has no object of that index",
    })?;
    insert_scene_object(world, obj, 0, meshes, cfg)
}

/// Steps until every remaining object rests or the settling time runs out.
/// `fresh_max_steps = Some(n)`: the objects were just inserted at rest (zero velocity), so the
/// rest test waits for the first 10 steps instead of passing before any, and the limit is `n`
/// steps instead of [`ExecutionConfig::settle_time_s`].
pub(super) fn settle(
    world: &mut PhysicsWorld,
    objects: &[RigidBodyHandle],
    removed: Option<usize>,
    cfg: &ExecutionConfig,
    fresh_max_steps: Option<usize>,
) -> (usize, bool) {
    let at_rest = |world: &PhysicsWorld| {
        objects.iter().enumerate().all(|(i, h)| {
            Some(i) == removed
                || world
                    .bodies
                    .get(*h)
                    .is_none_or(|b| body_at_rest(b, &cfg.objects))
        })
    };
    if let Some(max_steps) = fresh_max_steps {
        return step_until_rest(world, max_steps, 10, false, at_rest);
    }
    let max_steps = (cfg.settle_time_s / cfg.dt_s).ceil() as usize;
    let initially = at_rest(world);
    step_until_rest(world, max_steps, 5, initially, at_rest)
}

/// The remaining objects with their new poses; objects outside the bin are left out and listed.
pub(super) fn collect_scene(
    world: &PhysicsWorld,
    desc: &SceneDescription,
    objects: &[RigidBodyHandle],
    removed: Option<usize>,
) -> (SceneDescription, Vec<usize>) {
    let bin = &desc.bin;
    let mut kept = Vec::new();
    let mut lost = Vec::new();
    for (i, (obj, h)) in desc.objects.iter().zip(objects).enumerate() {
        if Some(i) == removed {
            continue;
        }
        match pose_in_bin(world, *h, bin) {
            Some(p) => kept.push(SceneObject {
                spec: obj.spec.clone(),
                workspace_from_object: p,
            }),
            None => lost.push(i),
        }
    }
    (
        SceneDescription {
            bin: *bin,
            objects: kept,
        },
        lost,
    )
}
