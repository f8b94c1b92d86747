//! Decoding the MLP outputs at contact points into [`GraspConfiguration`]s (network contract,
//! "Contact sampling and decoding", steps 4–5).
//!
//! Per point `c` with baseline `b`, width `w`, quality prior `q′` and collision priors `σ′_i`:
//! `b⊥ = normalize(up − (up·b)b)` (`up = +z`, or `+x` when that norm is below 1e-3), approach
//! vectors `a_i = R(b, γ_i)·b⊥` with `γ_i = π/2 + π·i/17`, `TCP = c + (w/2)·b`, approach points
//! `t_i = TCP − a_i·d`; then `q = I(P_contact, c)·q′` and `σ_i = I(P_gripper, t_i)·σ′_i`, with `I` the
//! clamped trilinear interpolation of the level-0 probability grids. Single-approach models keep
//! only the highest `σ_i` (ties → lower index) and set the others to 0.
use super::card::ModelError;
use super::sampling::{ClassProbabilities, GridLevel};
use nalgebra::{Point3, Vector3};
use psgrasp_geometry::{GraspConfiguration, Workspace, N_APPROACHES};

/// The per-point outputs of `mlp.onnx`, row-major, for N points.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HeadOutputs {
    /// `[N, 3]` unit baselines ν.
    pub baseline: Vec<f32>,
    /// `[N]` concentrations κ.
    pub kappa: Vec<f32>,
    /// `[N]` opening widths in metres.
    pub width: Vec<f32>,
    /// `[N]` quality priors q′ in [0, 1].
    pub quality_prior: Vec<f32>,
    /// `[N, 18]` collision priors σ′_i in [0, 1].
    pub collision_prior: Vec<f32>,
}

impl HeadOutputs {
    /// Number of points N (from `kappa`).
    pub fn len(&self) -> usize {
        self.kappa.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.kappa.is_empty()
    }

    /// Removes every point, keeping the allocations.
    pub fn clear(&mut self) {
        self.baseline.clear();
        self.kappa.clear();
        self.width.clear();
        self.quality_prior.clear();
        self.collision_prior.clear();
    }

    /// Checks that all outputs have N rows of the right width and hold finite values.
    pub fn check(&self) -> Result<(), ModelError> {
        let n = self.len();
        for (name, v, w) in [
            ("baseline", &self.baseline, 3),
            ("kappa", &self.kappa, 1),
            ("width", &self.width, 1),
            ("quality_prior", &self.quality_prior, 1),
            ("collision_prior", &self.collision_prior, N_APPROACHES),
        ] {
            if v.len() != n * w {
                return Err(ModelError::GraphInterface {
                    graph: "mlp",
                    reason: format!("output `{name}` has {} values, {n} × {w} expected", v.len()),
                });
            }
            if let Some(index) = v.iter().position(|x| !x.is_finite()) {
                return Err(ModelError::NonFiniteOutput {
                    output: name,
                    index,
                });
            }
        }
        Ok(())
    }
}

/// Decoding settings from the model card.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DecodeSettings {
    /// TCP to palm distance `d` for the approach points.
    pub approach_depth_m: f32,
    /// Keep only the best approach per configuration.
    pub single_approach: bool,
    /// The card's `kappa0`, the floor the graph clamps κ to; every configuration carries it
    /// ([`GraspConfiguration::kappa_floor`]).
    pub kappa_floor: f32,
}

/// `(cos γ_i, sin γ_i)` for `γ_i = π/2 + π·i/(N_APPROACHES − 1)`.
fn approach_rotations() -> [(f32, f32); N_APPROACHES] {
    std::array::from_fn(|i| {
        let g = std::f64::consts::FRAC_PI_2
            + std::f64::consts::PI * i as f64 / (N_APPROACHES - 1) as f64;
        (g.cos() as f32, g.sin() as f32)
    })
}

/// `b⊥` of the contract: `normalize(up − (up·b)b)`, or from `+x` when that norm is below 1e-3.
#[inline]
fn perpendicular(b: [f32; 3]) -> [f32; 3] {
    let p = [-b[2] * b[0], -b[2] * b[1], 1.0 - b[2] * b[2]];
    let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    if n >= 1e-3 {
        return [p[0] / n, p[1] / n, p[2] / n];
    }
    let p = [1.0 - b[0] * b[0], -b[0] * b[1], -b[0] * b[2]];
    let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
        .sqrt()
        .max(f32::MIN_POSITIVE);
    [p[0] / n, p[1] / n, p[2] / n]
}

/// The 18 approach vectors `a_i = R(b, γ_i)·b⊥` (Rodrigues; `b⊥ ⟂ b`).
pub fn approach_vectors_fast(b: [f32; 3]) -> [[f32; 3]; N_APPROACHES] {
    let rot = approach_rotations();
    approaches_with(&rot, b)
}

