//! The tracker's choice of groups: infinite conflict, splitting, lowest conflict, the threshold
//! on a whole group, reliabilities.

use super::*;

/// Three features on three poses, each with two states: a feature's state 1 is one pose.
fn triangle_model() -> TrackerModel {
    let poses = vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
    let assignments = [[0, 0, 1], [0, 1, 0], [1, 0, 0]];
    let features = assignments
        .iter()
        .map(|a| TrackedFeature {
            refining: Refining::from_assignment(2, a).unwrap(),
            validation_error: None,
        })
        .collect();
    TrackerModel::new(poses, features).unwrap()
}

/// The triangle measured on each feature's state 0: pairwise compatible but with no common pose,
/// so the group of three has infinite conflict (Theorem 4.3 case) and groups of two are used.
fn triangle(policy: SelectionPolicy) -> (Tracker, Vec<Option<Vec<f64>>>) {
    let settings = TrackSettings {
        selection: policy,
        ..TrackSettings::default()
    };
    let t = Tracker::new(triangle_model(), settings.check().unwrap()).unwrap();
    (t, vec![Some(vec![1.0, 0.0]); 3])
}

#[test]
fn pairwise_compatible_group_with_infinite_conflict_is_not_combined() {
    let (t, lik) = triangle(SelectionPolicy::LargestSubset);
    let k = t.pairwise_conflicts(&lik).unwrap();
    assert!(k.iter().flatten().all(|x| *x == Some(0.0)));
    assert_eq!(t.full_conflict_level(&lik).unwrap(), f64::INFINITY);
    let est = t.track(&lik).unwrap();
    assert_eq!(est.group, vec![0, 1]);
    assert_eq!(est.conflict_level, Some(0.0));
    assert_eq!(est.estimate, Some([0.0, 0.0]));
    assert!(!est.flags.fallback);
}

