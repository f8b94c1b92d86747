//! One selection pass over the configurations ([`select_from`]): the visiting order, the checks,
//! spacing, deferred picks and the fallback tier's second pass.
use psgrasp_collision::OccupancyGrid;
use psgrasp_fusion::HeightMapView;
use psgrasp_geometry::{BinModel, GraspConfiguration, GripperModel};

use crate::{
    grasp_centre, GraspChecker, OrderSettings, RejectionCounts, RejectionReason, SelectedGrasp,
    Selection, SelectionConfig, SelectionError,
};

/// What selection tests the hand against besides the bin: the grid's occupied voxels and the
/// frame's height map (either may be absent).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ObservedScene<'a> {
    pub(crate) occupancy: Option<&'a OccupancyGrid>,
    pub(crate) surface: Option<HeightMapView<'a>>,
}

/// The selection behind [`crate::select_filtered`] and [`crate::select_with_occupancy`]: one
/// pass at the primary thresholds, and a second at [`SelectionConfig::fallback`]'s when the first
/// picks nothing.
pub(crate) fn select_from(
    configs: &[GraspConfiguration],
    scene: ObservedScene<'_>,
    bin: &BinModel,
    gripper: &GripperModel,
    cfg: &SelectionConfig,
    mut pregrasp_free: impl FnMut(&SelectedGrasp) -> bool,
) -> Result<Selection, SelectionError> {
    let first = select_pass(configs, scene, bin, gripper, cfg, &mut pregrasp_free)?;
    match &cfg.fallback {
        Some(loose) if first.picks.is_empty() => {
            let second_cfg = loose.applied_to(cfg);
            let second = select_pass(configs, scene, bin, gripper, &second_cfg, pregrasp_free)?;
            Ok(Selection {
                fallback: true,
                ..second
            })
        }
        _ => Ok(first),
    }
}

/// One selection pass at `cfg`'s thresholds. A pick the surface check defers
/// ([`crate::SurfaceCheck::defers`]) makes way for the configuration's next approach; when none
/// of them reaches the fill, the configuration's first deferred pick waits, and the deferred picks
/// are handed out after all others (in the same order, spaced against every pick before them).
fn select_pass(
    configs: &[GraspConfiguration],
    scene: ObservedScene<'_>,
    bin: &BinModel,
    gripper: &GripperModel,
    cfg: &SelectionConfig,
    mut pregrasp_free: impl FnMut(&SelectedGrasp) -> bool,
) -> Result<Selection, SelectionError> {
    let checker =
        GraspChecker::new(cfg, *gripper, *bin, scene.occupancy)?.with_surface(scene.surface);
    let mut order: Vec<usize> = (0..configs.len()).collect();
    // Priority descending (not finite: last, and rejected as invalid); ties by index.
    let settings = OrderSettings {
        cos_half_tolerance: (0.5 * cfg.baseline_tolerance_deg.to_radians()).cos(),
        confident_kappa_above: cfg.confident_kappa_above,
    };
    let priority: Vec<f32> = configs
        .iter()
        .map(|c| cfg.pick_order.priority(c, bin, settings))
        .collect();
    let key = |i: usize| priority[i];
    order.sort_by(|&a, &b| key(b).total_cmp(&key(a)).then(a.cmp(&b)));

    let mut rejected = RejectionCounts::default();
    let mut picks: Vec<SelectedGrasp> = Vec::new();
    let mut deferred: Vec<SelectedGrasp> = Vec::new();
    let mut lowest_taken = f32::INFINITY;
    let too_near = |taken: &[SelectedGrasp], centre: &nalgebra::Vector3<f32>| {
        cfg.pick_spacing_m > 0.0
            && taken.iter().any(|p| {
                (p.workspace_from_gripper.translation.vector - centre).norm() < cfg.pick_spacing_m
            })
    };
    for (rank, &ci) in order.iter().enumerate() {
        let c = &configs[ci];
        // Enough picks, and this and every later configuration rank below all of them.
        if picks.len() >= cfg.top_k && key(ci) < lowest_taken {
            rejected.not_examined += order.len() - rank;
            break;
        }
        if let Err(reason) = checker.check_configuration(c) {
            rejected.add(reason);
            continue;
        }
        if too_near(&picks, &grasp_centre(c).coords) {
            rejected.near_better_pick += 1;
            continue;
        }
        let mut picked = false;
        let mut first_deferred = None;
        for &ai in c
            .approaches_by_score()
            .iter()
            .take(cfg.approaches_per_configuration)
        {
            match checker.check_approach(c, ci, ai) {
                Ok(pick) if !pregrasp_free(&pick) => {
                    rejected.add(RejectionReason::PregraspCollision)
                }
                Ok(pick) if cfg.surface_check.defers(&pick) => {
                    first_deferred.get_or_insert(pick);
                }
                Ok(pick) => {
                    picks.push(pick);
                    lowest_taken = lowest_taken.min(key(ci));
                    picked = true;
                    break;
                }
                Err(reason) => rejected.add(reason),
            }
        }
        match first_deferred {
            Some(pick) if !picked => {
                rejected.deferred_pad_fill += 1;
                deferred.push(pick);
            }
            _ if !picked => rejected.no_valid_approach += 1,
            _ => {}
        }
    }
    picks.sort_by(|a, b| {
        key(b.configuration_index)
            .total_cmp(&key(a.configuration_index))
            .then(b.collision_score.total_cmp(&a.collision_score))
            .then(a.configuration_index.cmp(&b.configuration_index))
    });
    picks.truncate(cfg.top_k);
    for pick in deferred {
        if picks.len() >= cfg.top_k {
            break;
        }
        if !too_near(&picks, &pick.workspace_from_gripper.translation.vector) {
            picks.push(pick);
        }
    }
    Ok(Selection {
        picks,
        rejected,
        fallback: false,
    })
}
