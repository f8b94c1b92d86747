//! A settled bin scene and the geometric queries on it: ray casts, depth rendering and box
//! collision tests, all against the exact shapes through a parry BVH.
use crate::convert::{point_from_glam, point_to_glam, pose_to_glam, vec_from_glam, vec_to_glam};
use crate::mesh::MeshLibrary;
use crate::objects::ObjectSpec;
use crate::SimError;
use nalgebra::{Isometry3, Point3, Vector3};
use parry3d::bounding_volume::{Aabb, BoundingVolume};
use parry3d::math::Pose;
use parry3d::partitioning::{Bvh, BvhBuildStrategy};
use parry3d::query::{intersection_test, PointQuery, Ray};
use parry3d::shape::{Cuboid, SharedShape, TriMesh, TriMeshFlags};
use psgrasp_geometry::{BinModel, CameraModel, DepthImage, OrientedBox};
use serde::{Deserialize, Serialize};
use std::sync::{Arc, OnceLock};

/// An object placed in the scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneObject {
    /// Geometry (already scaled).
    pub spec: ObjectSpec,
    /// Pose of the object frame in the workspace frame.
    pub workspace_from_object: Isometry3<f32>,
}

/// The plain-data description of a scene (what a scene file stores).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneDescription {
    /// The bin.
    pub bin: BinModel,
    /// The objects; an object's id is its index here.
    pub objects: Vec<SceneObject>,
}

/// What a ray hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HitTarget {
    /// Object with this index.
    Object(usize),
    /// The bin (floor or a wall).
    Bin,
}

/// A ray hit in the workspace frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    /// Distance along the (unit) ray.
    pub toi: f32,
    /// Hit point.
    pub point: Point3<f32>,
    /// Outward unit surface normal at the hit.
    pub normal: Vector3<f32>,
    /// What was hit.
    pub target: HitTarget,
}

/// A rendered frame: depth plus a per-pixel segmentation.
#[derive(Debug, Clone, PartialEq)]
pub struct Rendering {
    /// Depth along the optical axis in metres, 0 where the ray hits nothing.
    pub depth: DepthImage,
    /// Per pixel: 0 = nothing, 1 = bin, `2 + i` = object `i`.
    pub segmentation: Vec<u16>,
}

/// Segmentation value of the bin.
pub const SEGMENT_BIN: u16 = 1;
/// Segmentation value of object 0 (object `i` is `SEGMENT_OBJECT0 + i`).
pub const SEGMENT_OBJECT0: u16 = 2;

/// An object whose bounding box comes this close to a side wall lies against it (m): the
/// fingers of a top-down grasp cannot get between them.
pub const NEAR_WALL_M: f32 = 0.02;

/// Objects of a scene by where they lie relative to the side walls ([`Scene::wall_zones`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct WallZones {
    /// Objects counted.
    pub objects: usize,
    /// Within [`NEAR_WALL_M`] of a side wall (corners included).
    pub near_wall: usize,
    /// Within [`NEAR_WALL_M`] of two perpendicular side walls.
    pub in_corner: usize,
}

/// Where one object lies relative to the side walls ([`Scene::object_wall_zone`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WallZone {
    /// Farther than [`NEAR_WALL_M`] from every side wall.
    Interior,
    /// Within [`NEAR_WALL_M`] of one side wall, not in a corner.
    Wall,
    /// Within [`NEAR_WALL_M`] of two perpendicular side walls.
    Corner,
}

impl WallZone {
    /// Every zone, from the bin's middle outwards.
    pub const ALL: [Self; 3] = [Self::Interior, Self::Wall, Self::Corner];

    /// The zone of a bounding box `gap_x` and `gap_y` from the nearest x and y walls (m).
    pub fn of_gaps(gap_x: f32, gap_y: f32) -> Self {
        if gap_x.max(gap_y) < NEAR_WALL_M {
            Self::Corner
        } else if gap_x.min(gap_y) < NEAR_WALL_M {
            Self::Wall
        } else {
            Self::Interior
        }
    }
}

