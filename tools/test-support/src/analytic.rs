//! A tiny analytic ray caster and ground-truth nearest-surface queries (planes, spheres, boxes):
//! depth images of exactly known scenes and the accuracy of a fused [`NormalGrid`] against them.
//! Used by fusion's tests and benchmark.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::{CameraIntrinsics, CameraModel, DepthImage, Workspace};

/// An analytic surface in the workspace frame.
#[derive(Debug, Clone, Copy)]
pub enum Shape {
    /// Points with `n · p = d` (solid below, i.e. on the −n side).
    Plane {
        /// Unit normal.
        n: Vector3<f32>,
        /// Offset along the normal, metres.
        d: f32,
    },
    /// A solid ball.
    Sphere {
        /// Centre.
        c: Point3<f32>,
        /// Radius, metres.
        r: f32,
    },
    /// An axis-aligned solid box.
    Cuboid {
        /// Lowest corner.
        min: Point3<f32>,
        /// Highest corner.
        max: Point3<f32>,
    },
}

/// The nearest surface point of a shape to a query point.
#[derive(Debug, Clone, Copy)]
pub struct Nearest {
    /// The surface point.
    pub point: Point3<f32>,
    /// The outward surface normal there.
    pub normal: Vector3<f32>,
    /// Distance from the query point, metres.
    pub distance: f32,
    /// The nearest point lies on (or within the margin of) an edge/corner, or two faces tie.
    pub ambiguous: bool,
}

impl Shape {
    /// Smallest positive ray parameter of `o + t·dir`.
    pub fn intersect(&self, o: &Point3<f32>, dir: &Vector3<f32>) -> Option<f32> {
        match *self {
            Shape::Plane { n, d } => {
                let den = n.dot(dir);
                if den.abs() < 1e-9 {
                    return None;
                }
                let t = (d - n.dot(&o.coords)) / den;
                (t > 1e-6).then_some(t)
            }
            Shape::Sphere { c, r } => {
                let oc = o - c;
                let a = dir.dot(dir);
                let b = oc.dot(dir);
                let cc = oc.dot(&oc) - r * r;
                let disc = b * b - a * cc;
                if disc < 0.0 {
                    return None;
                }
                let s = disc.sqrt();
                let t0 = (-b - s) / a;
                let t1 = (-b + s) / a;
                if t0 > 1e-6 {
                    Some(t0)
                } else if t1 > 1e-6 {
                    Some(t1)
                } else {
                    None
                }
            }
            Shape::Cuboid { min, max } => {
                let (mut t0, mut t1) = (f32::NEG_INFINITY, f32::INFINITY);
                for a in 0..3 {
                    if dir[a].abs() < 1e-12 {
                        if o[a] < min[a] || o[a] > max[a] {
                            return None;
                        }
                        continue;
                    }
                    let ta = (min[a] - o[a]) / dir[a];
                    let tb = (max[a] - o[a]) / dir[a];
                    t0 = t0.max(ta.min(tb));
                    t1 = t1.min(ta.max(tb));
                }
                if t1 < t0 || t1 <= 1e-6 {
                    None
                } else if t0 > 1e-6 {
                    Some(t0)
                } else {
                    Some(t1)
                }
            }
        }
    }

