//! The object library: procedural objects generated from a seed, and mesh objects.
//!
//! Every object is a list of [`Part`]s in the object frame; each part is a [`Primitive`]. The
//! description is plain data (serde), so a scene file states the exact geometry that was
//! simulated, rendered and labelled. Cylinders and capsules use parry's convention: their axis is
//! the part's local `y` axis.
use crate::convert::pose_to_glam;
use crate::mesh::MeshLibrary;
use crate::SimError;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use parry3d::math::Vector;
use parry3d::shape::SharedShape;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// A convex (or mesh) building block of an object, in the part frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Primitive {
    /// A box with the given half extents.
    Cuboid {
        /// Half extents along x, y, z (metres).
        half_extents: [f32; 3],
    },
    /// A cylinder along the local y axis.
    Cylinder {
        /// Radius (metres).
        radius: f32,
        /// Half of the height along y (metres).
        half_height: f32,
    },
    /// A sphere.
    Ball {
        /// Radius (metres).
        radius: f32,
    },
    /// A capsule along the local y axis (segment ±`half_height`, swept by `radius`).
    Capsule {
        /// Radius (metres).
        radius: f32,
        /// Half length of the inner segment (metres).
        half_height: f32,
    },
    /// The convex hull of a point set.
    ConvexHull {
        /// Points in the part frame (metres).
        points: Vec<[f32; 3]>,
    },
    /// A triangle mesh from the mesh library, scaled uniformly.
    Mesh {
        /// Key of the mesh in the [`MeshLibrary`].
        key: String,
        /// Uniform scale applied to the stored vertices.
        scale: f32,
    },
}

/// One primitive placed in the object frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Part {
    /// Pose of the part frame in the object frame.
    pub object_from_part: Isometry3<f32>,
    /// The geometry.
    pub primitive: Primitive,
}

/// The family an object belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectKind {
    /// A box.
    Box,
    /// A cylinder.
    Cylinder,
    /// A sphere.
    Sphere,
    /// A capsule.
    Capsule,
    /// A torus approximated by a ring of capsules.
    Torus,
    /// A random convex hull.
    ConvexHull,
    /// Two boxes forming an L.
    LShape,
    /// A hollow cup with a handle (staves, a bottom disc and a capsule handle).
    Mug,
    /// A mesh object (YCB or random URDF).
    Mesh,
}

impl ObjectKind {
    /// The procedural kinds, in library order.
    pub const PROCEDURAL: [ObjectKind; 8] = [
        ObjectKind::Box,
        ObjectKind::Cylinder,
        ObjectKind::Sphere,
        ObjectKind::Capsule,
        ObjectKind::Torus,
        ObjectKind::ConvexHull,
        ObjectKind::LShape,
        ObjectKind::Mug,
    ];

    /// True for the "simple structure" kinds used by the easy test scenes (box, ball,
    /// cylinder).
    pub fn is_simple(self) -> bool {
        matches!(
            self,
            ObjectKind::Box | ObjectKind::Sphere | ObjectKind::Cylinder
        )
    }
}

/// A complete object description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectSpec {
    /// Human-readable unique name (e.g. `proc-017-mug`, `ycb/025_mug`).
    pub name: String,
    /// Object family.
    pub kind: ObjectKind,
    /// Parts in the object frame; their union is the object.
    pub parts: Vec<Part>,
}

fn check_positive(name: &'static str, v: f32) -> Result<(), SimError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(SimError::InvalidObject { reason: name })
    }
}

impl Primitive {
    fn scaled(&self, s: f32) -> Primitive {
        match self {
            Primitive::Cuboid { half_extents } => Primitive::Cuboid {
                half_extents: half_extents.map(|h| h * s),
            },
            Primitive::Cylinder {
                radius,
                half_height,
            } => Primitive::Cylinder {
                radius: radius * s,
                half_height: half_height * s,
            },
            Primitive::Ball { radius } => Primitive::Ball { radius: radius * s },
            Primitive::Capsule {
                radius,
                half_height,
            } => Primitive::Capsule {
                radius: radius * s,
                half_height: half_height * s,
            },
            Primitive::ConvexHull { points } => Primitive::ConvexHull {
                points: points.iter().map(|p| p.map(|c| c * s)).collect(),
            },
            Primitive::Mesh { key, scale } => Primitive::Mesh {
                key: key.clone(),
                scale: scale * s,
            },
        }
    }