#[inline]
fn approaches_with(rot: &[(f32, f32); N_APPROACHES], b: [f32; 3]) -> [[f32; 3]; N_APPROACHES] {
    let p = perpendicular(b);
    let q = [
        b[1] * p[2] - b[2] * p[1],
        b[2] * p[0] - b[0] * p[2],
        b[0] * p[1] - b[1] * p[0],
    ];
    std::array::from_fn(|i| {
        let (c, s) = rot[i];
        [
            c * p[0] + s * q[0],
            c * p[1] + s * q[1],
            c * p[2] + s * q[2],
        ]
    })
}

/// Decodes one frame's MLP outputs point by point (checked once, then infallible per point, so
/// points can be decoded in any order or in parallel).
#[derive(Debug, Clone, Copy)]
pub struct Decoder<'a> {
    contact: GridLevel<'a>,
    gripper: GridLevel<'a>,
    points: &'a [[f32; 3]],
    head: &'a HeadOutputs,
    rotations: [(f32, f32); N_APPROACHES],
    settings: DecodeSettings,
}

impl<'a> Decoder<'a> {
    /// Checks `head` (N rows, finite) against `points` and the probability grids against
    /// `workspace`.
    pub fn new(
        probabilities: &'a ClassProbabilities,
        workspace: &Workspace,
        points: &'a [[f32; 3]],
        head: &'a HeadOutputs,
        settings: &DecodeSettings,
    ) -> Result<Self, ModelError> {
        head.check()?;
        if head.len() != points.len() {
            return Err(ModelError::GraphInterface {
                graph: "mlp",
                reason: format!("{} outputs for {} points", head.len(), points.len()),
            });
        }
        let dims = workspace.dims.map(|d| d as usize);
        let s = workspace.voxel_size_m;
        Ok(Self {
            contact: GridLevel::new(&probabilities.contact, 1, dims, s)?,
            gripper: GridLevel::new(&probabilities.gripper, 1, dims, s)?,
            points,
            head,
            rotations: approach_rotations(),
            settings: *settings,
        })
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The configuration of point `n` (`n < len()`).
    pub fn config(&self, n: usize) -> GraspConfiguration {
        let head = self.head;
        let c = self.points[n];
        let b = [
            head.baseline[3 * n],
            head.baseline[3 * n + 1],
            head.baseline[3 * n + 2],
        ];
        let w = head.width[n];
        let tcp = [
            c[0] + 0.5 * w * b[0],
            c[1] + 0.5 * w * b[1],
            c[2] + 0.5 * w * b[2],
        ];
        let d = self.settings.approach_depth_m;
        let approaches = approaches_with(&self.rotations, b);
        let prior = &head.collision_prior[N_APPROACHES * n..N_APPROACHES * (n + 1)];
        let xs: [f32; N_APPROACHES] = std::array::from_fn(|i| tcp[0] - approaches[i][0] * d);
        let ys: [f32; N_APPROACHES] = std::array::from_fn(|i| tcp[1] - approaches[i][1] * d);
        let zs: [f32; N_APPROACHES] = std::array::from_fn(|i| tcp[2] - approaches[i][2] * d);
        let mut scores = self.gripper.sample_points(&xs, &ys, &zs);
        for (score, &p) in scores.iter_mut().zip(prior) {
            *score *= p;
        }
        if self.settings.single_approach {
            let best = (0..N_APPROACHES).fold(
                0,
                |best, i| {
                    if scores[i] > scores[best] {
                        i
                    } else {
                        best
                    }
                },
            );
            for (i, v) in scores.iter_mut().enumerate() {
                if i != best {
                    *v = 0.0;
                }
            }
        }
        GraspConfiguration {
            contact: Point3::from(c),
            baseline: Vector3::from(b),
            collision_scores: scores,
            width: w,
            quality: self.contact.sample(0, c) * head.quality_prior[n],
            kappa: head.kappa[n],
            kappa_floor: self.settings.kappa_floor,
        }
    }
}

/// Decodes `head` at `points` into configurations appended to `out` (one per point, same order).
///
/// `probabilities` are the level-0 class probabilities over `workspace`.
pub fn decode(
    probabilities: &ClassProbabilities,
    workspace: &Workspace,
    points: &[[f32; 3]],
    head: &HeadOutputs,
    settings: &DecodeSettings,
    out: &mut Vec<GraspConfiguration>,
) -> Result<(), ModelError> {
    let decoder = Decoder::new(probabilities, workspace, points, head, settings)?;
    out.reserve(points.len());
    out.extend((0..decoder.len()).map(|n| decoder.config(n)));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use psgrasp_geometry::approach_vectors;

    #[test]
    fn approach_vectors_match_the_geometry_crate() {
        for b in [
            [1.0, 0.0, 0.0],
            [0.3, -0.8, 0.5],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.0006, 0.0, 0.999_999_8],
        ] {
            let bv = Vector3::from(b).normalize();
            let ours = approach_vectors_fast([bv.x, bv.y, bv.z]);
            let theirs = approach_vectors(&bv);
            for i in 0..N_APPROACHES {
                assert!(
                    (Vector3::from(ours[i]) - theirs[i]).norm() < 2e-5,
                    "b {b:?} approach {i}: {:?} vs {:?}",
                    ours[i],
                    theirs[i]
                );
            }
        }
    }