impl FromIterator<WallZone> for WallZones {
    fn from_iter<I: IntoIterator<Item = WallZone>>(zones: I) -> Self {
        let mut counts = Self::default();
        for zone in zones {
            counts.objects += 1;
            counts.near_wall += usize::from(zone != WallZone::Interior);
            counts.in_corner += usize::from(zone == WallZone::Corner);
        }
        counts
    }
}

impl std::ops::AddAssign for WallZones {
    fn add_assign(&mut self, o: Self) {
        self.objects += o.objects;
        self.near_wall += o.near_wall;
        self.in_corner += o.in_corner;
    }
}

/// A scene ready for queries: exact shapes, their poses and a BVH over them.
#[derive(Clone)]
pub struct Scene {
    description: SceneDescription,
    /// Exact object shapes followed by the five bin boxes (ray casts, rendering).
    shapes: Vec<SharedShape>,
    /// Solid shapes for box collision tests: the exact shape for primitives, the convex
    /// decomposition for meshes (a triangle mesh has no inside and is slow to test).
    collision_shapes: Vec<SharedShape>,
    /// Per object, its triangle mesh with pseudo-normals (built on the first inside query): a
    /// plain parry triangle mesh has no inside, so every point would count as outside.
    oriented_meshes: Vec<OnceLock<Option<Arc<TriMesh>>>>,
    poses: Vec<Pose>,
    bvh: Bvh,
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("description", &self.description)
            .finish_non_exhaustive()
    }
}

impl Scene {
    /// Builds a scene of procedural objects (no meshes).
    pub fn new(description: SceneDescription) -> Result<Self, SimError> {
        Self::with_meshes(description, &MeshLibrary::default())
    }

    /// Builds a scene whose objects may reference meshes of `meshes`.
    pub fn with_meshes(
        description: SceneDescription,
        meshes: &MeshLibrary,
    ) -> Result<Self, SimError> {
        validate_bin(&description.bin)?;
        let mut shapes = Vec::with_capacity(description.objects.len() + 5);
        let mut collision_shapes = Vec::with_capacity(description.objects.len() + 5);
        let mut poses = Vec::with_capacity(description.objects.len() + 5);
        for obj in &description.objects {
            let pose = pose_to_glam(&obj.workspace_from_object);
            if !pose.is_finite() {
                return Err(SimError::InvalidObject {
                    reason: "object pose is not finite",
                });
            }
            let exact = obj.spec.build_shape(meshes)?;
            let has_mesh = obj
                .spec
                .parts
                .iter()
                .any(|p| matches!(p.primitive, crate::Primitive::Mesh { .. }));
            collision_shapes.push(if has_mesh {
                obj.spec.build_physics_shape(meshes)?
            } else {
                exact.clone()
            });
            shapes.push(exact);
            poses.push(pose);
        }
        for b in description.bin.boxes() {
            let cuboid = SharedShape::new(Cuboid::new(vec_to_glam(&b.half_extents)));
            collision_shapes.push(cuboid.clone());
            shapes.push(cuboid);
            poses.push(pose_to_glam(&b.parent_from_box));
        }
        let aabbs: Vec<Aabb> = shapes
            .iter()
            .zip(&collision_shapes)
            .zip(&poses)
            .map(|((s, c), p)| s.compute_aabb(p).merged(&c.compute_aabb(p)))
            .collect();
        let bvh = Bvh::from_leaves(BvhBuildStrategy::Binned, &aabbs);
        Ok(Self {
            oriented_meshes: (0..description.objects.len())
                .map(|_| OnceLock::new())
                .collect(),
            description,
            shapes,
            collision_shapes,
            poses,
            bvh,
        })
    }

    /// The plain description.
    pub fn description(&self) -> &SceneDescription {
        &self.description
    }

    /// The bin.
    pub fn bin(&self) -> &BinModel {
        &self.description.bin
    }

    /// The objects.
    pub fn objects(&self) -> &[SceneObject] {
        &self.description.objects
    }

    /// Number of objects.
    pub fn object_count(&self) -> usize {
        self.description.objects.len()
    }

