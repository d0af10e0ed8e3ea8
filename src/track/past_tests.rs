//! Tests of tracking with the past.

use crate::evidence::Constructor;
use crate::track::tracking::tests::tiny_tracker;

fn frame() -> Vec<Option<Vec<f64>>> {
    vec![
        Some(vec![0.3, 0.7]),
        Some(vec![0.2, 0.5, 0.3]),
        Some(vec![0.6, 0.4]),
    ]
}

#[test]
fn a_vacuous_past_joins_and_changes_nothing() {
    for constructor in [Constructor::Bayesian, Constructor::Consonant] {
        let tracker = tiny_tracker(constructor);
        let alone = tracker.track(&frame()).unwrap();
        let with = tracker
            .track_with_past(&frame(), &[1.0; 6], 1.0, false)
            .unwrap();
        assert!(with.past_joined, "{constructor:?}");
        assert_eq!(with.frame.group, alone.group);
        assert!((with.frame.conflict_level.unwrap() - alone.conflict_level.unwrap()).abs() < 1e-12);
        let (a, b) = (alone.estimate.unwrap(), with.frame.estimate.unwrap());
        assert!(
            (a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12,
            "{a:?} {b:?}"
        );
    }
}

#[test]
fn the_past_level_is_the_conflict_of_the_combination_with_the_past() {
    // The carried belief here is Bayesian-free and consonant: contour 1 on poses 4, 5 and
    // 0.25 elsewhere, i.e. mass 0.75 on {4, 5} and 0.25 on Θ. Adding it multiplies the
    // agreeing mass by Σ_F m(F) max_F c, checked against Dempster's rule on the poses.
    let tracker = tiny_tracker(Constructor::Bayesian);
    let carried = [0.25, 0.25, 0.25, 0.25, 1.0, 1.0];
    let with = tracker
        .track_with_past(&frame(), &carried, 1.0, false)
        .unwrap();
    assert!(with.past_joined);
    let alone = tracker.track(&frame()).unwrap();
    // Relative plausibility of the frame's combination per pose, times the carried contour.
    let pl = &alone.plausibility;
    let agree: f64 =
        pl.iter().zip(&carried).map(|(p, c)| p * c).sum::<f64>() / pl.iter().sum::<f64>();
    // Every pose is its own cell here only if the features separate them: poses 4 and 5
    // differ in feature 2, and so on; so max over a cell is the pose's own value.
    let expected = alone.conflict_level.unwrap() - agree.ln();
    assert!(
        (with.frame.conflict_level.unwrap() - expected).abs() < 1e-12,
        "{:?} vs {expected}",
        with.frame.conflict_level
    );
    let total: f64 = pl.iter().zip(&carried).map(|(p, c)| p * c).sum();
    for (k, w) in with.frame.plausibility.iter().enumerate() {
        assert!((w - pl[k] * carried[k] / total).abs() < 1e-12);
    }
}

#[test]
fn the_tuple_sums_give_the_combinations_agreement_with_the_past() {
    use super::PastLevels;
    use rand::{Rng, SeedableRng};
    let tracker = tiny_tracker(Constructor::Bayesian);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for round in 0..50 {
        // Some states impossible now and then, a past from sharp to vacuous.
        let mut draw = |n: usize| -> Option<Vec<f64>> {
            Some((0..n).map(|_| rng.random::<f64>().powi(3)).collect())
        };
        let lik = vec![draw(2), draw(3), draw(2)];
        let carried: Vec<f64> = (0..6).map(|_| rng.random::<f64>().powi(2)).collect();
        let (usable, _) = tracker.measure(&lik).unwrap();
        let mut cell_max = vec![0.0f64; tracker.cell_count()];
        for (&u, &c) in tracker.cell_of.iter().zip(&carried) {
            cell_max[u] = cell_max[u].max(c);
        }
        let mut levels = PastLevels::new(&tracker, &usable, 3, cell_max.clone());
        for group in 1..8u64 {
            let fast = levels.cells.bayesian_agreement(group, &cell_max).unwrap();
            let combined = levels.combined_agreement(group).unwrap_or(0.0);
            assert!(
                (fast - combined).abs() <= 1e-14 * combined.max(1e-300),
                "round {round}, group {group}: {fast} vs {combined}"
            );
        }
    }
    // Consonant functions take the combination.
    let tracker = tiny_tracker(Constructor::Consonant);
    let (usable, _) = tracker.measure(&frame()).unwrap();
    let mut cells = tracker.cell_levels(&usable);
    assert_eq!(
        cells.bayesian_agreement(0b11, &vec![1.0; tracker.cell_count()]),
        None
    );
}

#[test]
fn a_feature_or_pair_agrees_with_the_past_as_its_grown_tuples_bit_for_bit() {
    use rand::{Rng, SeedableRng};
    let tracker = tiny_tracker(Constructor::Bayesian);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    for round in 0..200 {
        // Impossible states now and then (a zero cube), and tiny values.
        let mut draw = |n: usize| -> Option<Vec<f64>> {
            Some(
                (0..n)
                    .map(|_| rng.random_range(-0.2f64..1.0).max(0.0).powi(5))
                    .collect(),
            )
        };
        let lik = vec![draw(2), draw(3), draw(2)];
        let cell_max: Vec<f64> = (0..tracker.cell_count())
            .map(|_| rng.random::<f64>().powi(3))
            .collect();
        let (usable, _) = tracker.measure(&lik).unwrap();
        let mut stack = crate::track::tuples::TupleStack::default();
        // A small model numbers each pair's tuples on the cells: its pairs take that path.
        assert!(tracker
            .pair_tuples
            .cell_tuples(0, 2, &tracker.to_cells)
            .is_some());
        for group in [0b001u64, 0b010, 0b100, 0b011, 0b101, 0b110] {
            let direct =
                (stack.small_agreement(&tracker, &usable, group, &cell_max)).expect("small tables");
            let grown = stack.grown_agreement(&tracker, &usable, group, &cell_max);
            assert_eq!(
                direct.map(f64::to_bits),
                grown.map(f64::to_bits),
                "round {round}, group {group:b}"
            );
        }
    }
}

#[test]
fn each_cell_is_numbered_with_its_pairs_tuple() {
    let tracker = tiny_tracker(Constructor::Bayesian);
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        let ids = tracker
            .pair_tuples
            .cell_tuples(i, j, &tracker.to_cells)
            .unwrap();
        let tuples = tracker.pair_tuples.of(i, j);
        assert_eq!(ids.len(), tracker.cell_count());
        for (k, &t) in ids.iter().enumerate() {
            let (x, y) = tuples[usize::from(t)];
            let states = (
                tracker.to_cells[i].assignment()[k],
                tracker.to_cells[j].assignment()[k],
            );
            assert_eq!(
                (x as usize, y as usize),
                states,
                "pair ({i}, {j}), cell {k}"
            );
        }
    }
}

