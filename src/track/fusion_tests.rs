use super::*;
use crate::evidence::{ConflictLevel, Constructor, Refining};
use crate::track::tracking::tests::tiny_tracker;
use crate::track::{SelectionPolicy, TrackedFeature};

fn tracker(constructor: Constructor, errors: Option<[f64; 3]>, settings: TrackSettings) -> Tracker {
    let base = tiny_tracker(constructor);
    let mut features: Vec<TrackedFeature> = base.model().features().to_vec();
    if let Some(e) = errors {
        for (f, e) in features.iter_mut().zip(e) {
            f.validation_error = Some(e);
        }
    }
    let model = TrackerModel::new(base.model().poses().to_vec(), features).unwrap();
    let settings = TrackSettings {
        constructor,
        ..settings
    };
    Tracker::new(model, settings.check().unwrap()).unwrap()
}

fn frames() -> Vec<Vec<Option<Vec<f64>>>> {
    vec![
        vec![
            Some(vec![0.9, 0.2]),
            Some(vec![0.1, 0.5, 0.7]),
            Some(vec![0.3, 0.8]),
        ],
        // Features 0 and 1 in total conflict when Bayesian.
        vec![
            Some(vec![1.0, 0.0]),
            Some(vec![0.0, 0.0, 1.0]),
            Some(vec![1.0, 0.01]),
        ],
        vec![Some(vec![0.5, 0.5]), None, Some(vec![0.05, 0.6])],
    ]
}