    fn target_of(&self, leaf: usize) -> HitTarget {
        if leaf < self.object_count() {
            HitTarget::Object(leaf)
        } else {
            HitTarget::Bin
        }
    }

    /// Casts a ray (`dir` need not be unit; `toi` is reported in metres) against everything.
    pub fn cast_ray(
        &self,
        origin: &Point3<f32>,
        dir: &Vector3<f32>,
        max_dist: f32,
    ) -> Option<RayHit> {
        let n = dir.norm();
        if !(n > 0.0 && n.is_finite()) {
            return None;
        }
        let ray = Ray::new(point_to_glam(origin), vec_to_glam(&(dir / n)));
        let (leaf, _) = self.bvh.cast_ray(&ray, max_dist, |i, best| {
            self.shapes[i as usize].cast_ray(&self.poses[i as usize], &ray, best, true)
        })?;
        let i = leaf as usize;
        let hit = self.shapes[i].cast_ray_and_get_normal(&self.poses[i], &ray, max_dist, true)?;
        Some(RayHit {
            toi: hit.time_of_impact,
            point: point_from_glam(ray.point_at(hit.time_of_impact)),
            normal: vec_from_glam(hit.normal),
            target: self.target_of(i),
        })
    }

    /// Casts a ray against object `index` only. With `solid = false` a ray starting inside the
    /// object reports where it leaves it. Returns the distance and the outward surface normal.
    pub fn cast_ray_object(
        &self,
        index: usize,
        origin: &Point3<f32>,
        dir: &Vector3<f32>,
        max_dist: f32,
        solid: bool,
    ) -> Option<(f32, Vector3<f32>)> {
        if index >= self.object_count() {
            return None;
        }
        let shape = &self.shapes[index];
        let n = dir.norm();
        if !(n > 0.0 && n.is_finite()) {
            return None;
        }
        let ray = Ray::new(point_to_glam(origin), vec_to_glam(&(dir / n)));
        let hit = shape.cast_ray_and_get_normal(&self.poses[index], &ray, max_dist, solid)?;
        // parry reports the normal facing the ray; make it the outward surface normal.
        let mut normal = vec_from_glam(hit.normal);
        if !solid && normal.dot(dir) < 0.0 && self.object_contains_point(index, origin) {
            normal = -normal;
        }
        Some((hit.time_of_impact, normal))
    }

    /// True if `p` lies inside object `index` (false for an unknown index). A mesh object's
    /// inside is judged by its triangles' pseudo-normals (the side of the nearest feature).
    pub fn object_contains_point(&self, index: usize, p: &Point3<f32>) -> bool {
        if index >= self.object_count() {
            return false;
        }
        let q = point_to_glam(p);
        match self.oriented_mesh(index) {
            Some(mesh) => mesh.contains_point(&self.poses[index], q),
            None => self.shapes[index].contains_point(&self.poses[index], q),
        }
    }

    /// Object `index`'s triangle mesh with pseudo-normals; `None` when it is not a mesh.
    fn oriented_mesh(&self, index: usize) -> Option<&TriMesh> {
        self.oriented_meshes[index]
            .get_or_init(|| {
                let mut mesh = self.shapes[index].as_trimesh()?.clone();
                // Pseudo-normals need no particular topology: the call cannot fail for them.
                mesh.set_flags(mesh.flags() | TriMeshFlags::ORIENTED).ok()?;
                Some(Arc::new(mesh))
            })
            .as_deref()
    }

    /// Radius of a sphere about the object's origin that encloses object `index`.
    pub fn object_bounding_radius(&self, index: usize) -> Option<f32> {
        (index < self.object_count()).then(|| crate::objects::bounding_radius(&self.shapes[index]))
    }

    /// World-frame (workspace-frame) axis-aligned bounds `(min, max)` of object `index`; `None`
    /// for an unknown index.
    pub fn object_aabb(&self, index: usize) -> Option<(Point3<f32>, Point3<f32>)> {
        (index < self.object_count()).then(|| {
            let aabb = self.shapes[index].compute_aabb(&self.poses[index]);
            (point_from_glam(aabb.mins), point_from_glam(aabb.maxs))
        })
    }

