//! The pruned group search on the grid levels against the exhaustive enumeration of every
//! complete subgraph, and the 64-feature frame.

use super::super::frame::Frame;
use super::super::{Continuous, ContinuousSettings};
use crate::estimator::test_maps::{
    feature_row, feature_value, fitted_continuous, workspace_mesh, workspace_points,
};
use crate::estimator::{Labelled, PoseEstimator, TrainingSet};
use crate::evidence::ConflictLevel;
use crate::planar::distance;
use crate::track::{select_group, select_group_exhaustive, SelectionPolicy};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const NOISE: f64 = 0.002;

/// The tracker on `features` test maps over a mesh of `per_side`² samples, threshold learned.
fn fitted(features: usize, per_side: usize) -> Continuous {
    fitted_continuous(features, per_side, 100, NOISE, true, 1)
}

/// A frame at a random pose: each feature stuck at its value of another pose (in range), far
/// outside its range, missing, or clean.
fn faulty_frame(features: usize, rng: &mut ChaCha8Rng) -> Vec<Option<f64>> {
    let q = workspace_points(1, rng)[0];
    let mut row = feature_row(features, q, NOISE, rng);
    for (i, v) in row.iter_mut().enumerate() {
        let u: f64 = rng.random();
        if u < 0.15 {
            *v = Some(feature_value(i, workspace_points(1, rng)[0]));
        } else if u < 0.22 {
            *v = v.map(|x| x + 3.0);
        } else if u < 0.27 {
            *v = None;
        }
    }
    row
}

#[test]
fn the_pruned_search_chooses_as_every_complete_subgraph_does() {
    let features = 12;
    let base = fitted(features, 20);
    let learned = base.threshold().value();
    assert!(learned.is_finite() && learned > 0.0);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let policies = [
        SelectionPolicy::LargestSubset,
        SelectionPolicy::LowestConflict { min_size: 1 },
        SelectionPolicy::LowestConflict { min_size: 3 },
        SelectionPolicy::Splitting { min_size: 2 },
    ];
    let mut searched = 0;
    for _ in 0..10 {
        let row = faulty_frame(features, &mut rng);
        for threshold in [learned * 0.25, learned, learned * 4.0, f64::INFINITY] {
            let mut model = base.clone();
            model.file.conflict_threshold = if threshold.is_finite() {
                ConflictLevel::Finite(threshold)
            } else {
                ConflictLevel::Infinite
            };
            let values = model.usable(row.clone());
            for policy in policies {
                let mut a = Frame::new(&model, values.clone());
                let usable = a.usable_mask;
                let pruned = select_group(&mut a, features, usable, policy, model.threshold());
                let mut b = Frame::new(&model, values.clone());
                let every =
                    select_group_exhaustive(&mut b, features, usable, policy, model.threshold());
                assert_eq!(pruned, every, "{policy:?}, threshold {threshold}, {row:?}");
                searched += usize::from(!pruned.fallback && pruned.chosen.is_some());
            }
        }
    }
    // Most comparisons chose a group (not only the fallback).
    assert!(searched > 100, "{searched}");
}

#[test]
fn levels_grow_as_features_are_added_and_match_the_fit() {
    let features = 8;
    let model = fitted(features, 20);
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    for _ in 0..20 {
        let q = workspace_points(1, &mut rng)[0];
        let row = feature_row(features, q, NOISE, &mut rng);
        let mut frame = Frame::new(&model, model.usable(row));
        let mut previous = 0.0;
        let mut group = 0;
        for i in 0..features {
            group |= 1 << i;
            let level = frame.grid_level(group, f64::INFINITY).value;
            assert!(level >= previous, "{level} < {previous}");
            previous = level;
        }
        // On a clean frame the grid's level is the fitted minimum up to the cells' linear model:
        // these maps bend by ~0.5 σ within 0.125 mm of a node, and 20 frames measured levels
        // from 0.40 below to 0.45 above fits of 0.68–6.2.
        let fitted = 0.5 * frame.fit(group).chi2;
        assert!(
            (previous - fitted).abs() <= 0.15 * (1.0 + fitted),
            "{previous} {fitted}"
        );
    }
}

#[test]
fn a_64_feature_frame_leaves_out_its_stuck_features() {
    let features = 64;
    let model = fitted(features, 12);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let stuck = [3, 20, 41, 60];
    for _ in 0..3 {
        let q = workspace_points(1, &mut rng)[0];
        let clean = feature_row(features, q, NOISE, &mut rng);
        let e = model.estimate(&clean).unwrap();
        assert!(e.flags.excluded.is_empty(), "{:?}", e.flags.excluded);
        let mut row = clean.clone();
        for i in stuck {
            row[i] = row[i].map(|v| v + 0.6);
        }
        let e = model.estimate(&row).unwrap();
        assert_eq!(e.flags.excluded, stuck.to_vec());
        assert!(distance(e.pose.unwrap(), q) < 0.05);
    }
}

#[test]
fn sixty_five_features_are_refused() {
    let names: Vec<String> = (0..65).map(|i| format!("f{i}")).collect();
    let poses = workspace_mesh(3);
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let rows: Vec<_> = (poses.iter())
        .map(|&q| feature_row(65, q, NOISE, &mut rng))
        .collect();
    let data = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows: &rows,
        },
    );
    let error = Continuous::fit(&ContinuousSettings::default(), &data).unwrap_err();
    assert!(
        error
            .to_string()
            .contains("65 features, but the continuous tracker takes at most 64"),
        "{error}"
    );
}
