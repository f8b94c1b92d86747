//! Mesh objects: triangle meshes loaded from STL/OBJ files, with a cached convex decomposition
//! for the physics engine.
use crate::SimError;
use parry3d::math::Vector;
use parry3d::shape::SharedShape;
use std::collections::BTreeMap;
use std::sync::Arc;

/// A loaded mesh: triangles in metres (object frame) and convex pieces for physics.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshAsset {
    /// Vertex positions.
    pub vertices: Vec<[f32; 3]>,
    /// Triangles as vertex indices.
    pub triangles: Vec<[u32; 3]>,
    /// Convex pieces (hull vertex sets) approximating the solid, for physics.
    pub convex_parts: Vec<Vec<[f32; 3]>>,
    /// The file it was read from, relative to the mesh directory (empty when built in code).
    pub source_file: String,
}

/// Meshes by key. The default library is empty (procedural objects only).
#[derive(Debug, Clone, Default)]
pub struct MeshLibrary {
    meshes: BTreeMap<String, Arc<MeshAsset>>,
}

impl MeshLibrary {
    /// Adds (or replaces) a mesh.
    pub fn insert(&mut self, key: impl Into<String>, asset: MeshAsset) {
        self.meshes.insert(key.into(), Arc::new(asset));
    }

    /// The mesh stored under `key`.
    pub fn get(&self, key: &str) -> Option<&Arc<MeshAsset>> {
        self.meshes.get(key)
    }

    /// Keys in sorted order.
    pub fn keys(&self) -> impl Iterator<Item = &str> {
        self.meshes.keys().map(String::as_str)
    }

    /// Number of meshes.
    pub fn len(&self) -> usize {
        self.meshes.len()
    }

    /// True when no mesh is loaded.
    pub fn is_empty(&self) -> bool {
        self.meshes.is_empty()
    }

    fn asset(&self, key: &str) -> Result<&Arc<MeshAsset>, SimError> {
        self.meshes.get(key).ok_or_else(|| SimError::MeshNotLoaded {
            key: key.to_owned(),
        })
    }

    /// The mesh as a parry triangle mesh scaled by `scale`.
    pub fn trimesh(&self, key: &str, scale: f32) -> Result<SharedShape, SimError> {
        let asset = self.asset(key)?;
        let vertices: Vec<Vector> = asset
            .vertices
            .iter()
            .map(|v| Vector::new(v[0], v[1], v[2]) * scale)
            .collect();
        SharedShape::trimesh(vertices, asset.triangles.clone()).map_err(|e| SimError::InvalidMesh {
            key: key.to_owned(),
            reason: e.to_string(),
        })
    }

    /// The mesh's convex pieces as a compound scaled by `scale`.
    pub fn convex_decomposition(&self, key: &str, scale: f32) -> Result<SharedShape, SimError> {
        let asset = self.asset(key)?;
        let mut pieces = Vec::new();
        for part in &asset.convex_parts {
            let pts: Vec<Vector> = part
                .iter()
                .map(|v| Vector::new(v[0], v[1], v[2]) * scale)
                .collect();
            if let Some(hull) = SharedShape::convex_hull(&pts) {
                pieces.push((parry3d::math::Pose::identity(), hull));
            }
        }
        if pieces.is_empty() {
            return Err(SimError::InvalidMesh {
                key: key.to_owned(),
                reason: "no convex piece".into(),
            });
        }
        Ok(SharedShape::compound(pieces))
    }
}

/// A set of meshes fetched by `scripts/fetch_objects.sh`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MeshSet {
    /// YCB objects (binary STL in metres) under `<dir>/ycb/`.
    Ycb,
    /// pybullet's procedural random URDF objects (OBJ, rescaled) under `<dir>/random_urdfs/`.
    RandomUrdf,
}

impl MeshSet {
    fn folder(self) -> &'static str {
        match self {
            MeshSet::Ycb => "ycb",
            MeshSet::RandomUrdf => "random_urdfs",
        }
    }
}