    /// Where the objects lie relative to the bin's side walls (their world-frame bounding
    /// boxes against the inner footprint).
    pub fn wall_zones(&self) -> WallZones {
        (0..self.object_count())
            .filter_map(|i| self.object_wall_zone(i))
            .collect()
    }

    /// Where object `index` lies relative to the side walls (its world-frame bounding box
    /// against the inner footprint); `None` for an unknown index.
    pub fn object_wall_zone(&self, index: usize) -> Option<WallZone> {
        let [gap_x, gap_y] = self.object_wall_gaps(index)?;
        Some(WallZone::of_gaps(gap_x, gap_y))
    }

    /// Gaps between object `index`'s world-frame bounding box and the nearest x wall and the
    /// nearest y wall of the inner footprint, metres (negative: it overlaps the wall's plane);
    /// `None` for an unknown index.
    pub fn object_wall_gaps(&self, index: usize) -> Option<[f32; 2]> {
        let bin = self.bin();
        let c = bin.floor_center;
        let [lx, ly, _] = bin.inner_size_m;
        let (lo, hi) = self.object_aabb(index)?;
        let gap_x = (lo.x - (c.x - 0.5 * lx)).min((c.x + 0.5 * lx) - hi.x);
        let gap_y = (lo.y - (c.y - 0.5 * ly)).min((c.y + 0.5 * ly) - hi.y);
        Some([gap_x, gap_y])
    }

    /// Signed distance from `p` to the surface of object `index` (negative inside); `None` for
    /// an unknown index.
    pub fn object_signed_distance(&self, index: usize, p: &Point3<f32>) -> Option<f32> {
        if index >= self.object_count() {
            return None;
        }
        let q = point_to_glam(p);
        let proj = match self.oriented_mesh(index) {
            Some(mesh) => mesh.project_point(&self.poses[index], q, false),
            None => self.shapes[index].project_point(&self.poses[index], q, false),
        };
        let d = proj.point.distance(q);
        Some(if proj.is_inside { -d } else { d })
    }

    /// Indices of the objects whose surface lies within `dist` of `p`.
    pub fn objects_near_point(&self, p: &Point3<f32>, dist: f32) -> Vec<usize> {
        let q = point_to_glam(p);
        let aabb = Aabb::new(
            q - parry3d::math::Vector::splat(dist),
            q + parry3d::math::Vector::splat(dist),
        );
        let mut out: Vec<usize> = self
            .bvh
            .intersect_aabb(&aabb)
            .map(|l| l as usize)
            .filter(|&l| l < self.object_count())
            .filter(|&l| self.shapes[l].distance_to_point(&self.poses[l], q, true) <= dist)
            .collect();
        out.sort_unstable();
        out
    }

    /// True if the oriented box intersects anything in the scene (objects and bin), skipping the
    /// object `ignore` when given. Mesh objects are tested through their convex decomposition.
    pub fn box_collides(&self, b: &OrientedBox, ignore: Option<usize>) -> bool {
        self.box_hits(b, ignore, true)
    }

    /// True if the oriented box intersects object `object` (through its convex decomposition for
    /// a mesh); false for an index that is not an object.
    pub fn box_hits_object(&self, b: &OrientedBox, object: usize) -> bool {
        if object >= self.object_count() {
            return false;
        }
        let cuboid = Cuboid::new(vec_to_glam(&b.half_extents));
        intersection_test(
            &pose_to_glam(&b.parent_from_box),
            &cuboid,
            &self.poses[object],
            self.collision_shapes[object].as_ref(),
        )
        .is_ok_and(|r| r.intersecting)
    }