    /// Nearest surface point; `margin` marks box points within that distance of an edge.
    pub fn nearest(&self, p: &Point3<f32>, margin: f32) -> Nearest {
        match *self {
            Shape::Plane { n, d } => {
                let s = n.dot(&p.coords) - d;
                Nearest {
                    point: p - n * s,
                    normal: n,
                    distance: s.abs(),
                    ambiguous: false,
                }
            }
            Shape::Sphere { c, r } => {
                let v = p - c;
                let l = v.norm().max(1e-9);
                let n = v / l;
                Nearest {
                    point: c + n * r,
                    normal: n,
                    distance: (l - r).abs(),
                    ambiguous: l < 1e-3,
                }
            }
            Shape::Cuboid { min, max } => {
                let inside = (0..3).all(|a| p[a] >= min[a] && p[a] <= max[a]);
                if inside {
                    // Nearest face; ambiguous if another face is almost as near.
                    let mut faces: Vec<(f32, usize, f32)> = Vec::new();
                    for a in 0..3 {
                        faces.push((p[a] - min[a], a, -1.0));
                        faces.push((max[a] - p[a], a, 1.0));
                    }
                    faces.sort_by(|x, y| x.0.total_cmp(&y.0));
                    let (dist, a, sign) = faces[0];
                    let mut q = *p;
                    q[a] = if sign > 0.0 { max[a] } else { min[a] };
                    let mut n = Vector3::zeros();
                    n[a] = sign;
                    let ambiguous =
                        faces[1].0 - dist < margin || near_edge(&q, &min, &max, a, margin);
                    Nearest {
                        point: q,
                        normal: n,
                        distance: dist,
                        ambiguous,
                    }
                } else {
                    let mut q = *p;
                    let mut clamped = 0;
                    let mut n = Vector3::zeros();
                    for a in 0..3 {
                        if p[a] < min[a] {
                            q[a] = min[a];
                            n[a] = -1.0;
                            clamped += 1;
                        } else if p[a] > max[a] {
                            q[a] = max[a];
                            n[a] = 1.0;
                            clamped += 1;
                        }
                    }
                    let face_axis = (0..3).find(|&a| n[a] != 0.0).unwrap_or(0);
                    let ambiguous = clamped != 1 || near_edge(&q, &min, &max, face_axis, margin);
                    Nearest {
                        point: q,
                        normal: n.normalize(),
                        distance: (p - q).norm(),
                        ambiguous,
                    }
                }
            }
        }
    }
}

/// True if face point `q` (on the face normal to `axis`) is within `margin` of the face border.
fn near_edge(
    q: &Point3<f32>,
    min: &Point3<f32>,
    max: &Point3<f32>,
    axis: usize,
    margin: f32,
) -> bool {
    (0..3)
        .filter(|&a| a != axis)
        .any(|a| q[a] - min[a] < margin || max[a] - q[a] < margin)
}

/// A scene of analytic shapes.
#[derive(Debug, Clone, Default)]
pub struct Scene {
    /// The shapes (a union of solids).
    pub shapes: Vec<Shape>,
}

