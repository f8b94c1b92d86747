//! The hand in the physics world: a kinematic palm and two force-driven fingers on prismatic
//! impulse joints, moved pose by pose; what the hand touches and how far its fingers are apart.
use super::world::{hand_groups, USER_BIN, USER_HAND};
use super::{ExecutionConfig, HandPart};
use crate::convert::{pose_from_glam, pose_to_glam, vec_to_glam};
use nalgebra::{Isometry3, Vector3};
use psgrasp_geometry::GripperModel;
use rapier3d::prelude::{
    ActiveCollisionTypes, ColliderBuilder, ColliderHandle, ImpulseJointHandle, PhysicsWorld,
    PrismaticJointBuilder, RigidBodyBuilder, RigidBodyHandle, SharedShape,
};

/// The hand's bodies, joints and colliders (palm first, then the two fingers).
pub(super) struct Hand {
    pub(super) palm: RigidBodyHandle,
    pub(super) fingers: [RigidBodyHandle; 2],
    pub(super) joints: [ImpulseJointHandle; 2],
    pub(super) colliders: [ColliderHandle; 3],
    pub(super) finger_thickness: f32,
}

pub(super) fn insert_hand(
    world: &mut PhysicsWorld,
    gripper: &GripperModel,
    pose: &Isometry3<f32>,
    opening: f32,
    cfg: &ExecutionConfig,
) -> Hand {
    let [palm_box, left_box, right_box] = gripper.boxes_in_gripper_frame(opening);
    let palm = world.insert_body(
        RigidBodyBuilder::kinematic_position_based()
            .pose(pose_to_glam(pose))
            .build(),
    );
    let palm_collider = ColliderBuilder::new(SharedShape::cuboid(
        palm_box.half_extents.x,
        palm_box.half_extents.y,
        palm_box.half_extents.z,
    ))
    .position(pose_to_glam(&palm_box.parent_from_box))
    // A kinematic body has no contacts with fixed ones (the bin) unless asked for.
    .active_collision_types(ActiveCollisionTypes::all())
    .collision_groups(hand_groups())
    .user_data(USER_HAND)
    .build();
    let palm_c = world.insert_collider(palm_collider, Some(palm));
    let ft = gripper.finger_size_m[0];
    let finger_z = left_box.parent_from_box.translation.z;
    let mut fingers = [palm; 2];
    let mut joints = [ImpulseJointHandle::invalid(); 2];
    let mut colliders = [palm_c; 3];
    for (k, (b, sign)) in [(left_box, -1.0f32), (right_box, 1.0)]
        .into_iter()
        .enumerate()
    {
        let body = world.insert_body(
            RigidBodyBuilder::dynamic()
                .pose(pose_to_glam(&(pose * b.parent_from_box)))
                .can_sleep(false)
                .build(),
        );
        let c = ColliderBuilder::new(SharedShape::cuboid(
            b.half_extents.x,
            b.half_extents.y,
            b.half_extents.z,
        ))
        .mass(cfg.finger_mass_kg)
        .friction(cfg.finger_friction)
        .restitution(0.0)
        .collision_groups(hand_groups())
        .user_data(USER_HAND)
        .build();
        colliders[k + 1] = world.insert_collider(c, Some(body));
        let axis = vec_to_glam(&(Vector3::x() * sign));
        let joint = PrismaticJointBuilder::new(axis)
            .local_anchor1(vec_to_glam(&Vector3::new(sign * 0.5 * ft, 0.0, finger_z)))
            .local_anchor2(vec_to_glam(&Vector3::zeros()))
            .limits([0.0, 0.5 * gripper.max_opening_m])
            .motor_position(0.5 * opening, 1.0e4, 200.0)
            .motor_max_force(cfg.finger_force_n.max(200.0))
            .contacts_enabled(false)
            .build();
        joints[k] = world.insert_impulse_joint(palm, body, joint);
        fingers[k] = body;
    }
    Hand {
        palm,
        fingers,
        joints,
        colliders,
        finger_thickness: ft,
    }
}