#[test]
fn splitting_lists_every_maximal_group() {
    let (t, lik) = triangle(SelectionPolicy::Splitting { min_size: 2 });
    let est = t.track(&lik).unwrap();
    let groups: Vec<Vec<usize>> = est.alternatives.iter().map(|a| a.group.clone()).collect();
    assert_eq!(groups, vec![vec![0, 1], vec![0, 2], vec![1, 2]]);
    let estimates: Vec<[f64; 2]> = est.alternatives.iter().map(|a| a.estimate).collect();
    assert_eq!(estimates, vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    assert_eq!(est.group, vec![0, 1]);
    // min_size 3: no combinable group that large → fallback, no alternatives.
    let (t, lik) = triangle(SelectionPolicy::Splitting { min_size: 3 });
    let est = t.track(&lik).unwrap();
    assert!(est.flags.fallback && est.alternatives.is_empty());
}

#[test]
fn lowest_conflict_picks_the_least_conflicting_group() {
    let feats = [X, Y, X_COARSE, Y_COARSE, SUM, DIFF];
    let t = tracker(
        &feats,
        TrackSettings {
            selection: SelectionPolicy::LowestConflict { min_size: 2 },
            ..TrackSettings::default()
        },
    );
    for p in points(10, 5) {
        let lik = frame(&feats, p);
        let est = t.track(&lik).unwrap();
        let k = t.pairwise_conflicts(&lik).unwrap();
        let best_pair = (0..feats.len())
            .flat_map(|i| (i + 1..feats.len()).map(move |j| (i, j)))
            .map(|(i, j)| k[i][j].unwrap())
            .fold(f64::INFINITY, f64::min);
        // K grows with the group (Theorem 4.3), so the lowest conflict is a pair's, or a tie.
        assert!(
            (est.conflict_level.unwrap() - best_pair).abs() < 1e-9,
            "{:?} vs {best_pair}",
            est.conflict_level
        );
        assert!(est.group.len() >= 2);
    }
}

#[test]
fn uncertainty_reflects_the_evidence() {
    let feats = [X, Y, SUM, DIFF];
    let t = tracker(&feats, TrackSettings::default());
    let p = [9.3, 4.6];
    let sharp = t.track(&frame(&feats, p)).unwrap();
    let vague = t
        .track(&[None, Some(Y.likelihoods(p[1])), None, None])
        .unwrap();
    let (us, uv) = (sharp.uncertainty.unwrap(), vague.uncertainty.unwrap());
    assert!(us.radius < 1.5 && us.spread < 1.0, "{us:?}");
    // Only y known: x spreads over the whole width of the mesh.
    assert!(uv.radius > 5.0 && uv.spread > 4.0, "{uv:?}");
    let s: f64 = sharp.plausibility.iter().sum();
    assert!((s - 1.0).abs() < 1e-12);
}

#[test]
fn a_group_beyond_the_threshold_is_not_combined_though_every_pair_is_within() {
    let feats = [X, Y, X_COARSE, Y_COARSE, SUM, DIFF];
    let open = tracker(&feats, TrackSettings::default());
    let mut tested = 0;
    for p in points(20, 9) {
        let lik = frame(&feats, p);
        let pairs = open.pairwise_conflicts(&lik).unwrap();
        let worst_pair = pairs
            .iter()
            .flatten()
            .flatten()
            .fold(0.0f64, |a, &b| a.max(b));
        let full = open.full_conflict_level(&lik).unwrap();
        if full <= 1.2 * worst_pair {
            continue;
        }
        tested += 1;
        // Every pair is an edge of the graph, but the whole group is above the threshold.
        let threshold = 0.5 * (worst_pair + full);
        let t = tracker(
            &feats,
            TrackSettings {
                conflict_threshold: ConflictLevel::Finite(threshold),
                ..TrackSettings::default()
            },
        );
        let est = t.track(&lik).unwrap();
        assert!(
            est.group.len() < feats.len() && est.group.len() > 1,
            "{:?}",
            est.group
        );
        assert!(est.conflict_level.unwrap() <= threshold);
        assert_eq!(est.full_conflict_level, Some(full));
        assert_eq!(est.group.len() + est.flags.excluded.len(), feats.len());
        assert!(!est.flags.fallback);
    }
    assert!(
        tested >= 5,
        "only {tested} frames had a group level above every pair's"
    );
}

/// The triangle with soft measurements and the given validation error per pair of features.
fn weighed_triangle(errors: [f64; 3]) -> FrameEstimate {
    capped_triangle(Some(errors), TrackSettings::default().max_alternatives)
}

/// [`weighed_triangle`] keeping at most `cap` alternatives; without `errors`, no group errors.
fn capped_triangle(errors: Option<[f64; 3]>, cap: usize) -> FrameEstimate {
    let groups = [vec![0, 1], vec![0, 2], vec![1, 2]];
    let group_errors: Vec<GroupError> = groups
        .iter()
        .zip(errors.into_iter().flatten())
        .map(|(g, error)| GroupError {
            features: g.clone(),
            error,
        })
        .collect();
    let model = triangle_model().with_group_errors(&group_errors).unwrap();
    let lik = vec![Some(vec![1.0, 0.3]); 3];
    let open = Tracker::new(model.clone(), TrackSettings::default().check().unwrap()).unwrap();
    let pair = open.pairwise_conflicts(&lik).unwrap()[0][1].unwrap();
    let full = open.full_conflict_level(&lik).unwrap();
    assert!(full > 1.5 * pair, "{pair} {full}");
    // Pairs within the threshold, the three together beyond it: three alternatives.
    let settings = TrackSettings {
        selection: SelectionPolicy::Splitting { min_size: 2 },
        conflict_threshold: ConflictLevel::Finite(0.5 * (pair + full)),
        max_alternatives: cap,
        ..TrackSettings::default()
    };
    let t = Tracker::new(model, settings.check().unwrap()).unwrap();
    t.track(&lik).unwrap()
}

#[test]
fn the_cap_keeps_the_most_reliable_alternatives_weighs_only_them_and_counts_them_all() {
    // Uncapped, the third alternative is the most reliable.
    let errors = Some([0.5, 0.5, 0.25]);
    let all = capped_triangle(errors, 3);
    let reliabilities = |e: &FrameEstimate| -> Vec<Option<f64>> {
        e.alternatives.iter().map(|a| a.reliability).collect()
    };
    assert_eq!(reliabilities(&all), [Some(0.5), Some(0.5), Some(1.0)]);
    assert_eq!(
        (all.alternatives_found, all.flags.alternatives_capped),
        (3, false)
    );
    // Kept: the most reliable, then the first of the two tied, in the policy's order; each
    // estimated as uncapped.
    for (cap, kept) in [(1, vec![2]), (2, vec![0, 2])] {
        let capped = capped_triangle(errors, cap);
        assert_eq!(
            (capped.alternatives_found, capped.flags.alternatives_capped),
            (3, true)
        );
        assert_eq!(capped.alternatives.len(), cap);
        for (a, &k) in capped.alternatives.iter().zip(&kept) {
            let b = &all.alternatives[k];
            assert_eq!(
                (&a.group, a.conflict_level, a.estimate, &a.uncertainty),
                (&b.group, b.conflict_level, b.estimate, &b.uncertainty)
            );
        }
    }
    // Two kept: weighed between themselves, the third's full say kept; the level is its.
    let two = capped_triangle(errors, 2);
    assert_eq!(reliabilities(&two), [Some(0.5), Some(1.0)]);
    assert_eq!(two.conflict_level, Some(all.alternatives[2].conflict_level));
    // One kept: nothing to weigh, the most reliable alternative is the estimate and the group.
    let one = capped_triangle(errors, 1);
    assert_eq!(reliabilities(&one), [None]);
    assert_eq!(one.estimate, Some(all.alternatives[2].estimate));
    assert_eq!(one.group, all.alternatives[2].group);
    assert_eq!(one.conflict_level, Some(all.alternatives[2].conflict_level));
    // Without group errors the cap keeps the first in the policy's order.
    let unweighed = capped_triangle(None, 3);
    let first = capped_triangle(None, 1);
    assert_eq!(first.alternatives.len(), 1);
    assert_eq!(first.alternatives[0].group, unweighed.alternatives[0].group);
    assert_eq!(first.estimate, unweighed.estimate);
}

#[test]
fn splitting_weighs_alternatives_by_their_reliability() {
    let close = |a: [f64; 2], b: [f64; 2]| dist(a, b) < 1e-6;
    for best in 0..3 {
        let mut errors = [1e12; 3];
        errors[best] = 0.1;
        let est = weighed_triangle(errors);
        assert_eq!(est.alternatives.len(), 3);
        // The nearly unreliable alternatives barely move the most reliable one's estimate.
        let chosen = &est.alternatives[best];
        assert!(close(est.estimate.unwrap(), chosen.estimate), "{est:?}");
        assert_eq!(chosen.reliability, Some(1.0));
        assert_eq!(est.conflict_level, Some(chosen.conflict_level));
        assert_eq!(est.group, vec![0, 1, 2]);
    }
    // Equal reliabilities: the symmetric combination, between the alternatives.
    let est = weighed_triangle([0.5; 3]);
    let e = est.estimate.unwrap();
    assert!(
        (e[0] - e[1]).abs() < 1e-12 && e[0] > 0.05 && e[0] < 0.5,
        "{e:?}"
    );
    // Halving one alternative's error pulls the estimate towards it.
    let towards = weighed_triangle([0.5, 0.25, 0.5]).estimate.unwrap();
    assert!(
        towards[0] > e[0] && towards[1] < e[1],
        "{towards:?} vs {e:?}"
    );
    // Without reliabilities the first alternative is the estimate, as before.
    let (t, lik) = triangle(SelectionPolicy::Splitting { min_size: 2 });
    let est = t.track(&lik).unwrap();
    assert!(est.alternatives.iter().all(|a| a.reliability.is_none()));
    assert_eq!(est.estimate, Some(est.alternatives[0].estimate));
}