impl Scene {
    /// Nearest ray hit `(t, shape index)`.
    pub fn cast(&self, o: &Point3<f32>, dir: &Vector3<f32>) -> Option<(f32, usize)> {
        self.shapes
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.intersect(o, dir).map(|t| (t, i)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
    }

    /// Renders a depth image (distance along the optical axis; 0 where nothing is hit).
    pub fn render(&self, camera: &CameraModel) -> DepthImage {
        let k = camera.intrinsics;
        let eye = camera.eye();
        let rot = camera.workspace_from_camera.rotation;
        let mut data = Vec::with_capacity(k.pixel_count());
        for v in 0..k.height {
            for u in 0..k.width {
                // Ray with unit optical-axis component: the parameter is the depth.
                let d_cam = Vector3::new((u as f32 - k.cx) / k.fx, (v as f32 - k.cy) / k.fy, 1.0);
                let dir = rot * d_cam;
                data.push(self.cast(&eye, &dir).map_or(0.0, |(t, _)| t));
            }
        }
        DepthImage::from_metres(k.width, k.height, data).unwrap()
    }

    /// Is the surface point `q` (of shape `shape`) seen by the camera, not at a grazing angle?
    pub fn visible(
        &self,
        camera: &CameraModel,
        q: &Point3<f32>,
        normal: &Vector3<f32>,
        shape: usize,
    ) -> bool {
        let eye = camera.eye();
        let to_q = q - eye;
        let dist = to_q.norm();
        let dir = to_q / dist;
        if normal.dot(&-dir) < 0.17 {
            // Back-facing or within ~10° of grazing: the silhouette.
            return false;
        }
        let qc = camera.workspace_from_camera.inverse() * q;
        match camera.intrinsics.project(&qc) {
            Some((u, v))
                if u >= 0.5
                    && v >= 0.5
                    && u < camera.intrinsics.width as f32 - 1.5
                    && v < camera.intrinsics.height as f32 - 1.5 => {}
            _ => return false,
        }
        match self.cast(&eye, &dir) {
            Some((t, i)) => i == shape && (t - dist).abs() < 1e-3,
            None => false,
        }
    }

    /// Ground truth for a voxel: nearest surface of the union, or `None` when the truth is
    /// ambiguous (two shapes within `margin` of each other, a box edge, or a nearest point the
    /// camera does not see well).
    pub fn truth(&self, cameras: &[CameraModel], p: &Point3<f32>, margin: f32) -> Option<Nearest> {
        let mut all: Vec<(Nearest, usize)> = self
            .shapes
            .iter()
            .enumerate()
            .map(|(i, s)| (s.nearest(p, margin), i))
            .collect();
        all.sort_by(|a, b| a.0.distance.total_cmp(&b.0.distance));
        let (best, idx) = all[0];
        if best.ambiguous {
            return None;
        }
        if all.len() > 1 && all[1].0.distance - best.distance < margin {
            return None;
        }
        // The nearest point must be inside no other solid (e.g. floor under a box).
        if cameras
            .iter()
            .any(|c| self.visible(c, &best.point, &best.normal, idx))
        {
            Some(best)
        } else {
            None
        }
    }
}

/// A camera at `eye` looking at `target`, image y along the projection of `down`.
pub fn look_at(
    k: CameraIntrinsics,
    eye: Point3<f32>,
    target: Point3<f32>,
    down: Vector3<f32>,
) -> CameraModel {
    let z = (target - eye).normalize();
    let y = (down - z * z.dot(&down)).normalize();
    let x = y.cross(&z);
    let rot = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    CameraModel {
        intrinsics: k,
        workspace_from_camera: Isometry3::from_parts(
            Translation3::from(eye.coords),
            UnitQuaternion::from_rotation_matrix(&rot),
        ),
    }
}

/// Height of the [`floor`] plane, metres.
pub const FLOOR_Z: f32 = 0.1;

/// The workspace of the analytic scenes: [`Workspace::default`].
pub fn workspace() -> Workspace {
    Workspace::default()
}

/// Top-down camera 0.8 m above the floor, over the workspace centre.
pub fn top_camera() -> CameraModel {
    let c = workspace().extent() * 0.5;
    CameraModel::top_down(
        CameraIntrinsics::default_640x480(),
        Point3::new(c.x, c.y, FLOOR_Z + 0.8),
    )
}

/// A second view: 0.35 m to the side, looking at the scene centre.
pub fn side_camera() -> CameraModel {
    let c = workspace().extent() * 0.5;
    look_at(
        CameraIntrinsics::default_640x480(),
        Point3::new(c.x + 0.35, c.y - 0.1, FLOOR_Z + 0.72),
        Point3::new(c.x, c.y, FLOOR_Z + 0.05),
        Vector3::new(0.0, -1.0, 0.0),
    )
}

/// The floor plane at [`FLOOR_Z`].
pub fn floor() -> Shape {
    Shape::Plane {
        n: Vector3::z(),
        d: FLOOR_Z,
    }
}

/// A ball of radius 8 cm resting on the floor.
pub fn sphere() -> Shape {
    Shape::Sphere {
        c: Point3::new(0.38, 0.34, FLOOR_Z + 0.08),
        r: 0.08,
    }
}

/// An 18 × 18 × 11 cm box standing on the floor.
pub fn cuboid() -> Shape {
    Shape::Cuboid {
        min: Point3::new(0.08, 0.10, FLOOR_Z),
        max: Point3::new(0.26, 0.28, FLOOR_Z + 0.11),
    }
}

/// Accuracy of a normal grid against a scene's ground truth.
#[derive(Debug, Clone, Default)]
pub struct NormalReport {
    /// Band voxels (|tsdf| < 1).
    pub band: usize,
    /// Band voxels with an unambiguous, visible nearest surface.
    pub evaluated: usize,
    /// Evaluated voxels whose normal is within 5° of the truth.
    pub within_5deg: usize,
    /// Band voxels with a zero normal.
    pub zero_normals: usize,
    /// Sorted angular errors (degrees).
    pub errors: Vec<f32>,
}

impl NormalReport {
    /// Fraction of the evaluated voxels within 5° of the truth.
    pub fn fraction_within(&self) -> f32 {
        self.within_5deg as f32 / self.evaluated.max(1) as f32
    }