pub(super) fn move_palm(world: &mut PhysicsWorld, hand: &Hand, pose: &Isometry3<f32>) {
    if let Some(b) = world.bodies.get_mut(hand.palm) {
        b.set_next_kinematic_position(pose_to_glam(pose));
    }
}

/// What hand collider `collider` touches closer than `touch`, one item per contact pair:
/// `Some(object index)`, or `None` for the bin (hand parts only meet the world: `hand_groups`).
fn touched_by(
    world: &PhysicsWorld,
    collider: ColliderHandle,
    touch: f32,
) -> impl Iterator<Item = Option<usize>> + '_ {
    world
        .narrow_phase
        .contact_pairs_with(collider)
        .filter_map(move |pair| {
            let close = pair
                .manifolds()
                .iter()
                .any(|m| m.points.iter().any(|p| p.dist < touch));
            let other = if pair.collider1 == collider {
                pair.collider2
            } else {
                pair.collider1
            };
            let data = world.colliders.get(other)?.user_data;
            close.then(|| (data != USER_BIN && data != USER_HAND).then(|| (data - 1) as usize))
        })
}

/// The first hand collider (palm, then fingers) touching something closer than `touch`, and
/// what it touches (`Some(object index)`, `None` for the bin).
pub(super) fn first_touch(
    world: &PhysicsWorld,
    hand: &Hand,
    touch: f32,
) -> Option<(HandPart, Option<usize>)> {
    hand.colliders.iter().enumerate().find_map(|(k, c)| {
        let part = if k == 0 {
            HandPart::Palm
        } else {
            HandPart::Finger
        };
        touched_by(world, *c, touch)
            .next()
            .map(|object| (part, object))
    })
}

/// Object indices with a contact closer than `touch` to either finger.
pub(super) fn fingers_touch(world: &PhysicsWorld, hand: &Hand, touch: f32) -> Vec<usize> {
    let mut out = touches_per_finger(world, hand, touch).concat();
    out.sort_unstable();
    out.dedup();
    out
}

/// Object indices each finger (left, right) touches closer than `touch`.
pub(super) fn touches_per_finger(world: &PhysicsWorld, hand: &Hand, touch: f32) -> [Vec<usize>; 2] {
    [1, 2].map(|k| {
        let mut out: Vec<usize> = touched_by(world, hand.colliders[k], touch)
            .flatten()
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    })
}

/// How close an object must be to a finger to count as held: the touch distance, at least 2 mm
/// (a held object rests on the pads; the approach's touch distance may be set tighter).
pub(super) fn holding_distance(cfg: &ExecutionConfig) -> f32 {
    cfg.touch_distance_m.max(0.002)
}

/// Largest finger speed along the closing axis relative to the palm, m/s.
pub(super) fn finger_speeds(world: &PhysicsWorld, hand: &Hand) -> f32 {
    let Some(palm) = world.bodies.get(hand.palm) else {
        return 0.0;
    };
    let x = palm.position().rotation * parry3d::math::Vector::X;
    hand.fingers
        .iter()
        .filter_map(|f| world.bodies.get(*f))
        .map(|f| (f.linvel() - palm.linvel()).dot(x).abs())
        .fold(0.0, f32::max)
}

/// Gap between the finger pads, metres.
pub(super) fn hand_opening(world: &PhysicsWorld, hand: &Hand) -> f32 {
    let (Some(palm), Some(l), Some(r)) = (
        world.bodies.get(hand.palm),
        world.bodies.get(hand.fingers[0]),
        world.bodies.get(hand.fingers[1]),
    ) else {
        return 0.0;
    };
    let inv = pose_from_glam(palm.position()).inverse();
    let xl = (inv * pose_from_glam(l.position())).translation.x;
    let xr = (inv * pose_from_glam(r.position())).translation.x;
    (xr - xl - hand.finger_thickness).max(0.0)
}