#[test]
fn a_past_in_total_conflict_is_dropped_and_the_frame_is_followed() {
    let mut tracker = tiny_tracker(Constructor::Bayesian);
    tracker.settings.conflict_threshold = crate::evidence::ConflictLevel::Finite(5.0);
    // Only pose 0 is plausible for the frame; the past says poses 4 and 5, nothing else.
    let lik = vec![
        Some(vec![1.0, 0.0]),
        Some(vec![1.0, 0.0, 0.0]),
        Some(vec![1.0, 0.0]),
    ];
    let with = tracker
        .track_with_past(&lik, &[0.0, 0.0, 0.0, 0.0, 1.0, 1.0], 1.0, false)
        .unwrap();
    assert!(!with.past_joined);
    assert_eq!(with.frame.group, vec![0, 1, 2]);
    assert_eq!(with.frame.estimate, tracker.track(&lik).unwrap().estimate);
    // The wrong length and the splitting policy are refused with a message.
    let short = tracker
        .track_with_past(&lik, &[1.0; 3], 1.0, false)
        .unwrap_err();
    assert!(
        short.to_string().contains("one value per sample pose"),
        "{short}"
    );
}

#[test]
fn the_peaks_are_the_largest_cells() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
    for n in [1usize, 2, 3, 4, 5, 9, 40] {
        for _ in 0..20 {
            // Few distinct values, so that ties occur.
            let values: Vec<f64> = (0..n).map(|_| rng.random_range(0..5) as f64).collect();
            let mut order: Vec<usize> = (0..n).collect();
            order.sort_by(|&a, &b| values[b].total_cmp(&values[a]).then(a.cmp(&b)));
            let peaks = super::peak_cells(&values);
            for (r, &k) in peaks.iter().enumerate() {
                assert_eq!(k, order[r.min(n - 1)], "{values:?}: {peaks:?}");
            }
        }
    }
}

#[test]
fn a_proven_group_is_within_the_threshold_and_the_choice_is_unchanged() {
    use super::{group_beside_past, group_beside_past_with, PastLevels};
    use crate::evidence::ConflictLevel;
    use crate::track::GroupLevels;
    use rand::{Rng, SeedableRng};
    let mut tracker = tiny_tracker(Constructor::Bayesian);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    let mut proven = 0;
    for round in 0..400 {
        let mut draw = |n: usize| -> Option<Vec<f64>> {
            Some((0..n).map(|_| rng.random::<f64>().powi(3)).collect())
        };
        let lik = vec![draw(2), draw(3), draw(2)];
        let carried: Vec<f64> = (0..6).map(|_| rng.random::<f64>().powi(4)).collect();
        let threshold = match round % 4 {
            0 => ConflictLevel::Infinite,
            _ => ConflictLevel::Finite(rng.random_range(0.0..4.0)),
        };
        tracker.settings.conflict_threshold = threshold;
        let (usable, _) = tracker.measure(&lik).unwrap();
        let mut cell_max = vec![0.0f64; tracker.cell_count()];
        for (&u, &c) in tracker.cell_of.iter().zip(&carried) {
            cell_max[u] = cell_max[u].max(c);
        }
        let fresh = || PastLevels::new(&tracker, &usable, 3, cell_max.clone());
        let mut levels = fresh();
        for group in [1u64, 2, 4, 3, 5, 6] {
            if levels.proven_within(group, threshold) {
                proven += 1;
                let exact = levels.group_level(group | 1 << 3);
                assert!(threshold.admits(exact), "round {round}, {group}: {exact}");
            }
        }
        let policy = crate::track::SelectionPolicy::LargestSubset;
        let plain = group_beside_past(&mut fresh(), 0b111, 3, policy, threshold);
        let fast = group_beside_past_with(&mut fresh(), 0b111, 3, policy, threshold, {
            |l: &mut PastLevels, g| l.proven_within(g, threshold)
        });
        assert_eq!(plain.0, fast.0, "round {round}");
        assert_eq!(plain.1.to_bits(), fast.1.to_bits(), "round {round}");
    }
    assert!(proven > 100, "{proven}");
}