    fn one_point_head(b: [f32; 3], w: f32, q: f32, sigma: [f32; N_APPROACHES]) -> HeadOutputs {
        HeadOutputs {
            baseline: b.to_vec(),
            kappa: vec![30.0],
            width: vec![w],
            quality_prior: vec![q],
            collision_prior: sigma.to_vec(),
        }
    }

    /// Probability grids that are linear in position: `P_c = 0.2 + x`, `P_g = 0.1 + 2z`
    /// (within [0, 1] on this grid), so the interpolated values are known in closed form.
    fn linear_probabilities(ws: &Workspace) -> ClassProbabilities {
        let n = ws.voxel_count();
        let mut p = ClassProbabilities {
            contact: vec![0.0; n],
            gripper: vec![0.0; n],
        };
        for idx in 0..n {
            let [i, j, k] = ws.unindex(idx);
            let c = ws.voxel_center(i, j, k);
            p.contact[idx] = 0.2 + c.x;
            p.gripper[idx] = 0.1 + 2.0 * c.z;
        }
        p
    }

    #[test]
    fn decoding_scales_priors_by_interpolated_probabilities() {
        let ws = Workspace {
            dims: [32, 32, 32],
            voxel_size_m: 0.01,
        };
        let probs = linear_probabilities(&ws);
        let c = [0.151, 0.16, 0.12];
        let b = [0.0, 1.0, 0.0];
        let w = 0.04;
        let sigma: [f32; N_APPROACHES] = std::array::from_fn(|i| 0.5 + 0.02 * i as f32);
        let head = one_point_head(b, w, 0.8, sigma);
        let settings = DecodeSettings {
            approach_depth_m: 0.039,
            single_approach: false,
            kappa_floor: 25.0,
        };
        let mut out = Vec::new();
        decode(&probs, &ws, &[c], &head, &settings, &mut out).unwrap();
        let g = &out[0];
        assert!((g.quality - (0.2 + c[0]) * 0.8).abs() < 1e-5);
        assert_eq!(g.width, w);
        assert_eq!(g.kappa, 30.0);
        assert_eq!(
            g.kappa_floor, 25.0,
            "the card's floor travels with the configuration"
        );
        // Approach i points along a_i; the approach point is tcp − a_i·d, P_g depends on z only.
        let a = approach_vectors(&Vector3::from(b));
        let tcp_z = c[2] + 0.5 * w * b[2];
        for i in 0..N_APPROACHES {
            let tz = tcp_z - a[i].z * 0.039;
            let expected = (0.1 + 2.0 * tz) * sigma[i];
            assert!(
                (g.collision_scores[i] - expected).abs() < 1e-5,
                "approach {i}: {} vs {expected}",
                g.collision_scores[i]
            );
        }
        // Approaches point down, so approach points lie above the TCP: straight down (middle) is
        // the highest, hence has the largest gripper probability factor.
        let factor = |i: usize| g.collision_scores[i] / sigma[i];
        assert!(factor(8) > factor(0) && factor(9) > factor(17));

        let single = DecodeSettings {
            single_approach: true,
            ..settings
        };
        let mut out1 = Vec::new();
        decode(&probs, &ws, &[c], &head, &single, &mut out1).unwrap();
        let best = g.approaches_by_score()[0];
        for i in 0..N_APPROACHES {
            let expected = if i == best {
                g.collision_scores[i]
            } else {
                0.0
            };
            assert_eq!(out1[0].collision_scores[i], expected);
        }
    }

    #[test]
    fn decoding_refuses_inconsistent_head_outputs() {
        let ws = Workspace {
            dims: [8, 8, 8],
            voxel_size_m: 0.01,
        };
        let probs = linear_probabilities(&ws);
        let settings = DecodeSettings {
            approach_depth_m: 0.039,
            single_approach: false,
            kappa_floor: 25.0,
        };
        let mut head = one_point_head([1.0, 0.0, 0.0], 0.03, 0.5, [0.5; N_APPROACHES]);
        let mut out = Vec::new();
        assert!(decode(
            &probs,
            &ws,
            &[[0.0; 3], [0.0; 3]],
            &head,
            &settings,
            &mut out
        )
        .is_err());
        head.collision_prior.pop();
        assert!(matches!(
            decode(&probs, &ws, &[[0.0; 3]], &head, &settings, &mut out),
            Err(ModelError::GraphInterface { .. })
        ));
        let mut head = one_point_head([1.0, 0.0, 0.0], f32::NAN, 0.5, [0.5; N_APPROACHES]);
        assert!(matches!(
            decode(&probs, &ws, &[[0.0; 3]], &head, &settings, &mut out),
            Err(ModelError::NonFiniteOutput {
                output: "width",
                ..
            })
        ));
        head.width[0] = 0.03;
        decode(&probs, &ws, &[[0.0; 3]], &head, &settings, &mut out).unwrap();
        assert_eq!(out.len(), 1);
    }
}