    /// Builds the exact parry shape (meshes as triangle meshes).
    fn build(&self, meshes: &MeshLibrary) -> Result<SharedShape, SimError> {
        Ok(match self {
            Primitive::Cuboid {
                half_extents: [x, y, z],
            } => {
                for v in [x, y, z] {
                    check_positive("cuboid half extent must be > 0", *v)?;
                }
                SharedShape::cuboid(*x, *y, *z)
            }
            Primitive::Cylinder {
                radius,
                half_height,
            } => {
                check_positive("cylinder radius must be > 0", *radius)?;
                check_positive("cylinder half height must be > 0", *half_height)?;
                SharedShape::cylinder(*half_height, *radius)
            }
            Primitive::Ball { radius } => {
                check_positive("ball radius must be > 0", *radius)?;
                SharedShape::ball(*radius)
            }
            Primitive::Capsule {
                radius,
                half_height,
            } => {
                check_positive("capsule radius must be > 0", *radius)?;
                if !(half_height.is_finite() && *half_height >= 0.0) {
                    return Err(SimError::InvalidObject {
                        reason: "capsule half height must be >= 0",
                    });
                }
                SharedShape::capsule_y(*half_height, *radius)
            }
            Primitive::ConvexHull { points } => {
                if points.len() < 4 || points.iter().flatten().any(|c| !c.is_finite()) {
                    return Err(SimError::InvalidObject {
                        reason: "convex hull needs >= 4 finite points",
                    });
                }
                let pts: Vec<Vector> = points
                    .iter()
                    .map(|p| Vector::new(p[0], p[1], p[2]))
                    .collect();
                let hull = SharedShape::convex_hull(&pts).ok_or(SimError::InvalidObject {
                    reason: "degenerate convex hull (flat point set)",
                })?;
                let aabb = hull.compute_local_aabb();
                if (aabb.maxs - aabb.mins).min_element() < 1e-5 {
                    return Err(SimError::InvalidObject {
                        reason: "degenerate convex hull (flat point set)",
                    });
                }
                hull
            }
            Primitive::Mesh { key, scale } => {
                check_positive("mesh scale must be > 0", *scale)?;
                meshes.trimesh(key, *scale)?
            }
        })
    }

    /// Builds the shape used by the physics engine: convex pieces for meshes, else the exact shape.
    fn build_physics(&self, meshes: &MeshLibrary) -> Result<SharedShape, SimError> {
        match self {
            Primitive::Mesh { key, scale } => {
                check_positive("mesh scale must be > 0", *scale)?;
                meshes.convex_decomposition(key, *scale)
            }
            other => other.build(meshes),
        }
    }
}

impl ObjectSpec {
    /// The object scaled uniformly by `s` about its origin.
    pub fn scaled(&self, s: f32) -> ObjectSpec {
        ObjectSpec {
            name: self.name.clone(),
            kind: self.kind,
            parts: self
                .parts
                .iter()
                .map(|p| Part {
                    object_from_part: Isometry3::from_parts(
                        Translation3::from(p.object_from_part.translation.vector * s),
                        p.object_from_part.rotation,
                    ),
                    primitive: p.primitive.scaled(s),
                })
                .collect(),
        }
    }

    fn assemble(
        &self,
        meshes: &MeshLibrary,
        build: impl Fn(&Primitive, &MeshLibrary) -> Result<SharedShape, SimError>,
    ) -> Result<SharedShape, SimError> {
        if self.parts.is_empty() {
            return Err(SimError::InvalidObject {
                reason: "object has no parts",
            });
        }
        let mut pieces = Vec::new();
        for part in &self.parts {
            let shape = build(&part.primitive, meshes)?;
            let pose = pose_to_glam(&part.object_from_part);
            if !pose.is_finite() {
                return Err(SimError::InvalidObject {
                    reason: "part pose is not finite",
                });
            }
            // Compounds cannot nest composite shapes: flatten them.
            if let Some(compound) = shape.as_compound() {
                for (sub_pose, sub) in compound.shapes() {
                    pieces.push((pose * *sub_pose, sub.clone()));
                }
            } else {
                pieces.push((pose, shape));
            }
        }
        let single_identity = pieces.len() == 1 && {
            let p = &pieces[0].0;
            p.translation.length() < 1e-9 && p.rotation.is_near_identity()
        };
        if single_identity {
            return Ok(pieces
                .pop()
                .map(|p| p.1)
                .unwrap_or_else(|| SharedShape::ball(0.0)));
        }
        if pieces.iter().any(|(_, s)| s.as_composite_shape().is_some()) {
            return Err(SimError::InvalidObject {
                reason: "a mesh part must be the object's only part",
            });
        }
        Ok(SharedShape::compound(pieces))
    }