/// Settings of mesh preparation.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct MeshPrepConfig {
    /// YCB meshes whose largest extent exceeds this are skipped (m).
    pub max_extent_m: f32,
    /// Random URDF meshes are scaled so that their largest extent is this (m).
    pub random_urdf_extent_m: f32,
    /// VHACD voxel resolution.
    pub vhacd_resolution: u32,
    /// Share of the objects that go to the training split (the paper: 149/200), taken within
    /// each object kind so that the test split keeps simple shapes for the easy level.
    pub train_share: f32,
    /// Most random URDF objects used (a fixed seeded choice), so that the 1000 generated
    /// shapes do not crowd out the scanned YCB objects (the paper: 200 objects in all).
    pub random_urdf_max: usize,
    /// Most convex pieces per mesh (VHACD's `max_convex_hulls`).
    pub max_convex_hulls: u32,
    /// Most vertices kept per convex piece (farthest-point sampling): the physics engine's
    /// support-point queries scan every vertex, so this bounds the cost of every contact.
    pub max_hull_vertices: usize,
    /// Objects whose thinnest side (at the set's scale) is under this are skipped (m): a
    /// parallel-jaw hand whose fingertips reach 9.5 mm past the contact cannot close on a
    /// shard lying flat on the floor (`docs/datasets.md`).
    pub min_thickness_m: f32,
}

impl Default for MeshPrepConfig {
    fn default() -> Self {
        Self {
            max_extent_m: 0.25,
            random_urdf_extent_m: 0.08,
            vhacd_resolution: 64,
            train_share: 0.745,
            random_urdf_max: 150,
            min_thickness_m: 0.025,
            max_convex_hulls: 12,
            max_hull_vertices: 32,
        }
    }
}

/// YCB objects of simple structure, by name: boxes, cylinders and balls (the easy level's pool).
pub const YCB_SIMPLE: [(&str, crate::objects::ObjectKind); 18] = {
    use crate::objects::ObjectKind::{Box, Cylinder, Sphere};
    [
        ("cracker_box", Box),
        ("sugar_box", Box),
        ("pudding_box", Box),
        ("gelatin_box", Box),
        ("potted_meat_can", Box),
        ("wood_block", Box),
        ("foam_brick", Box),
        ("dice", Box),
        ("rubiks_cube", Box),
        ("master_chef_can", Cylinder),
        ("tomato_soup_can", Cylinder),
        ("tuna_fish_can", Cylinder),
        ("mini_soccer_ball", Sphere),
        ("softball", Sphere),
        ("baseball", Sphere),
        ("tennis_ball", Sphere),
        ("racquetball", Sphere),
        ("golf_ball", Sphere),
    ]
};

/// The kind of a mesh object: a simple shape for the YCB objects of [`YCB_SIMPLE`], else mesh.
pub fn mesh_kind(set: MeshSet, stem: &str) -> crate::objects::ObjectKind {
    match set {
        MeshSet::Ycb => YCB_SIMPLE
            .iter()
            .find(|(name, _)| stem.ends_with(name))
            .map(|&(_, kind)| kind)
            .unwrap_or(crate::objects::ObjectKind::Mesh),
        MeshSet::RandomUrdf => crate::objects::ObjectKind::Mesh,
    }
}

/// YCB objects skipped: multi-part sets and very large or flat items.
pub const YCB_EXCLUDED: [&str; 10] = [
    "marbles",
    "cups",
    "blocks",
    "lego",
    "toy_airplane",
    "chain",
    "skillet_lid",
    "nine_hole_peg",
    "plate",
    "rope",
];

fn files_with_ext(dir: &std::path::Path, ext: &str, out: &mut Vec<std::path::PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<_> = entries.flatten().map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            files_with_ext(&p, ext, out);
        } else if p.extension().is_some_and(|e| e.eq_ignore_ascii_case(ext)) {
            out.push(p);
        }
    }
}