    /// The `q` quantile (0–1) of the angular errors, degrees (NaN without any).
    pub fn percentile(&self, q: f32) -> f32 {
        if self.errors.is_empty() {
            return f32::NAN;
        }
        self.errors[((self.errors.len() - 1) as f32 * q).round() as usize]
    }
}

/// Compares every band voxel's normal with the nearest analytic surface (see [`Scene::truth`]).
pub fn evaluate_normals(
    grid: &NormalGrid,
    scene: &Scene,
    cameras: &[CameraModel],
    margin: f32,
) -> NormalReport {
    let ws = grid.workspace;
    let view = grid.view();
    let mut r = NormalReport::default();
    for idx in 0..ws.voxel_count() {
        if grid.tsdf[idx].abs() >= 1.0 {
            continue;
        }
        r.band += 1;
        let n = view.normal(idx);
        let n = Vector3::new(n[0], n[1], n[2]);
        if n.norm() == 0.0 {
            r.zero_normals += 1;
        }
        let [i, j, k] = ws.unindex(idx);
        let Some(t) = scene.truth(cameras, &ws.voxel_center(i, j, k), margin) else {
            continue;
        };
        r.evaluated += 1;
        let e = if n.norm() == 0.0 {
            180.0
        } else {
            angle_deg(&n, &t.normal)
        };
        if e <= 5.0 {
            r.within_5deg += 1;
        }
        r.errors.push(e);
    }
    r.errors.sort_by(|a, b| a.total_cmp(b));
    r
}

/// Zero crossings of the TSDF along vertical voxel columns against the analytic top surface.
/// Columns whose surface is steep (|n_z| < 0.5), near a box edge or unseen are skipped.
/// Returns (columns checked, columns without a crossing, max error m, mean error m).
pub fn zero_crossing_errors(
    grid: &NormalGrid,
    scene: &Scene,
    cameras: &[CameraModel],
    margin: f32,
) -> (usize, usize, f32, f32) {
    let ws = grid.workspace;
    let s = ws.voxel_size_m;
    let [nx, ny, nz] = ws.dims.map(|d| d as usize);
    let (mut count, mut missing, mut max, mut sum) = (0usize, 0usize, 0.0f32, 0.0f32);
    for i in 0..nx {
        for j in 0..ny {
            let c = ws.voxel_center(i, j, nz - 1);
            let top = Point3::new(c.x, c.y, 2.0);
            let Some((t, shape)) = scene.cast(&top, &-Vector3::z()) else {
                continue;
            };
            let hit = Point3::new(c.x, c.y, 2.0 - t);
            let near = scene.shapes[shape].nearest(&hit, margin);
            if near.ambiguous
                || near.normal.z < 0.5
                || hit.z < 0.5 * s
                || hit.z > (nz as f32 - 0.5) * s
            {
                continue;
            }
            // The surface and the voxels one above and below it must be in view.
            let in_view = |cam: &CameraModel| {
                scene.visible(cam, &hit, &near.normal, shape)
                    && [-1.5f32, 1.5].iter().all(|dz| {
                        let p = Point3::new(hit.x, hit.y, hit.z + dz * s);
                        let pc = cam.workspace_from_camera.inverse() * p;
                        let on_image = cam.intrinsics.project(&pc).is_some_and(|(u, v)| {
                            u >= 0.0
                                && v >= 0.0
                                && u < cam.intrinsics.width as f32 - 1.0
                                && v < cam.intrinsics.height as f32 - 1.0
                        });
                        // No silhouette of another shape between the camera and the column.
                        on_image
                            && scene
                                .cast(&cam.eye(), &(p - cam.eye()))
                                .is_some_and(|(_, i)| i == shape)
                    })
            };
            if !cameras.iter().any(in_view) {
                continue;
            }
            // No other shape near the column's band (a wall right beside it, a sphere overhang).
            let crowded = (0..=5).any(|m| {
                let p = Point3::new(hit.x, hit.y, hit.z + m as f32 * s);
                scene
                    .shapes
                    .iter()
                    .enumerate()
                    .any(|(i, sh)| i != shape && sh.nearest(&p, margin).distance < margin)
            });
            if crowded {
                continue;
            }
            // First + → − crossing from the top between two band voxels.
            let col = |k: usize| grid.tsdf[ws.index(i, j, k)];
            let Some(k) = (1..nz)
                .rev()
                .find(|&k| col(k) >= 0.0 && col(k - 1) < 0.0 && col(k) < 1.0 && col(k - 1) > -1.0)
            else {
                count += 1;
                missing += 1;
                continue;
            };
            let (a, b) = (col(k - 1), col(k));
            let z0 = ws.voxel_center(i, j, k - 1).z + s * (-a) / (b - a);
            let e = (z0 - hit.z).abs();
            count += 1;
            max = max.max(e);
            sum += e;
        }
    }
    (count, missing, max, sum / (count - missing).max(1) as f32)
}

/// Angle between `a` and `b`, degrees.
pub fn angle_deg(a: &Vector3<f32>, b: &Vector3<f32>) -> f32 {
    (a.dot(b) / (a.norm() * b.norm()))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}