    /// The exact shape in the object frame (rendering, labels, gripper collision).
    pub fn build_shape(&self, meshes: &MeshLibrary) -> Result<SharedShape, SimError> {
        self.assemble(meshes, Primitive::build)
    }

    /// The shape the physics engine uses (meshes replaced by their convex decomposition).
    pub fn build_physics_shape(&self, meshes: &MeshLibrary) -> Result<SharedShape, SimError> {
        self.assemble(meshes, Primitive::build_physics)
    }
}

/// Which split an object belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Used in training scenes only.
    Train,
    /// Used in test scenes only.
    Test,
}

/// An object of the library with its fixed split.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LibraryObject {
    /// The object at unit scale.
    pub spec: ObjectSpec,
    /// Its split.
    pub split: Split,
    /// Second-smallest side of its bounding box at unit scale (m), 0 = unknown. Scaled to fit
    /// the hand's opening ([`crate::SceneRecipe::fit_width_m`]), it lets the hand close across
    /// the object whichever face it rests on: of the two smallest sides at least one lies
    /// horizontal.
    #[serde(default)]
    pub fit_extent_m: f32,
}

/// Second-smallest side of the local bounding box of `spec` at unit scale (m), 0 if it cannot
/// be built ([`LibraryObject::fit_extent_m`]).
pub fn fit_extent(spec: &ObjectSpec, meshes: &MeshLibrary) -> f32 {
    spec.build_shape(meshes)
        .map(|shape| {
            let aabb = shape.compute_local_aabb();
            let d = aabb.maxs - aabb.mins;
            middle_of([d.x, d.y, d.z])
        })
        .unwrap_or(0.0)
}

/// The middle value of three.
pub fn middle_of(mut v: [f32; 3]) -> f32 {
    v.sort_by(f32::total_cmp);
    v[1]
}

/// The seed of the procedural library: fixed, so that the objects and their split never change.
pub const PROCEDURAL_LIBRARY_SEED: u64 = 0x5053_4752_4153_5031; // "PSGRASP1"
/// Number of procedural prototypes (the paper's 149 train + 51 test).
pub const PROCEDURAL_LIBRARY_SIZE: usize = 200;
/// Number of procedural training prototypes.
pub const PROCEDURAL_TRAIN_COUNT: usize = 149;

/// A set of objects with a fixed train/test split.
#[derive(Debug, Clone, Default)]
pub struct ObjectLibrary {
    /// All objects.
    pub objects: Vec<LibraryObject>,
}

impl ObjectLibrary {
    /// The fixed procedural library: 200 prototypes (25 of each procedural kind), 149 train / 51
    /// test, chosen by a fixed seeded shuffle.
    pub fn procedural() -> Self {
        let mut order: Vec<usize> = (0..PROCEDURAL_LIBRARY_SIZE).collect();
        order.shuffle(&mut ChaCha8Rng::seed_from_u64(PROCEDURAL_LIBRARY_SEED));
        let mut is_train = [false; PROCEDURAL_LIBRARY_SIZE];
        for &i in &order[..PROCEDURAL_TRAIN_COUNT] {
            is_train[i] = true;
        }
        let objects = (0..PROCEDURAL_LIBRARY_SIZE)
            .map(|i| {
                let kind = ObjectKind::PROCEDURAL[i % ObjectKind::PROCEDURAL.len()];
                let mut rng = ChaCha8Rng::seed_from_u64(
                    PROCEDURAL_LIBRARY_SEED ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                );
                let spec = procedural_object(kind, &format!("proc-{i:03}"), &mut rng);
                LibraryObject {
                    fit_extent_m: fit_extent(&spec, &MeshLibrary::default()),
                    spec,
                    split: if is_train[i] {
                        Split::Train
                    } else {
                        Split::Test
                    },
                }
            })
            .collect();
        Self { objects }
    }

    /// The objects of one split, optionally only the simple kinds (box, ball, cylinder).
    pub fn select(&self, split: Option<Split>, simple_only: bool) -> Vec<&LibraryObject> {
        self.objects
            .iter()
            .filter(|o| split.is_none_or(|s| o.split == s))
            .filter(|o| !simple_only || o.spec.kind.is_simple())
            .collect()
    }

    /// Appends another library.
    pub fn extend(&mut self, other: ObjectLibrary) {
        self.objects.extend(other.objects);
    }
}

fn uni(rng: &mut impl Rng, lo: f32, hi: f32) -> f32 {
    rng.random_range(lo..hi)
}

fn at(x: f32, y: f32, z: f32) -> Isometry3<f32> {
    Isometry3::translation(x, y, z)
}

