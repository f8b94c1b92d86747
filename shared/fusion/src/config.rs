//! Tuned parameters of the fusion.
use crate::FusionError;
use serde::{Deserialize, Serialize};

/// Parameters of TSDF integration and normal extraction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FusionConfig {
    /// Truncation distance in voxels (the band half-width). Default 4.
    pub truncation_voxels: f32,
    /// Depth readings closer than this (metres) are treated as invalid. Default 0.1 m.
    pub min_depth_m: f32,
    /// Depth readings farther than this (metres) are treated as invalid. Default 3 m.
    pub max_depth_m: f32,
    /// Cap of the per-voxel integration weight; once reached the running average becomes an
    /// exponential moving average, so the volume can follow a changing scene. Default 64.
    pub max_weight: f32,
    /// Integrate voxels in free space (in front of the band) as +1, so a later view can carve
    /// away surfaces seen earlier. Default true.
    pub carve_free_space: bool,
    /// Weight of such a free-space observation. A truncated +1 only says "at least one band
    /// away from this view's surface"; at full weight it would bend the distances another view
    /// measured near a surface (≈2° of extra normal error at silhouettes in our two-view test).
    /// Default 0.1.
    pub free_space_weight: f32,
    /// Observations behind the surface (negative distance) get a weight falling linearly from 1
    /// at the surface to `behind_min_weight` at this fraction of the band. Behind a view's
    /// silhouette the band claims space the object does not fill; another view that sees that
    /// space as free then wins the average. Default 0.5.
    pub behind_falloff: f32,
    /// Smallest weight of an observation behind the surface (see `behind_falloff`). Default 0.05.
    pub behind_min_weight: f32,
    /// Interpolate the depth bilinearly between the four pixels around a voxel's projection
    /// (nearest pixel otherwise, and wherever the four differ by more than `max_depth_jump_m`
    /// or one is missing). Removes the half-pixel quantisation of the signed distance on
    /// slanted surfaces, which tilts normals by ~1° and biases the fusion of oblique views.
    /// Default true.
    pub bilinear_depth: bool,
    /// Largest depth difference (metres) between the four interpolated pixels; larger means a
    /// depth discontinuity, where the nearest pixel is used. Default 0.01 m.
    pub max_depth_jump_m: f32,
    /// Smooth the cached TSDF gradients of band voxels with a separable [1, 2, 1] kernel
    /// before reading normals. A voxel samples only a few pixels, so sensor noise of ~2 mm
    /// tilts raw central differences over 9 mm voxels by 5–10°; smoothing cuts that by ~3×
    /// and leaves planar (linear) fields unchanged. Default true.
    pub smooth_gradients: bool,
    /// Closest-point iterations per band voxel when extracting normals (0 = normal of the
    /// first-order projection onto the surface). 3 gets normals of curved surfaces within ~1°
    /// across the whole band. Default 3.
    pub normal_iterations: u32,
    /// Smallest magnitude of the signed-distance gradient (dimensionless: 1 for an exact
    /// distance field, ≥ 1 for a projective one) accepted as a normal direction; band voxels with
    /// weaker gradients (thin or noisy structures) get the mean normal of their neighbours.
    /// Default 0.1.
    pub min_gradient: f32,
}

impl Default for FusionConfig {
    fn default() -> Self {
        Self {
            truncation_voxels: 4.0,
            min_depth_m: 0.1,
            max_depth_m: 3.0,
            max_weight: 64.0,
            carve_free_space: true,
            free_space_weight: 0.1,
            behind_falloff: 0.5,
            behind_min_weight: 0.05,
            bilinear_depth: true,
            max_depth_jump_m: 0.01,
            smooth_gradients: true,
            normal_iterations: 3,
            min_gradient: 0.1,
        }
    }
}

impl FusionConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), FusionError> {
        if !(self.truncation_voxels.is_finite() && (1.0..=64.0).contains(&self.truncation_voxels)) {
            return Err(FusionError::InvalidConfig(
                "truncation_voxels must be in [1, 64]",
            ));
        }
        if !(self.min_depth_m.is_finite() && self.min_depth_m >= 0.0) {
            return Err(FusionError::InvalidConfig(
                "min_depth_m must be finite and >= 0",
            ));
        }
        if !(self.max_depth_m.is_finite() && self.max_depth_m > self.min_depth_m) {
            return Err(FusionError::InvalidConfig(
                "max_depth_m must be finite and > min_depth_m",
            ));
        }
        if !(self.max_weight.is_finite() && self.max_weight >= 1.0) {
            return Err(FusionError::InvalidConfig(
                "max_weight must be finite and >= 1",
            ));
        }
        if !(self.free_space_weight.is_finite()
            && self.free_space_weight > 0.0
            && self.free_space_weight <= 1.0)
        {
            return Err(FusionError::InvalidConfig(
                "free_space_weight must be in (0, 1]",
            ));
        }
        if !(self.behind_falloff.is_finite() && self.behind_falloff > 0.0) {
            return Err(FusionError::InvalidConfig(
                "behind_falloff must be finite and > 0",
            ));
        }
        if !(self.behind_min_weight.is_finite()
            && self.behind_min_weight > 0.0
            && self.behind_min_weight <= 1.0)
        {
            return Err(FusionError::InvalidConfig(
                "behind_min_weight must be in (0, 1]",
            ));
        }
        if !(self.max_depth_jump_m.is_finite() && self.max_depth_jump_m >= 0.0) {
            return Err(FusionError::InvalidConfig(
                "max_depth_jump_m must be finite and >= 0",
            ));
        }
        if self.normal_iterations > 32 {
            return Err(FusionError::InvalidConfig(
                "normal_iterations must be <= 32",
            ));
        }
        if !(self.min_gradient.is_finite() && self.min_gradient > 0.0) {
            return Err(FusionError::InvalidConfig(
                "min_gradient must be finite and > 0",
            ));
        }
        Ok(())
    }
}