/// At most `k` of `points`, spread by farthest-point sampling (the first is the point farthest
/// from the centroid); all of them when there are at most `k`.
pub fn farthest_points(points: &[[f32; 3]], k: usize) -> Vec<[f32; 3]> {
    if points.len() <= k {
        return points.to_vec();
    }
    let d2 = |a: &[f32; 3], b: &[f32; 3]| {
        (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
    };
    let n = points.len() as f32;
    let c = points.iter().fold([0.0f32; 3], |c, p| {
        [c[0] + p[0] / n, c[1] + p[1] / n, c[2] + p[2] / n]
    });
    let first = (0..points.len())
        .max_by(|&a, &b| d2(&points[a], &c).total_cmp(&d2(&points[b], &c)))
        .unwrap_or(0);
    let mut nearest: Vec<f32> = points.iter().map(|p| d2(p, &points[first])).collect();
    let mut out = vec![points[first]];
    while out.len() < k {
        let next = (0..points.len())
            .max_by(|&a, &b| nearest[a].total_cmp(&nearest[b]))
            .unwrap_or(0);
        out.push(points[next]);
        for (i, p) in points.iter().enumerate() {
            nearest[i] = nearest[i].min(d2(p, &points[next]));
        }
    }
    out
}

/// Rotates `v` about its centroid onto its principal axes (a right-handed frame, axes in
/// ascending order of spread).
pub fn align_to_principal_axes(v: &mut [[f32; 3]]) {
    use nalgebra::{Matrix3, Vector3};
    if v.len() < 4 {
        return;
    }
    let n = v.len() as f64;
    let mean = v.iter().fold(Vector3::<f64>::zeros(), |m, p| {
        m + Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
    }) / n;
    let cov = v.iter().fold(Matrix3::<f64>::zeros(), |c, p| {
        let d = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64) - mean;
        c + d * d.transpose()
    }) / n;
    let eig = cov.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let mut axes = Matrix3::from_columns(&order.map(|i| eig.eigenvectors.column(i).into_owned()));
    if !axes.iter().all(|x| x.is_finite()) {
        return;
    }
    if axes.determinant() < 0.0 {
        axes.set_column(2, &-axes.column(2));
    }
    for p in v.iter_mut() {
        let d = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64) - mean;
        let r = axes.transpose() * d;
        *p = [r.x as f32, r.y as f32, r.z as f32];
    }
}

/// Vertices and triangles of a mesh file.
type Triangles = (Vec<[f32; 3]>, Vec<[u32; 3]>);

fn load_triangles(path: &std::path::Path) -> Result<Triangles, SimError> {
    let key = path.display().to_string();
    let bad = |reason: String| SimError::InvalidMesh {
        key: key.clone(),
        reason,
    };
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if ext == "stl" {
        let mut f = std::fs::File::open(path).map_err(|e| bad(e.to_string()))?;
        let mesh = stl_io::read_stl(&mut f).map_err(|e| bad(e.to_string()))?;
        let v = mesh.vertices.iter().map(|v| [v[0], v[1], v[2]]).collect();
        let t = mesh
            .faces
            .iter()
            .map(|f| f.vertices.map(|i| i as u32))
            .collect();
        Ok((v, t))
    } else {
        let (models, _) = tobj::load_obj(
            path,
            &tobj::LoadOptions {
                triangulate: true,
                single_index: true,
                ..Default::default()
            },
        )
        .map_err(|e| bad(e.to_string()))?;
        let mut v = Vec::new();
        let mut t = Vec::new();
        for m in models {
            let base = v.len() as u32;
            v.extend(m.mesh.positions.chunks_exact(3).map(|p| [p[0], p[1], p[2]]));
            t.extend(
                m.mesh
                    .indices
                    .chunks_exact(3)
                    .map(|i| [base + i[0], base + i[1], base + i[2]]),
            );
        }
        Ok((v, t))
    }
}

/// Loads (and on first use decomposes and caches under `<dir>/cache/`) every mesh of `set`,
/// adds them to `meshes` and returns them as library objects with a fixed, name-based split.
pub fn load_mesh_set(
    dir: &std::path::Path,
    set: MeshSet,
    meshes: &mut MeshLibrary,
) -> Result<crate::ObjectLibrary, SimError> {
    load_mesh_set_with(dir, set, meshes, &MeshPrepConfig::default())
}