/// Generates one procedural object of `kind` at unit scale (sizes in metres, chosen so that most
/// objects have at least one dimension the 80 mm gripper can span).
pub fn procedural_object(kind: ObjectKind, prefix: &str, rng: &mut impl Rng) -> ObjectSpec {
    let id = Isometry3::identity();
    let parts = match kind {
        ObjectKind::Box => {
            let mut h = [
                uni(rng, 0.012, 0.06),
                uni(rng, 0.012, 0.06),
                uni(rng, 0.01, 0.05),
            ];
            // Keep at least one side graspable.
            let min = h.iter().cloned().fold(f32::INFINITY, f32::min);
            if min > 0.03 {
                h[rng.random_range(0..3)] = uni(rng, 0.012, 0.03);
            }
            vec![Part {
                object_from_part: id,
                primitive: Primitive::Cuboid { half_extents: h },
            }]
        }
        ObjectKind::Cylinder => vec![Part {
            object_from_part: id,
            primitive: Primitive::Cylinder {
                radius: uni(rng, 0.012, 0.03),
                half_height: uni(rng, 0.02, 0.08),
            },
        }],
        ObjectKind::Sphere => {
            vec![Part {
                object_from_part: id,
                primitive: Primitive::Ball {
                    radius: uni(rng, 0.015, 0.032),
                },
            }]
        }
        ObjectKind::Capsule => vec![Part {
            object_from_part: id,
            primitive: Primitive::Capsule {
                radius: uni(rng, 0.01, 0.028),
                half_height: uni(rng, 0.015, 0.06),
            },
        }],
        ObjectKind::Torus => {
            let major = uni(rng, 0.03, 0.06);
            let minor = uni(rng, 0.007, 0.015);
            let n = 12;
            let seg_half = major * (std::f32::consts::PI / n as f32).tan();
            (0..n)
                .map(|i| {
                    let phi = 2.0 * std::f32::consts::PI * i as f32 / n as f32;
                    // Capsule axis (local y) tangent to the ring in the xy plane.
                    let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), phi);
                    Part {
                        object_from_part: Isometry3::from_parts(
                            Translation3::new(major * phi.cos(), major * phi.sin(), 0.0),
                            rot,
                        ),
                        primitive: Primitive::Capsule {
                            radius: minor,
                            half_height: seg_half,
                        },
                    }
                })
                .collect()
        }
        ObjectKind::ConvexHull => {
            let axes = [
                uni(rng, 0.015, 0.05),
                uni(rng, 0.015, 0.05),
                uni(rng, 0.012, 0.04),
            ];
            let n = rng.random_range(8..20);
            let points = (0..n)
                .map(|_| {
                    // Uniform direction on the unit sphere, scaled onto the ellipsoid.
                    let z: f32 = uni(rng, -1.0, 1.0);
                    let t: f32 = uni(rng, 0.0, 2.0 * std::f32::consts::PI);
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let s = uni(rng, 0.7, 1.0);
                    [
                        axes[0] * r * t.cos() * s,
                        axes[1] * r * t.sin() * s,
                        axes[2] * z * s,
                    ]
                })
                .collect();
            vec![Part {
                object_from_part: id,
                primitive: Primitive::ConvexHull { points },
            }]
        }
        ObjectKind::LShape => {
            let t = uni(rng, 0.01, 0.025);
            let w = uni(rng, 0.012, 0.03);
            let la = uni(rng, 0.04, 0.08);
            let lb = uni(rng, 0.03, 0.06);
            vec![
                Part {
                    object_from_part: at(0.0, 0.0, 0.0),
                    primitive: Primitive::Cuboid {
                        half_extents: [la, w, t],
                    },
                },
                Part {
                    object_from_part: at(la - t, 0.0, lb),
                    primitive: Primitive::Cuboid {
                        half_extents: [t, w, lb - t],
                    },
                },
            ]
        }
        ObjectKind::Mug => {
            let radius = uni(rng, 0.028, 0.04);
            let half_h = uni(rng, 0.035, 0.055);
            let wall = uni(rng, 0.004, 0.007);
            let n = 12;
            let stave_half_w = (radius) * (std::f32::consts::PI / n as f32).tan() + 0.5 * wall;
            let mut parts: Vec<Part> = (0..n)
                .map(|i| {
                    let phi = 2.0 * std::f32::consts::PI * i as f32 / n as f32;
                    let rc = radius - 0.5 * wall;
                    Part {
                        object_from_part: Isometry3::from_parts(
                            Translation3::new(rc * phi.cos(), rc * phi.sin(), 0.0),
                            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), phi),
                        ),
                        primitive: Primitive::Cuboid {
                            half_extents: [0.5 * wall, stave_half_w, half_h],
                        },
                    }
                })
                .collect();
            // Bottom disc: a cylinder whose axis (y) is turned onto z.
            parts.push(Part {
                object_from_part: Isometry3::from_parts(
                    Translation3::new(0.0, 0.0, -half_h + 0.5 * wall),
                    UnitQuaternion::from_axis_angle(
                        &Vector3::x_axis(),
                        std::f32::consts::FRAC_PI_2,
                    ),
                ),
                primitive: Primitive::Cylinder {
                    radius,
                    half_height: 0.5 * wall,
                },
            });
            // Handle: three capsules forming a bracket on the +x side.
            let hr = uni(rng, 0.004, 0.007);
            let reach = uni(rng, 0.015, 0.025);
            let hz = 0.6 * half_h;
            let side_half = 0.5 * reach;
            let horiz =
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f32::consts::FRAC_PI_2);
            parts.push(Part {
                object_from_part: Isometry3::from_parts(
                    Translation3::new(radius + side_half, 0.0, hz),
                    horiz,
                ),
                primitive: Primitive::Capsule {
                    radius: hr,
                    half_height: side_half,
                },
            });
            parts.push(Part {
                object_from_part: Isometry3::from_parts(
                    Translation3::new(radius + side_half, 0.0, -hz),
                    horiz,
                ),
                primitive: Primitive::Capsule {
                    radius: hr,
                    half_height: side_half,
                },
            });
            parts.push(Part {
                object_from_part: Isometry3::from_parts(
                    Translation3::new(radius + reach, 0.0, 0.0),
                    UnitQuaternion::from_axis_angle(
                        &Vector3::x_axis(),
                        std::f32::consts::FRAC_PI_2,
                    ),
                ),
                primitive: Primitive::Capsule {
                    radius: hr,
                    half_height: hz,
                },
            });
            parts
        }
        ObjectKind::Mesh => Vec::new(),
    };
    let kind_name = serde_json::to_value(kind)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default();
    ObjectSpec {
        name: format!("{prefix}-{kind_name}"),
        kind,
        parts,
    }
}

