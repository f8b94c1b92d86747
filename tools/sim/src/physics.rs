//! Dropping objects into the bin and letting them settle, with rapier3d, and the building blocks
//! that grasp execution (`psgrasp-eval`) sets up its world with: [`physics_world`], [`insert_bin`],
//! [`insert_object`], [`body_at_rest`], [`step_until_rest`] and [`pose_in_bin`].
use crate::convert::{pose_from_glam, pose_to_glam, vec_to_glam};
use crate::mesh::MeshLibrary;
use crate::objects::{bounding_radius, ObjectSpec};
use crate::scene::{validate_bin, SceneDescription, SceneObject};
use crate::SimError;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use psgrasp_geometry::BinModel;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rapier3d::prelude::{
    ColliderBuilder, InteractionGroups, PhysicsWorld, RigidBody, RigidBodyBuilder, RigidBodyHandle,
    SharedShape,
};
use serde::{Deserialize, Serialize};

/// Settings of the drop-and-settle simulation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SettleConfig {
    /// Physics time step in seconds.
    pub dt_s: f32,
    /// Simulated time limit; the scene is taken as it is when it runs out (rolling bodies).
    pub max_time_s: f32,
    /// A body is at rest below this linear speed (m/s) ...
    pub rest_linear_speed: f32,
    /// ... and this angular speed (rad/s).
    pub rest_angular_speed: f32,
    /// Gap between objects released over the same spot, stacked (m).
    pub spawn_gap_m: f32,
    /// Objects are released above the central part of the bin floor: this share of each side
    /// of the inner footprint (1 = anywhere over the floor). Our reading of the paper, which
    /// drops objects into the bin (and re-drops those lying against a wall), and of VGN, which
    /// drops its piles from the middle of the workspace (`docs/datasets.md`).
    pub drop_region_fraction: f32,
    /// How high above the floor the lowest object is released: the gap under its bounding
    /// sphere, m (objects released over the same spot stack above it, `spawn_gap_m` apart).
    /// Low releases settle where they land instead of scattering; at least the bin's depth
    /// releases everything above the rim.
    pub release_height_m: f32,
    /// Friction coefficient of all colliders.
    pub friction: f32,
    /// Restitution of all colliders.
    pub restitution: f32,
    /// Object density (kg/m³).
    pub density: f32,
    /// Extra thickness given to the bin's physics walls, outward only, against tunnelling (m).
    pub wall_padding_m: f32,
    /// Linear velocity damping of the objects (1/s); rapier has no rolling friction, so a
    /// little damping lets round objects come to rest within the time limit.
    pub linear_damping: f32,
    /// Angular velocity damping of the objects (1/s).
    pub angular_damping: f32,
}

impl Default for SettleConfig {
    fn default() -> Self {
        Self {
            dt_s: 1.0 / 100.0,
            max_time_s: 4.0,
            rest_linear_speed: 0.01,
            rest_angular_speed: 0.1,
            spawn_gap_m: 0.01,
            drop_region_fraction: 0.5,
            release_height_m: 0.02,
            friction: 0.7,
            restitution: 0.05,
            density: 500.0,
            wall_padding_m: 0.05,
            linear_damping: 0.2,
            angular_damping: 1.0,
        }
    }
}

/// What happened during settling.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SettleReport {
    /// Simulated seconds.
    pub simulated_s: f32,
    /// True if every body came to rest before the time limit.
    pub at_rest: bool,
    /// Objects dropped.
    pub dropped: usize,
    /// Objects removed because they ended outside the bin.
    pub removed: usize,
}