    /// True if the oriented box intersects any object other than `ignore` (the bin is ignored
    /// when `include_bin` is false).
    pub fn box_hits(&self, b: &OrientedBox, ignore: Option<usize>, include_bin: bool) -> bool {
        let cuboid = Cuboid::new(vec_to_glam(&b.half_extents));
        let pose = pose_to_glam(&b.parent_from_box);
        let aabb = cuboid.aabb(&pose);
        let n = self.object_count();
        for leaf in self.bvh.intersect_aabb(&aabb) {
            let i = leaf as usize;
            if Some(i) == ignore || (!include_bin && i >= n) {
                continue;
            }
            if intersection_test(
                &pose,
                &cuboid,
                &self.poses[i],
                self.collision_shapes[i].as_ref(),
            )
            .is_ok_and(|r| r.intersecting)
            {
                return true;
            }
        }
        false
    }

    /// Everything the oriented box intersects (objects by index, the bin once per box part).
    pub fn box_colliders(&self, b: &OrientedBox) -> Vec<HitTarget> {
        let cuboid = Cuboid::new(vec_to_glam(&b.half_extents));
        let pose = pose_to_glam(&b.parent_from_box);
        let aabb = cuboid.aabb(&pose);
        let mut out: Vec<usize> = self
            .bvh
            .intersect_aabb(&aabb)
            .map(|l| l as usize)
            .filter(|&i| {
                intersection_test(
                    &pose,
                    &cuboid,
                    &self.poses[i],
                    self.collision_shapes[i].as_ref(),
                )
                .is_ok_and(|r| r.intersecting)
            })
            .collect();
        out.sort_unstable();
        out.into_iter().map(|i| self.target_of(i)).collect()
    }

    /// The parts of the bin the oriented box intersects, as indices into
    /// [`BinModel::boxes`]: 0 the floor, 1–4 the side walls.
    pub fn box_bin_parts(&self, b: &OrientedBox) -> Vec<usize> {
        let cuboid = Cuboid::new(vec_to_glam(&b.half_extents));
        let pose = pose_to_glam(&b.parent_from_box);
        let n = self.object_count();
        (0..self.shapes.len() - n)
            .filter(|&part| {
                let leaf = n + part;
                intersection_test(
                    &pose,
                    &cuboid,
                    &self.poses[leaf],
                    self.shapes[leaf].as_ref(),
                )
                .is_ok_and(|r| r.intersecting)
            })
            .collect()
    }

    /// Renders the clean depth image (metres along the optical axis, 0 where nothing is hit).
    pub fn render_depth(&self, camera: &CameraModel) -> DepthImage {
        self.render(camera).depth
    }

    /// Renders depth and segmentation by casting one ray through each pixel centre.
    pub fn render(&self, camera: &CameraModel) -> Rendering {
        let k = camera.intrinsics;
        let (w, h) = (k.width, k.height);
        let mut depth = vec![0.0f32; k.pixel_count()];
        let mut segmentation = vec![0u16; k.pixel_count()];
        let eye = camera.eye();
        let rot = camera.workspace_from_camera.rotation;
        let max_dist = 20.0;
        for v in 0..h {
            for u in 0..w {
                let dir_cam = k.ray_direction(u as f32, v as f32);
                if !dir_cam.iter().all(|c| c.is_finite()) {
                    continue;
                }
                let dir = rot * dir_cam;
                if let Some(hit) = self.cast_ray(&eye, &dir, max_dist) {
                    let idx = v as usize * w as usize + u as usize;
                    depth[idx] = hit.toi * dir_cam.z;
                    segmentation[idx] = match hit.target {
                        HitTarget::Bin => SEGMENT_BIN,
                        HitTarget::Object(i) => {
                            SEGMENT_OBJECT0.saturating_add(i.min(u16::MAX as usize) as u16)
                        }
                    };
                }
            }
        }
        Rendering {
            depth: DepthImage {
                width: w,
                height: h,
                data: depth,
            },
            segmentation,
        }
    }
}