/// Local bounding-sphere radius of a shape (about the object origin).
pub(crate) fn bounding_radius(shape: &SharedShape) -> f32 {
    let aabb = shape.compute_local_aabb();
    aabb.mins.abs().max(aabb.maxs.abs()).length()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn library_is_fixed_and_split_149_51() {
        let a = ObjectLibrary::procedural();
        let b = ObjectLibrary::procedural();
        assert_eq!(a.objects, b.objects);
        assert_eq!(a.select(Some(Split::Train), false).len(), 149);
        assert_eq!(a.select(Some(Split::Test), false).len(), 51);
        assert!(!a.select(Some(Split::Test), true).is_empty());
        let meshes = MeshLibrary::default();
        for o in &a.objects {
            let shape = o
                .spec
                .build_shape(&meshes)
                .expect("procedural objects build");
            let r = bounding_radius(&shape);
            assert!(r > 0.005 && r < 0.2, "{} has radius {r}", o.spec.name);
        }
    }

    #[test]
    fn bad_dimensions_are_errors_not_panics() {
        let spec = ObjectSpec {
            name: "bad".into(),
            kind: ObjectKind::Box,
            parts: vec![Part {
                object_from_part: Isometry3::identity(),
                primitive: Primitive::Cuboid {
                    half_extents: [0.01, f32::NAN, 0.01],
                },
            }],
        };
        assert!(matches!(
            spec.build_shape(&MeshLibrary::default()),
            Err(SimError::InvalidObject { .. })
        ));
        let flat = ObjectSpec {
            name: "flat".into(),
            kind: ObjectKind::ConvexHull,
            parts: vec![Part {
                object_from_part: Isometry3::identity(),
                primitive: Primitive::ConvexHull {
                    points: vec![
                        [0.0, 0.0, 0.0],
                        [1.0, 0.0, 0.0],
                        [0.0, 1.0, 0.0],
                        [1.0, 1.0, 0.0],
                    ],
                },
            }],
        };
        assert!(flat.build_shape(&MeshLibrary::default()).is_err());
    }

    #[test]
    fn scaling_scales_extent() {
        let lib = ObjectLibrary::procedural();
        let meshes = MeshLibrary::default();
        for o in lib.objects.iter().take(16) {
            let r1 = bounding_radius(&o.spec.build_shape(&meshes).unwrap());
            let r2 = bounding_radius(&o.spec.scaled(1.5).build_shape(&meshes).unwrap());
            assert!(
                (r2 / r1 - 1.5).abs() < 0.02,
                "{}: {r1} -> {r2}",
                o.spec.name
            );
        }
    }
}