/// Drops `objects` (already scaled) into `bin` from random poses and simulates until everything
/// rests or the time limit runs out. Objects that end outside the bin are removed. Deterministic
/// for a given `rng` state on a given build.
pub fn drop_and_settle(
    bin: &BinModel,
    objects: &[ObjectSpec],
    meshes: &MeshLibrary,
    config: &SettleConfig,
    rng: &mut ChaCha8Rng,
) -> Result<(SceneDescription, SettleReport), SimError> {
    validate_bin(bin)?;
    if !(config.dt_s > 0.0
        && config.dt_s.is_finite()
        && config.max_time_s.is_finite()
        && config.max_time_s >= 0.0)
    {
        return Err(SimError::InvalidConfig {
            reason: "settle dt_s must be > 0 and max_time_s >= 0",
        });
    }
    if !(config.drop_region_fraction > 0.0 && config.drop_region_fraction <= 1.0) {
        return Err(SimError::InvalidConfig {
            reason: "settle drop_region_fraction must be in (0, 1]",
        });
    }
    if !(config.release_height_m >= 0.0 && config.release_height_m <= 10.0) {
        return Err(SimError::InvalidConfig {
            reason: "settle release_height_m must be in 0..=10 m",
        });
    }
    let mut world = physics_world(config.dt_s);

    // The bin, padded outward so that fast objects cannot tunnel through its thin walls.
    insert_bin(&mut world, bin, config, ColliderTags::default());

    // Spawn poses: random xy over the drop region, stacked in z without overlap.
    let mut placed: Vec<(Vector3<f32>, f32)> = Vec::new();
    let mut handles: Vec<RigidBodyHandle> = Vec::new();
    for spec in objects {
        let shape = spec.build_physics_shape(meshes)?;
        let r = bounding_radius(&shape);
        let (x, y) = spawn_xy(bin, r, config.drop_region_fraction, rng);
        let mut z = bin.floor_center.z + config.release_height_m + r;
        for (p, pr) in &placed {
            let dxy = ((p.x - x).powi(2) + (p.y - y).powi(2)).sqrt();
            if dxy < r + pr + config.spawn_gap_m {
                z = z.max(p.z + pr + r + config.spawn_gap_m);
            }
        }
        let pos = Vector3::new(x, y, z);
        placed.push((pos, r));
        let rot = random_rotation(rng);
        let pose = Isometry3::from_parts(Translation3::from(pos), rot);
        let handle = insert_object(
            &mut world,
            shape,
            &pose,
            config,
            true,
            ColliderTags::default(),
        );
        handles.push(handle);
    }

    let max_steps = (config.max_time_s / config.dt_s).ceil() as usize;
    // Freshly spawned bodies do not move yet: the first rest test comes after 10 steps.
    let (steps, at_rest) = step_until_rest(&mut world, max_steps, 10, handles.is_empty(), |w| {
        handles
            .iter()
            .all(|h| w.bodies.get(*h).is_none_or(|b| body_at_rest(b, config)))
    });

    let mut out = Vec::new();
    for (spec, h) in objects.iter().zip(&handles) {
        if let Some(pose) = pose_in_bin(&world, *h, bin) {
            out.push(SceneObject {
                spec: spec.clone(),
                workspace_from_object: pose,
            });
        }
    }
    let report = SettleReport {
        simulated_s: steps as f32 * config.dt_s,
        at_rest,
        dropped: objects.len(),
        removed: objects.len() - out.len(),
    };
    Ok((
        SceneDescription {
            bin: *bin,
            objects: out,
        },
        report,
    ))
}

/// Where an object of bounding radius `r` is released (x, y): uniform over the central
/// `fraction` of each side of the bin's inner footprint, and never so close to a wall that the
/// object would start inside it.
pub fn spawn_xy(bin: &BinModel, r: f32, fraction: f32, rng: &mut impl Rng) -> (f32, f32) {
    let c = bin.floor_center;
    let [lx, ly, _] = bin.inner_size_m;
    let half = |l: f32| (0.5 * l * fraction).min(0.5 * l - r).max(0.0);
    let draw = |h: f32, rng: &mut dyn rand::RngCore| {
        if h > 0.0 {
            rng.random_range(-h..=h)
        } else {
            0.0
        }
    };
    let x = c.x + draw(half(lx), rng);
    let y = c.y + draw(half(ly), rng);
    (x, y)
}

/// A physics world with gravity (−9.81 m/s² along workspace z) and time step `dt_s`; every
/// other integration parameter is rapier's default.
pub fn physics_world(dt_s: f32) -> PhysicsWorld {
    let mut world = PhysicsWorld::new();
    world.gravity = vec_to_glam(&Vector3::new(0.0, 0.0, -9.81));
    world.integration_parameters.dt = dt_s;
    world
}

/// Collision groups and user data given to the colliders (and bodies) that [`insert_bin`] and
/// [`insert_object`] create. The default is rapier's: every group, user data 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColliderTags {
    /// Collision groups of the colliders.
    pub groups: InteractionGroups,
    /// `user_data` of the colliders and of an object's rigid body.
    pub user_data: u128,
}

impl Default for ColliderTags {
    fn default() -> Self {
        Self {
            groups: InteractionGroups::all(),
            user_data: 0,
        }
    }
}