/// [`load_mesh_set`] with explicit settings.
pub fn load_mesh_set_with(
    dir: &std::path::Path,
    set: MeshSet,
    meshes: &mut MeshLibrary,
    config: &MeshPrepConfig,
) -> Result<crate::ObjectLibrary, SimError> {
    use crate::objects::{LibraryObject, ObjectKind, ObjectSpec, Part, Primitive, Split};
    use rand::seq::SliceRandom;
    use rand::SeedableRng;
    let root = dir.join(set.folder());
    let mut files = Vec::new();
    match set {
        MeshSet::Ycb => files_with_ext(&root, "stl", &mut files),
        MeshSet::RandomUrdf => {
            files_with_ext(&root, "obj", &mut files);
            files.retain(|p| {
                !p.file_stem()
                    .is_some_and(|s| s.to_string_lossy().ends_with("_coll"))
            });
        }
    }
    if files.is_empty() {
        return Err(SimError::InvalidMesh {
            key: root.display().to_string(),
            reason: "no mesh files found (run scripts/fetch_objects.sh)".into(),
        });
    }
    if set == MeshSet::RandomUrdf {
        // A fixed seeded choice of `random_urdf_max` objects among those thick enough.
        files.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(
            crate::objects::PROCEDURAL_LIBRARY_SEED ^ 0x5552_4446,
        ));
    }
    let cache_dir = dir.join("cache");
    let _ = std::fs::create_dir_all(&cache_dir);
    let mut keys = Vec::new();
    for path in files {
        if set == MeshSet::RandomUrdf && keys.len() >= config.random_urdf_max {
            break;
        }
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if set == MeshSet::Ycb && YCB_EXCLUDED.iter().any(|x| stem.contains(x)) {
            continue;
        }
        let key = format!("{}/{stem}", set.folder());
        let (mut v, t) = load_triangles(&path)?;
        if v.is_empty() || t.is_empty() {
            continue;
        }
        // Turn onto the principal axes (so that the bounding box's sides measure the object's
        // thickness and widths even for a mesh stored diagonally), centre on the bounding box
        // and scale.
        align_to_principal_axes(&mut v);
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in &v {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0f32, f32::max);
        if !(extent.is_finite() && extent > 1e-6) {
            continue;
        }
        let scale = match set {
            MeshSet::Ycb if extent > config.max_extent_m => continue,
            MeshSet::Ycb => 1.0,
            MeshSet::RandomUrdf => config.random_urdf_extent_m / extent,
        };
        let sides: [f32; 3] = std::array::from_fn(|a| (hi[a] - lo[a]) * scale);
        if sides.iter().copied().fold(f32::INFINITY, f32::min) < config.min_thickness_m {
            continue;
        }
        let c = [
            0.5 * (lo[0] + hi[0]),
            0.5 * (lo[1] + hi[1]),
            0.5 * (lo[2] + hi[2]),
        ];
        for p in &mut v {
            *p = [
                (p[0] - c[0]) * scale,
                (p[1] - c[1]) * scale,
                (p[2] - c[2]) * scale,
            ];
        }
        let cache = cache_dir.join(format!(
            "{}-{stem}-pca-r{}-h{}-v{}.json",
            set.folder(),
            config.vhacd_resolution,
            config.max_convex_hulls,
            config.max_hull_vertices
        ));
        let parts: Vec<Vec<[f32; 3]>> = match std::fs::read_to_string(&cache)
            .ok()
            .and_then(|s| serde_json::from_str(&s).ok())
        {
            Some(p) => p,
            None => {
                let verts: Vec<Vector> = v.iter().map(|p| Vector::new(p[0], p[1], p[2])).collect();
                let params = parry3d::transformation::vhacd::VHACDParameters {
                    resolution: config.vhacd_resolution,
                    max_convex_hulls: config.max_convex_hulls.max(1),
                    ..Default::default()
                };
                let decomp =
                    parry3d::transformation::vhacd::VHACD::decompose(&params, &verts, &t, true);
                let hulls: Vec<Vec<[f32; 3]>> = decomp
                    .compute_exact_convex_hulls(&verts, &t)
                    .into_iter()
                    .map(|(pts, _)| {
                        let pts: Vec<[f32; 3]> = pts.iter().map(|p| [p.x, p.y, p.z]).collect();
                        farthest_points(&pts, config.max_hull_vertices.max(4))
                    })
                    .filter(|pts: &Vec<[f32; 3]>| pts.len() >= 4)
                    .collect();
                if let Ok(text) = serde_json::to_string(&hulls) {
                    let tmp = cache.with_extension(format!("tmp-{}", std::process::id()));
                    if std::fs::write(&tmp, text).is_ok() {
                        let _ = std::fs::rename(&tmp, &cache);
                    }
                }
                hulls
            }
        };
        if parts.is_empty() {
            continue;
        }
        let fit_extent_m = crate::objects::middle_of(sides);
        meshes.insert(
            key.clone(),
            MeshAsset {
                vertices: v,
                triangles: t,
                convex_parts: parts,
                source_file: path
                    .strip_prefix(dir)
                    .unwrap_or(&path)
                    .to_string_lossy()
                    .into_owned(),
            },
        );
        keys.push((key, mesh_kind(set, &stem), fit_extent_m));
    }
    keys.sort_by(|a, b| a.0.cmp(&b.0));
    // The split is drawn within each kind (a fixed seeded shuffle), so both splits keep some
    // of every simple shape.
    let mut train = std::collections::BTreeSet::new();
    let mut kinds: Vec<ObjectKind> = keys.iter().map(|k| k.1).collect();
    kinds.sort_by_key(|k| format!("{k:?}"));
    kinds.dedup();
    for kind in kinds {
        let mut order: Vec<&String> = keys.iter().filter(|k| k.1 == kind).map(|k| &k.0).collect();
        order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(
            crate::objects::PROCEDURAL_LIBRARY_SEED ^ set as u64,
        ));
        let n_train = (config.train_share.clamp(0.0, 1.0) * order.len() as f32).round() as usize;
        train.extend(order[..n_train].iter().map(|k| (*k).clone()));
    }
    let objects = keys
        .iter()
        .map(|(key, kind, fit_extent_m)| LibraryObject {
            spec: ObjectSpec {
                name: key.clone(),
                kind: *kind,
                parts: vec![Part {
                    object_from_part: nalgebra::Isometry3::identity(),
                    primitive: Primitive::Mesh {
                        key: key.clone(),
                        scale: 1.0,
                    },
                }],
            },
            split: if train.contains(key) {
                Split::Train
            } else {
                Split::Test
            },
            fit_extent_m: *fit_extent_m,
        })
        .collect();
    Ok(crate::ObjectLibrary { objects })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_mesh_set_loads_decomposes_and_caches() {
        let dir = std::env::temp_dir().join(format!("psgrasp-mesh-test-{}", std::process::id()));
        let sub = dir.join("random_urdfs/000");
        std::fs::create_dir_all(&sub).unwrap();
        // A unit cube as OBJ (will be rescaled to 80 mm).
        let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
                   f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n";
        std::fs::write(sub.join("000.obj"), obj).unwrap();
        std::fs::write(sub.join("000_coll.obj"), obj).unwrap();
        let mut meshes = MeshLibrary::default();
        let lib = load_mesh_set(&dir, MeshSet::RandomUrdf, &mut meshes).unwrap();
        assert_eq!(lib.objects.len(), 1);
        assert_eq!(meshes.len(), 1);
        let shape = lib.objects[0].spec.build_shape(&meshes).unwrap();
        let aabb = shape.compute_local_aabb();
        assert!(((aabb.maxs - aabb.mins).max_element() - 0.08).abs() < 1e-4);
        assert!(lib.objects[0].spec.build_physics_shape(&meshes).is_ok());
        // Second load comes from the cache and gives the same pieces.
        let mut again = MeshLibrary::default();
        load_mesh_set(&dir, MeshSet::RandomUrdf, &mut again).unwrap();
        assert_eq!(
            meshes.get("random_urdfs/000"),
            again.get("random_urdfs/000")
        );
        assert!(dir.join("cache").read_dir().unwrap().count() >= 1);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn missing_directory_is_a_clear_error() {
        let mut meshes = MeshLibrary::default();
        let err = load_mesh_set(
            std::path::Path::new("/nonexistent/psgrasp"),
            MeshSet::Ycb,
            &mut meshes,
        )
        .unwrap_err();
        assert!(matches!(err, SimError::InvalidMesh { .. }));
    }
}