pub(crate) fn validate_bin(bin: &BinModel) -> Result<(), SimError> {
    let ok = bin.inner_size_m.iter().all(|v| v.is_finite() && *v > 0.0)
        && bin.wall_thickness_m.is_finite()
        && bin.wall_thickness_m > 0.0
        && bin.floor_center.coords.iter().all(|v| v.is_finite());
    if ok {
        Ok(())
    } else {
        Err(SimError::InvalidBin)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objects::{ObjectKind, Part, Primitive};
    use psgrasp_geometry::CameraIntrinsics;

    #[test]
    fn a_box_names_the_bin_parts_it_crosses() {
        let scene = cube_scene(0.02);
        let c = scene.bin().floor_center;
        let [lx, ly, _] = scene.bin().inner_size_m;
        let at = |x: f32, y: f32, z: f32| OrientedBox {
            parent_from_box: Isometry3::translation(c.x + x, c.y + y, c.z + z),
            half_extents: Vector3::new(0.01, 0.01, 0.01),
        };
        // In the middle above the cube: nothing; through the floor: the floor; through the −x
        // wall: wall 1; through the +y wall at the floor: the floor and wall 4.
        assert!(scene.box_bin_parts(&at(0.1, 0.0, 0.1)).is_empty());
        assert_eq!(scene.box_bin_parts(&at(0.1, 0.0, 0.0)), [0]);
        assert_eq!(scene.box_bin_parts(&at(-0.5 * lx, 0.0, 0.1)), [1]);
        assert_eq!(scene.box_bin_parts(&at(0.0, 0.5 * ly, 0.0)), [0, 4]);
        // The cube itself is not a bin part.
        assert!(scene.box_bin_parts(&at(0.0, 0.0, 0.02)).is_empty());
    }

    fn cube_scene(half: f32) -> Scene {
        let bin = BinModel::default();
        let spec = ObjectSpec {
            name: "cube".into(),
            kind: ObjectKind::Box,
            parts: vec![Part {
                object_from_part: Isometry3::identity(),
                primitive: Primitive::Cuboid {
                    half_extents: [half; 3],
                },
            }],
        };
        let pose = Isometry3::translation(
            bin.floor_center.x,
            bin.floor_center.y,
            bin.floor_center.z + half,
        );
        Scene::new(SceneDescription {
            bin,
            objects: vec![SceneObject {
                spec,
                workspace_from_object: pose,
            }],
        })
        .unwrap()
    }

    #[test]
    fn rendered_depth_matches_analytic_cube_and_floor() {
        let half = 0.03;
        let scene = cube_scene(half);
        let bin = *scene.bin();
        let eye = Point3::new(
            bin.floor_center.x,
            bin.floor_center.y,
            bin.floor_center.z + 0.9,
        );
        let cam = CameraModel::top_down(CameraIntrinsics::default_640x480(), eye);
        let r = scene.render(&cam);
        // The centre pixel sees the cube top: 0.9 − 2·half.
        let c = r.depth.at(320, 240);
        assert!((c - (0.9 - 2.0 * half)).abs() < 1e-4, "centre depth {c}");
        assert_eq!(r.segmentation[240 * 640 + 320], SEGMENT_OBJECT0);
        // A pixel 100 px right of the principal point sees the floor at depth 0.9 exactly.
        let d = r.depth.at(420, 240);
        assert!((d - 0.9).abs() < 1e-4, "floor depth {d}");
        assert_eq!(r.segmentation[240 * 640 + 420], SEGMENT_BIN);
        // Every pixel of this camera sees something (the floor plate is wider than the view? no:
        // outside the bin the rays miss and report 0).
        assert!(r
            .depth
            .data
            .iter()
            .all(|d| *d == 0.0 || (*d > 0.5 && *d < 1.0)));
    }

    #[test]
    fn box_collision_against_cube_and_bin() {
        let scene = cube_scene(0.03);
        let c = scene.bin().floor_center;
        let probe = |x: f32, z: f32| OrientedBox {
            parent_from_box: Isometry3::translation(c.x + x, c.y, c.z + z),
            half_extents: Vector3::new(0.01, 0.01, 0.01),
        };
        assert!(scene.box_collides(&probe(0.0, 0.03), None));
        assert!(!scene.box_collides(&probe(0.0, 0.03), Some(0)));
        assert!(!scene.box_collides(&probe(0.05, 0.05), None));
        // Touching the floor.
        assert!(scene.box_collides(&probe(0.1, 0.005), None));
        assert!(!scene.box_hits(&probe(0.1, 0.005), None, false));
        // One object only: the cube is hit, the floor never counts, other indices never hit.
        assert!(scene.box_hits_object(&probe(0.0, 0.03), 0));
        assert!(scene.box_hits_object(&probe(0.035, 0.03), 0));
        assert!(!scene.box_hits_object(&probe(0.045, 0.03), 0));
        assert!(!scene.box_hits_object(&probe(0.1, 0.005), 0));
        assert!(!scene.box_hits_object(&probe(0.0, 0.03), 1));
    }

    /// A closed 2·`half` cube as a triangle mesh resting on the bin floor (outward winding).
    fn mesh_cube_scene(half: f32) -> Scene {
        let v: Vec<[f32; 3]> = (0..8)
            .map(|i| {
                let c = |bit: u32| if i & bit != 0 { half } else { -half };
                [c(1), c(2), c(4)]
            })
            .collect();
        let triangles = vec![
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6], // −z, +z
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7], // −y, +y
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5], // −x, +x
        ];
        let mut meshes = MeshLibrary::default();
        meshes.insert(
            "cube",
            crate::mesh::MeshAsset {
                vertices: v.clone(),
                triangles,
                convex_parts: vec![v],
                source_file: String::new(),
            },
        );
        let bin = BinModel::default();
        let spec = ObjectSpec {
            name: "mesh-cube".into(),
            kind: ObjectKind::Box,
            parts: vec![Part {
                object_from_part: Isometry3::identity(),
                primitive: Primitive::Mesh {
                    key: "cube".into(),
                    scale: 1.0,
                },
            }],
        };
        let c = bin.floor_center;
        let pose = Isometry3::translation(c.x, c.y, c.z + half);
        Scene::with_meshes(
            SceneDescription {
                bin,
                objects: vec![SceneObject {
                    spec,
                    workspace_from_object: pose,
                }],
            },
            &meshes,
        )
        .unwrap()
    }

    #[test]
    fn a_mesh_object_has_an_inside() {
        // A mesh object is tested by its triangles: points inside count as inside and their
        // signed distance is negative, as for the same cube built from a primitive.
        let (mesh, solid) = (mesh_cube_scene(0.03), cube_scene(0.03));
        let c = solid.bin().floor_center;
        let at = |x: f32, z: f32| Point3::new(c.x + x, c.y, c.z + z);
        for (p, inside, distance) in [
            (at(0.0, 0.03), true, -0.03),
            (at(0.025, 0.03), true, -0.005),
            (at(0.035, 0.03), false, 0.005),
            (at(0.0, 0.07), false, 0.01),
        ] {
            for scene in [&mesh, &solid] {
                assert_eq!(scene.object_contains_point(0, &p), inside, "{p:?}");
                let d = scene.object_signed_distance(0, &p).unwrap();
                assert!((d - distance).abs() < 1e-5, "{p:?}: {d}");
            }
        }
        // A ray from inside the mesh leaves through the far face with its outward normal.
        let (toi, n) = mesh
            .cast_ray_object(0, &at(-0.029, 0.03), &Vector3::x(), 1.0, false)
            .unwrap();
        assert!((toi - 0.059).abs() < 1e-4, "toi {toi}");
        assert!((n - Vector3::x()).norm() < 1e-4, "{n:?}");
    }

    #[test]
    fn exit_ray_gives_the_far_side() {
        let scene = cube_scene(0.03);
        let c = scene.bin().floor_center;
        let start = Point3::new(c.x - 0.029, c.y, c.z + 0.03);
        let (toi, n) = scene
            .cast_ray_object(0, &start, &Vector3::x(), 1.0, false)
            .unwrap();
        assert!((toi - 0.059).abs() < 1e-4, "toi {toi}");
        assert!((n - Vector3::x()).norm() < 1e-4);
        assert!(scene.object_contains_point(0, &Point3::new(c.x, c.y, c.z + 0.01)));
        assert_eq!(
            scene.objects_near_point(&Point3::new(c.x + 0.035, c.y, c.z + 0.03), 0.01),
            vec![0]
        );
    }
}