#[test]
fn the_proof_bound_is_never_below_the_level_it_bounds() {
    use super::PastLevels;
    use crate::track::GroupLevels;
    use rand::{Rng, SeedableRng};
    let tracker = tiny_tracker(Constructor::Bayesian);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
    let (mut bounded, mut tight, mut above_one) = (0, 0, 0);
    for round in 0..2000 {
        // Unnormalised likelihoods (scales above and below 1), impossible states now and then,
        // and now and then a carried belief above 1 somewhere (the own level's path).
        let scale = [1e-3, 0.5, 1.0, 40.0][round % 4];
        let mut draw = |n: usize| -> Option<Vec<f64>> {
            Some(
                (0..n)
                    .map(|_| scale * rng.random_range(-0.2f64..1.0).max(0.0).powi(3))
                    .collect(),
            )
        };
        let lik = vec![draw(2), draw(3), draw(2)];
        let top = if round % 5 == 0 { 1.5 } else { 1.0 };
        let carried: Vec<f64> = (0..6).map(|_| top * rng.random::<f64>().powi(2)).collect();
        let Ok((usable, _)) = tracker.measure(&lik) else {
            continue;
        };
        let mut cell_max = vec![0.0f64; tracker.cell_count()];
        for (&u, &c) in tracker.cell_of.iter().zip(&carried) {
            cell_max[u] = cell_max[u].max(c);
        }
        above_one += cell_max.iter().any(|&c| c > 1.0) as usize;
        let mut levels = PastLevels::new(&tracker, &usable, 3, cell_max);
        for group in [1u64, 2, 4, 3, 5, 6] {
            let Some(bound) = levels.proof_bound(group) else {
                continue;
            };
            let exact = levels.group_level(group | 1 << 3);
            assert!(
                exact <= bound + 1e-12 * (1.0 + bound),
                "round {round}, group {group:b}: {exact} above {bound}"
            );
            bounded += 1;
            tight += (bound - exact < 1e-9 * (1.0 + exact)) as usize;
        }
    }
    // Bounds were given, some of them equal to the level, and the own level's path was taken.
    assert!(
        bounded > 3000 && tight > 100 && above_one > 100,
        "{bounded} {tight} {above_one}"
    );
}

#[test]
fn a_doubtful_past_never_outweighs_a_feature_of_a_coherent_frame() {
    let mut tracker = tiny_tracker(Constructor::Bayesian);
    // The three features agree (level 0.70) around pose 2; the past says pose 3, which
    // feature 0 rules out.
    let lik = vec![
        Some(vec![0.7, 0.3]),
        Some(vec![0.1, 0.6, 0.3]),
        Some(vec![0.35, 0.65]),
    ];
    let past = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0];
    tracker.settings.conflict_threshold = crate::evidence::ConflictLevel::Finite(2.0);
    let alone = tracker.track(&lik).unwrap();
    assert_eq!(alone.group, vec![0, 1, 2]);
    // Counted as 1.5 features, the past outweighs feature 0 ...
    let trusted = tracker.track_with_past(&lik, &past, 1.5, false).unwrap();
    assert!(trusted.past_joined);
    assert_eq!(trusted.frame.group, vec![1, 2]);
    // ... unless it is doubtful: the frame alone.
    let doubtful = tracker.track_with_past(&lik, &past, 1.5, true).unwrap();
    assert!(!doubtful.past_joined);
    assert_eq!(doubtful.frame.estimate, alone.estimate);
    assert_eq!(doubtful.frame.group, alone.group);
    // A frame whose features do not all agree (threshold 0.5: 0.70 is beyond it) weighs a
    // doubtful past as any other.
    tracker.settings.conflict_threshold = crate::evidence::ConflictLevel::Finite(0.5);
    let split = |doubtful| tracker.track_with_past(&lik, &past, 1.5, doubtful).unwrap();
    let (a, b) = (split(false), split(true));
    assert_eq!(
        (a.past_joined, &a.frame.group),
        (b.past_joined, &b.frame.group)
    );
    assert_eq!(a.frame.estimate, b.frame.estimate);
}