/// Inserts the bin's five boxes (floor and four walls) as fixed colliders with `material`'s
/// friction and restitution. The floor and walls are padded outward by
/// [`SettleConfig::wall_padding_m`] (the inner faces stay where they are) so that fast objects
/// cannot tunnel through them.
pub fn insert_bin(
    world: &mut PhysicsWorld,
    bin: &BinModel,
    material: &SettleConfig,
    tags: ColliderTags,
) {
    let pad = material.wall_padding_m.max(0.0);
    let outward = [
        Vector3::new(0.0, 0.0, -1.0),
        -Vector3::x(),
        Vector3::x(),
        -Vector3::y(),
        Vector3::y(),
    ];
    for (b, dir) in bin.boxes().iter().zip(outward) {
        let half = b.half_extents + dir.abs() * (0.5 * pad);
        let centre = b.parent_from_box.translation.vector + dir * (0.5 * pad);
        let collider = ColliderBuilder::new(SharedShape::cuboid(half.x, half.y, half.z))
            .position(pose_to_glam(&Isometry3::from_parts(
                Translation3::from(centre),
                UnitQuaternion::identity(),
            )))
            .friction(material.friction)
            .restitution(material.restitution)
            .collision_groups(tags.groups)
            .user_data(tags.user_data)
            .build();
        world.insert_collider(collider, None);
    }
}

/// Inserts one object: a dynamic body at `pose` with `material`'s damping (continuous collision
/// detection if `ccd`) and a collider of `shape` with its friction, restitution and density.
pub fn insert_object(
    world: &mut PhysicsWorld,
    shape: SharedShape,
    pose: &Isometry3<f32>,
    material: &SettleConfig,
    ccd: bool,
    tags: ColliderTags,
) -> RigidBodyHandle {
    let body = RigidBodyBuilder::dynamic()
        .pose(pose_to_glam(pose))
        .ccd_enabled(ccd)
        .linear_damping(material.linear_damping.max(0.0))
        .angular_damping(material.angular_damping.max(0.0))
        .user_data(tags.user_data)
        .build();
    let handle = world.insert_body(body);
    let collider = ColliderBuilder::new(shape)
        .friction(material.friction)
        .restitution(material.restitution)
        .density(material.density)
        .collision_groups(tags.groups)
        .user_data(tags.user_data)
        .build();
    world.insert_collider(collider, Some(handle));
    handle
}

/// True if `body` sleeps or moves slower than [`SettleConfig::rest_linear_speed`] and
/// [`SettleConfig::rest_angular_speed`].
pub fn body_at_rest(body: &RigidBody, material: &SettleConfig) -> bool {
    body.is_sleeping()
        || (body.linvel().length() < material.rest_linear_speed
            && body.angvel().length() < material.rest_angular_speed)
}

/// Steps `world` until `at_rest` holds or `max_steps` steps are done; `at_rest` is tested after
/// every `check_every` steps, and `initially_at_rest` stands for it before the first step.
/// Returns the steps taken and whether it ended at rest.
pub fn step_until_rest(
    world: &mut PhysicsWorld,
    max_steps: usize,
    check_every: usize,
    initially_at_rest: bool,
    at_rest: impl Fn(&PhysicsWorld) -> bool,
) -> (usize, bool) {
    let mut steps = 0;
    let mut rest = initially_at_rest;
    while !rest && steps < max_steps {
        world.step();
        steps += 1;
        if steps.is_multiple_of(check_every) {
            rest = at_rest(world);
        }
    }
    (steps, rest)
}

/// The pose of `body` if it is still in the world, finite and inside `bin`: within the inner
/// footprint, at most 1 cm below the floor and 5 cm above the rim.
pub fn pose_in_bin(
    world: &PhysicsWorld,
    body: RigidBodyHandle,
    bin: &BinModel,
) -> Option<Isometry3<f32>> {
    let pose = pose_from_glam(world.bodies.get(body)?.position());
    let p = pose.translation.vector;
    if !p.iter().all(|v| v.is_finite()) {
        return None;
    }
    let c = bin.floor_center;
    let [lx, ly, _] = bin.inner_size_m;
    let inside = (p.x - c.x).abs() <= 0.5 * lx
        && (p.y - c.y).abs() <= 0.5 * ly
        && p.z >= c.z - 0.01
        && p.z <= bin.rim_z() + 0.05;
    inside.then_some(pose)
}

/// A uniformly distributed random rotation (Shoemake's method).
pub fn random_rotation(rng: &mut impl Rng) -> UnitQuaternion<f32> {
    let u1: f32 = rng.random();
    let u2: f32 = rng.random_range(0.0..std::f32::consts::TAU);
    let u3: f32 = rng.random_range(0.0..std::f32::consts::TAU);
    let a = (1.0 - u1).sqrt();
    let b = u1.sqrt();
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        a * u2.sin(),
        a * u2.cos(),
        b * u3.sin(),
        b * u3.cos(),
    ))
}