#[test]
fn every_shortcut_equals_the_general_combination_on_the_cells() {
    let mut compared = 0;
    for constructor in [Constructor::Bayesian, Constructor::Consonant] {
        for rule in [
            Rule::Dempster,
            Rule::Conjunctive,
            Rule::Murphy,
            Rule::Disjunctive,
            Rule::Yager,
        ] {
            for discount in [Discount::None, Discount::Fixed(0.7), Discount::Learned] {
                let settings = TrackSettings {
                    rule,
                    discount,
                    ..TrackSettings::default()
                };
                let t = tracker(constructor, Some([1.0, 2.0, 4.0]), settings);
                for lik in frames() {
                    let (usable, _) = t.measure(&lik).unwrap();
                    for group in [0b111, 0b011, 0b101, 0b001] {
                        let Some(fast) = t.shortcut_weights(group, &usable) else {
                            assert!(rule == Rule::Yager && discount != Discount::None);
                            continue;
                        };
                        let fast = t.on_poses(&fast);
                        let slow = t
                            .general_weights(group, &usable, false)
                            .and_then(|w| t.on_poses(&w));
                        let what =
                            format!("{constructor:?} {rule:?} {discount:?} {lik:?} {group:b}");
                        match (fast, slow) {
                            (Some(a), Some(b)) => {
                                for (x, y) in a.iter().zip(&b) {
                                    assert!((x - y).abs() < 1e-12, "{what}: {a:?} vs {b:?}");
                                }
                                compared += 1;
                            }
                            (a, b) => {
                                // Only Dempster's rule on total conflict has no result.
                                assert!(a.is_none() && b.is_none(), "{what}: {a:?} vs {b:?}");
                                assert!(matches!(rule, Rule::Dempster | Rule::Conjunctive));
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(compared > 100, "{compared}");
}

#[test]
fn the_conjunctive_rule_estimates_as_dempsters_and_yagers_does_not() {
    let lik = &frames()[0];
    let est = |rule| {
        let settings = TrackSettings {
            rule,
            combine: Combine::All,
            ..TrackSettings::default()
        };
        tracker(Constructor::Bayesian, None, settings)
            .track(lik)
            .unwrap()
            .estimate
            .unwrap()
    };
    let d = est(Rule::Dempster);
    let c = est(Rule::Conjunctive);
    assert!((d[0] - c[0]).abs() < 1e-12, "{d:?} {c:?}");
    assert!((est(Rule::Yager)[0] - d[0]).abs() > 1e-3);
}

#[test]
fn combining_all_keeps_every_usable_feature_beyond_the_threshold() {
    let lik = &frames()[0];
    let settings = |combine| TrackSettings {
        conflict_threshold: ConflictLevel::Finite(0.0),
        combine,
        ..TrackSettings::default()
    };
    let selected = tracker(Constructor::Bayesian, None, settings(Combine::Selected));
    let all = tracker(Constructor::Bayesian, None, settings(Combine::All));
    let s = selected.track(lik).unwrap();
    let a = all.track(lik).unwrap();
    assert!(s.group.len() < 3, "{s:?}");
    assert_eq!(a.group, vec![0, 1, 2]);
    assert!(a.flags.excluded.is_empty());
    assert_eq!(a.conflict_level, a.full_conflict_level);
    // Under Dempster's rule on total conflict, combining everything fails and says so.
    let total = all.track(&frames()[1]).unwrap();
    assert!(total.flags.combination_failed && total.estimate.is_none());
    let yager = tracker(
        Constructor::Bayesian,
        None,
        TrackSettings {
            rule: Rule::Yager,
            ..settings(Combine::All)
        },
    );
    let y = yager.track(&frames()[1]).unwrap();
    assert!(y.estimate.is_some(), "{y:?}");
}

#[test]
fn learned_reliabilities_are_the_best_error_over_each_features_own() {
    let settings = TrackSettings {
        discount: Discount::Learned,
        ..TrackSettings::default()
    };
    let t = tracker(
        Constructor::Bayesian,
        Some([2.0, 1.0, 4.0]),
        settings.clone(),
    );
    assert_eq!(t.alpha, vec![0.5, 1.0, 0.25]);
    let base = tiny_tracker(Constructor::Bayesian);
    let err = Tracker::new(base.model().clone(), settings.check().unwrap()).unwrap_err();
    assert!(err.to_string().contains("validation"), "{err}");
}

#[test]
fn rules_are_named_and_refused_where_they_cannot_run() {
    let err = toml::from_str::<TrackSettings>("rule = \"dempsterr\"").unwrap_err();
    for name in Rule::ALL.map(Rule::name) {
        assert!(err.to_string().contains(name), "{err}");
    }
    let parsed: TrackSettings =
        toml::from_str("rule = \"pcr6\"\ndiscount = \"learned\"\ncombine = \"all\"").unwrap();
    assert_eq!(
        (parsed.rule, parsed.discount, parsed.combine),
        (Rule::Pcr6, Discount::Learned, Combine::All)
    );
    let parsed: TrackSettings = toml::from_str("discount = 1").unwrap();
    assert_eq!(parsed.discount, Discount::Fixed(1.0));
    let err = toml::from_str::<TrackSettings>("discount = \"some\"").unwrap_err();
    assert!(err.to_string().contains("learned"), "{err}");
    let check = |s: TrackSettings| s.check().map(|_| ()).unwrap_err().to_string();
    let d = TrackSettings::default;
    assert!(check(TrackSettings {
        discount: Discount::Fixed(1.5),
        ..d()
    })
    .contains("[0, 1]"));
    assert!(check(TrackSettings {
        rule: Rule::Cautious,
        ..d()
    })
    .contains("dogmatic"));
    assert!(check(TrackSettings {
        combine: Combine::All,
        selection: SelectionPolicy::LowestConflict { min_size: 2 },
        ..d()
    })
    .contains("selection"));
    assert!(check(TrackSettings {
        rule: Rule::Yager,
        selection: SelectionPolicy::Splitting { min_size: 2 },
        ..d()
    })
    .contains("splitting"));
    // Defaults leave the file as it was.
    let json = serde_json::to_string(&d()).unwrap();
    assert!(
        !json.contains("rule") && !json.contains("discount"),
        "{json}"
    );
}

#[test]
fn rules_beyond_their_bounds_are_refused_when_the_tracker_is_built() {
    // 8 features of 4 states: 5⁸ tuples; 32 poses in more cells than the cautious rule takes.
    let poses: Vec<[f64; 2]> = (0..32).map(|i| [i as f64, 0.0]).collect();
    let features: Vec<TrackedFeature> = (0..8)
        .map(|k| {
            let a: Vec<usize> = (0..32).map(|i| (i / (k % 3 + 1) + k) % 4).collect();
            TrackedFeature {
                refining: Refining::from_assignment(4, &a).unwrap(),
                validation_error: None,
            }
        })
        .collect();
    let model = TrackerModel::new(poses, features).unwrap();
    for (rule, discount, says) in [
        (Rule::Pcr6, Discount::None, "tuple"),
        (Rule::DuboisPrade, Discount::None, "tuple"),
        (Rule::Cautious, Discount::Fixed(0.9), "cells"),
    ] {
        let s = TrackSettings {
            rule,
            discount,
            ..TrackSettings::default()
        };
        let err = Tracker::new(model.clone(), s.check().unwrap()).unwrap_err();
        assert!(err.to_string().contains(says), "{err}");
    }
}

#[test]
fn the_general_rules_give_estimates_on_small_frames() {
    for rule in [Rule::DuboisPrade, Rule::Pcr6, Rule::Cautious, Rule::Yager] {
        let settings = TrackSettings {
            rule,
            discount: Discount::Fixed(0.9),
            combine: Combine::All,
            ..TrackSettings::default()
        };
        let t = tracker(Constructor::Consonant, None, settings);
        for lik in frames() {
            let est = t.track(&lik).unwrap();
            let e = est
                .estimate
                .unwrap_or_else(|| panic!("{rule:?} {lik:?}: {est:?}"));
            assert!((0.0..=5.0).contains(&e[0]), "{rule:?}: {e:?}");
            let sum: f64 = est.plausibility.iter().sum();
            assert!((sum - 1.0).abs() < 1e-12);
        }
    }
}

#[test]
fn the_past_joins_every_feature_combined_by_the_rule() {
    // The carried contour multiplies the frame's rule-combined relative plausibility.
    let carried = [0.25, 0.25, 0.25, 0.25, 1.0, 1.0];
    for rule in [Rule::Yager, Rule::Murphy, Rule::Disjunctive, Rule::Pcr6] {
        let settings = TrackSettings {
            rule,
            combine: Combine::All,
            ..TrackSettings::default()
        };
        let t = tracker(Constructor::Bayesian, None, settings);
        let lik = &frames()[0];
        let alone = t.track(lik).unwrap();
        let with = t.track_with_past(lik, &carried, 1.0, false).unwrap();
        assert!(with.past_joined, "{rule:?}");
        assert_eq!(with.frame.group, vec![0, 1, 2]);
        let total: f64 = alone
            .plausibility
            .iter()
            .zip(&carried)
            .map(|(p, c)| p * c)
            .sum();
        for (k, w) in with.frame.plausibility.iter().enumerate() {
            let expected = alone.plausibility[k] * carried[k] / total;
            assert!((w - expected).abs() < 1e-12, "{rule:?} pose {k}");
        }
    }
}
