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
