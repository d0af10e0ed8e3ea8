//! Evidential model: training on a mesh, refinings, removed states, tuning, persistence.

use evitrack::evidence::ConflictLevel;
use evitrack::evidence::Subset;
use evitrack::hmm::{AssignmentRule, GaussianHmm, HmmSettings};
use evitrack::model::{
    EvidentialModel, FeatureFrames, FeatureModel, ModelError, ModelParts, ModelSettings,
    StateCountTuner, StateCounts, TunerError, Tuning, FORMAT_VERSION,
};
use evitrack::model_file::{ModelFileError, Provenance};
use evitrack::track::{GroupError, TrackSettings};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

mod persist;

/// A complete model of trained frames, with default tracker settings and no validation.
fn complete(frames: FeatureFrames) -> EvidentialModel {
    EvidentialModel::new(ModelParts {
        frames,
        feature_config: None,
        track: TrackSettings::default(),
        threshold_learned: false,
        validation_errors: None,
        group_errors: Vec::new(),
        provenance: Provenance::new(Some("test".into()), 1),
    })
    .unwrap()
}

/// 20 × 20 mesh over the workspace, visited in serpentine order.
fn mesh() -> Vec<[f64; 2]> {
    let mut poses = Vec::with_capacity(400);
    for r in 0..20 {
        for c in 0..20 {
            let c = if r % 2 == 0 { c } else { 19 - c };
            poses.push([-9.5 + c as f64, 38.0 + r as f64]);
        }
    }
    poses
}

/// Smooth features of the pose, with a little measurement noise.
fn smooth_features(poses: &[[f64; 2]], seed: u64) -> (Vec<String>, Vec<Vec<Option<f64>>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.01).unwrap();
    let fields: [fn(f64, f64) -> f64; 4] = [
        |x, _| x,
        |_, y| 0.1 * y,
        |x, y| (x / 4.0).sin() + (y / 5.0).cos(),
        |x, y| (x * x + (y - 47.5).powi(2)).sqrt(),
    ];
    let names = (0..fields.len()).map(|i| format!("f{i}")).collect();
    let rows = poses
        .iter()
        .map(|&[x, y]| {
            fields
                .iter()
                .map(|f| Some(f(x, y) + noise.sample(&mut rng)))
                .collect()
        })
        .collect();
    (names, rows)
}

fn assert_partition(blocks: &[Subset], n: usize) {
    let mut seen = vec![0usize; n];
    for b in blocks {
        assert!(!b.is_empty(), "empty block");
        for e in b.iter() {
            seen[e] += 1;
        }
    }
    assert!(
        seen.iter().all(|&c| c == 1),
        "blocks overlap or miss a pose"
    );
}

#[test]
fn smooth_field_on_mesh_gives_covering_disjoint_refinings() {
    let poses = mesh();
    let (names, rows) = smooth_features(&poses, 1);
    let settings = ModelSettings::default();
    let model = FeatureFrames::train(&poses, &names, &rows, &settings).unwrap();
    assert_eq!(model.n_features(), 4);
    assert_eq!(model.sample_poses(), &poses[..]);
    for (i, f) in model.features().iter().enumerate() {
        assert_eq!(f.name(), names[i]);
        assert_eq!(f.requested_states(), 3);
        let refining = f.refining();
        assert_eq!(refining.fine_size(), 400);
        assert_eq!(refining.coarse_size(), f.frame_size());
        assert!(f.frame_size() >= 2, "feature {i} collapsed to one state");
        assert_partition(refining.blocks(), 400);
        assert_eq!(f.block_sizes().iter().sum::<usize>(), 400);
        assert_eq!(f.imputed(), &[] as &[usize]);
        assert_eq!(f.n_observations(), 400);
        assert!(f.log_likelihood().is_finite());
        // Each sample pose lies in the block of the frame element with the largest Γ of its
        // own value (the paper's rule, §3.3).
        for (s, row) in rows.iter().enumerate() {
            let gamma = f.likelihoods(row[i]).unwrap();
            assert_eq!(gamma.len(), f.frame_size());
            let best = (0..gamma.len())
                .max_by(|&a, &b| gamma[a].total_cmp(&gamma[b]))
                .unwrap();
            assert_eq!(gamma[best], 1.0);
            assert!(gamma.iter().all(|g| (0.0..=1.0).contains(g)));
            assert_eq!(f.assignment()[s], best, "feature {i}, sample {s}");
            assert!(refining.blocks()[best].contains(s));
        }
    }
    // The first feature is the x coordinate: its blocks are bands of x.
    let f0 = &model.features()[0];
    let mut bands: Vec<(f64, f64)> = f0
        .refining()
        .blocks()
        .iter()
        .map(|b| {
            let xs: Vec<f64> = b.iter().map(|s| poses[s][0]).collect();
            (
                xs.iter().copied().fold(f64::INFINITY, f64::min),
                xs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            )
        })
        .collect();
    bands.sort_by(|a, b| a.0.total_cmp(&b.0));
    for w in bands.windows(2) {
        assert!(w[0].1 < w[1].0, "x bands overlap: {bands:?}");
    }
    // Same data and seed → identical model.
    let again = FeatureFrames::train(&poses, &names, &rows, &settings).unwrap();
    assert_eq!(model, again);
}

#[test]
fn per_frame_likelihoods_follow_the_feature_vector() {
    let poses = mesh();
    let (names, rows) = smooth_features(&poses, 2);
    let model = FeatureFrames::train(&poses, &names, &rows, &ModelSettings::default()).unwrap();
    let out = model
        .likelihoods(&[Some(0.0), None, Some(f64::NAN), Some(1e9)])
        .unwrap();
    assert_eq!(out.len(), 4);
    assert_eq!(
        out[0].as_ref().unwrap().len(),
        model.features()[0].frame_size()
    );
    assert!(out[1].is_none());
    assert!(out[2].is_none());
    // A far outlier still gives usable relative likelihoods (no underflow to all zeros).
    let far = out[3].as_ref().unwrap();
    assert!(far.iter().all(|g| g.is_finite()));
    assert_eq!(far.iter().copied().fold(0.0, f64::max), 1.0);
    assert!(matches!(
        model.likelihoods(&[Some(0.0)]),
        Err(ModelError::InvalidInput { .. })
    ));
    let logs = model.features()[0].log_likelihoods(Some(0.0)).unwrap();
    let rel = model.features()[0].likelihoods(Some(0.0)).unwrap();
    let max = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    for (l, r) in logs.iter().zip(&rel) {
        assert!(((l - max).exp() - r).abs() < 1e-15);
    }
}

#[test]
fn missing_values_take_the_state_of_the_nearest_pose() {
    let poses = mesh();
    let (names, mut rows) = smooth_features(&poses, 3);
    let missing = [0usize, 57, 58, 210, 399];
    for &s in &missing {
        rows[s][0] = None;
    }
    rows[100][0] = Some(f64::INFINITY);
    let model = FeatureFrames::train(&poses, &names, &rows, &ModelSettings::default()).unwrap();
    let f = &model.features()[0];
    let mut expected: Vec<usize> = missing.to_vec();
    expected.push(100);
    expected.sort();
    assert_eq!(f.imputed(), &expected[..]);
    assert_eq!(f.n_observations(), 400 - expected.len());
    assert_partition(f.refining().blocks(), 400);
    for &s in &expected {
        // Nearest pose with a value: mesh spacing is 1, so some neighbour at distance 1.
        let q = poses[s];
        let nearest = (0..400)
            .filter(|i| !expected.contains(i))
            .min_by(|&a, &b| {
                let da = (poses[a][0] - q[0]).powi(2) + (poses[a][1] - q[1]).powi(2);
                let db = (poses[b][0] - q[0]).powi(2) + (poses[b][1] - q[1]).powi(2);
                da.total_cmp(&db)
            })
            .unwrap();
        assert_eq!(f.assignment()[s], f.assignment()[nearest], "sample {s}");
    }
    // Other features are untouched.
    assert!(model.features()[1].imputed().is_empty());
    assert!(model.summary()[0]
        .to_string()
        .contains("6 missing values imputed"));
}

#[test]
fn feature_without_values_is_an_error() {
    let poses = mesh();
    let (names, mut rows) = smooth_features(&poses, 4);
    for r in &mut rows {
        r[2] = None;
    }
    match FeatureFrames::train(&poses, &names, &rows, &ModelSettings::default()) {
        Err(ModelError::NoValues { feature }) => assert_eq!(feature, "f2"),
        other => panic!("expected NoValues, got {other:?}"),
    }
}

#[test]
fn malformed_training_input_is_an_error() {
    let poses = mesh();
    let (names, rows) = smooth_features(&poses, 5);
    let s = ModelSettings::default();
    assert!(matches!(
        FeatureFrames::train(&poses[..399], &names, &rows, &s),
        Err(ModelError::RowCount {
            rows: 400,
            poses: 399
        })
    ));
    let mut short = rows.clone();
    short[7].pop();
    assert!(matches!(
        FeatureFrames::train(&poses, &names, &short, &s),
        Err(ModelError::RowLength {
            row: 7,
            expected: 4,
            got: 3
        })
    ));
    let mut dup = names.clone();
    dup[3] = "f0".into();
    assert!(matches!(
        FeatureFrames::train(&poses, &dup, &rows, &s),
        Err(ModelError::DuplicateFeature(n)) if n == "f0"
    ));
    let mut bad_poses = poses.clone();
    bad_poses[12][1] = f64::NAN;
    assert!(matches!(
        FeatureFrames::train(&bad_poses, &names, &rows, &s),
        Err(ModelError::NonFinitePose { index: 12, .. })
    ));
    assert!(matches!(
        FeatureFrames::train(&[], &names, &[], &s),
        Err(ModelError::NoSamples)
    ));
    assert!(matches!(
        FeatureFrames::train(&poses, &[], &vec![vec![]; 400], &s),
        Err(ModelError::NoFeatures)
    ));
    let wrong_counts = ModelSettings {
        states: StateCounts::PerFeature(vec![2, 3]),
        ..Default::default()
    };
    assert!(matches!(
        FeatureFrames::train(&poses, &names, &rows, &wrong_counts),
        Err(ModelError::Settings {
            field: "states",
            ..
        })
    ));
}

#[test]
fn bic_picks_more_states_for_a_multimodal_feature() {
    let poses = mesh();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let noise = Normal::new(0.0, 0.3).unwrap();
    // Multi-modal: four well-separated levels by band of x. Unimodal: i.i.d. Gaussian noise.
    let rows: Vec<Vec<Option<f64>>> = poses
        .iter()
        .map(|&[x, _]| {
            let level = ((x + 10.0) / 5.0).floor();
            vec![
                Some(5.0 * level + noise.sample(&mut rng)),
                Some(noise.sample(&mut rng)),
            ]
        })
        .collect();
    let names = vec!["levels".to_string(), "noise".to_string()];
    let settings = ModelSettings {
        tuning: Tuning::Bic {
            min_states: StateCounts::All(1),
            max_states: StateCounts::All(6),
        },
        ..Default::default()
    };
    let model = FeatureFrames::train(&poses, &names, &rows, &settings).unwrap();
    let multi = &model.features()[0];
    let uni = &model.features()[1];
    assert_eq!(multi.requested_states(), 4);
    assert_eq!(multi.frame_size(), 4);
    assert_eq!(multi.block_sizes(), vec![100; 4]);
    assert!(uni.requested_states() <= 2, "{}", uni.requested_states());
    assert!(multi.requested_states() > uni.requested_states());
    // The chosen count has the lowest BIC among the candidates.
    for n in 1..=6 {
        let given = ModelSettings {
            states: StateCounts::All(n),
            ..Default::default()
        };
        let m = FeatureFrames::train(&poses, &names, &rows, &given).unwrap();
        assert!(m.features()[0].bic() >= multi.bic() - 1e-9);
        assert!(m.features()[1].bic() >= uni.bic() - 1e-9);
    }
}

/// Prefers a fixed count: stands in for the tracker's validation error.
struct PreferCount(usize, Vec<(usize, usize)>);

impl StateCountTuner for PreferCount {
    fn score(
        &mut self,
        feature: usize,
        candidate: &FeatureModel,
        sample_poses: &[[f64; 2]],
    ) -> Result<f64, TunerError> {
        assert_eq!(sample_poses.len(), candidate.assignment().len());
        self.1.push((feature, candidate.requested_states()));
        Ok((candidate.requested_states() as f64 - self.0 as f64).abs())
    }
}

#[test]
fn validation_tuning_goes_through_the_tuner_hook() {
    let poses = mesh();
    let (names, rows) = smooth_features(&poses, 10);
    let settings = ModelSettings {
        tuning: Tuning::Validation {
            min_states: StateCounts::All(2),
            max_states: StateCounts::PerFeature(vec![4, 4, 5, 5]),
        },
        ..Default::default()
    };
    assert!(matches!(
        FeatureFrames::train(&poses, &names, &rows, &settings),
        Err(ModelError::TunerRequired)
    ));
    let mut tuner = PreferCount(3, Vec::new());
    let model =
        FeatureFrames::train_with_tuner(&poses, &names, &rows, &settings, &mut tuner).unwrap();
    assert!(model.features().iter().all(|f| f.requested_states() == 3));
    assert_eq!(
        tuner.1,
        vec![
            (0, 2),
            (0, 3),
            (0, 4),
            (1, 2),
            (1, 3),
            (1, 4),
            (2, 2),
            (2, 3),
            (2, 4),
            (2, 5),
            (3, 2),
            (3, 3),
            (3, 4),
            (3, 5)
        ]
    );
    // The tuned count gives the same model as asking for that count directly.
    let given = ModelSettings {
        states: StateCounts::All(3),
        ..Default::default()
    };
    let direct = FeatureFrames::train(&poses, &names, &rows, &given).unwrap();
    assert_eq!(model, direct);

    struct Failing;
    impl StateCountTuner for Failing {
        fn score(&mut self, _: usize, _: &FeatureModel, _: &[[f64; 2]]) -> Result<f64, TunerError> {
            Err("tracker diverged".into())
        }
    }
    let err = FeatureFrames::train_with_tuner(&poses, &names, &rows, &settings, &mut Failing)
        .unwrap_err();
    assert!(err.to_string().contains("tracker diverged"), "{err}");

    struct NotANumber;
    impl StateCountTuner for NotANumber {
        fn score(&mut self, _: usize, _: &FeatureModel, _: &[[f64; 2]]) -> Result<f64, TunerError> {
            Ok(f64::NAN)
        }
    }
    let err = FeatureFrames::train_with_tuner(&poses, &names, &rows, &settings, &mut NotANumber)
        .unwrap_err();
    assert!(
        matches!(&err, ModelError::Tuner { feature, states: 2, .. } if feature == "f0"),
        "{err}"
    );
    assert!(err.to_string().contains("not finite"), "{err}");
}

#[test]
fn settings_from_toml() {
    let s: ModelSettings = toml::from_str(
        r#"
        states = [2, 3, 4]
        seed = 7
        [hmm]
        restarts = 2
        assignment = "viterbi"
        [tuning]
        method = "bic"
        min_states = 1
        max_states = [3, 4, 5]
        "#,
    )
    .unwrap();
    assert_eq!(s.states, StateCounts::PerFeature(vec![2, 3, 4]));
    assert_eq!(s.seed, 7);
    assert_eq!(
        s.hmm,
        HmmSettings {
            restarts: 2,
            assignment: AssignmentRule::Viterbi,
            ..Default::default()
        }
    );
    assert_eq!(
        s.tuning,
        Tuning::Bic {
            min_states: StateCounts::All(1),
            max_states: StateCounts::PerFeature(vec![3, 4, 5])
        }
    );
    assert!(s.check().is_ok());
    assert!(toml::from_str::<ModelSettings>("state = 3").is_err());
    assert!(toml::from_str::<ModelSettings>(
        "[tuning]\nmethod = \"bic\"\nmin_states = 1\nmax_states = 2\nmaximum = 3"
    )
    .is_err());
    assert!(toml::from_str::<ModelSettings>("[tuning]\nmethod = \"guess\"").is_err());
}

/// A hand-built HMM whose third state lies far from every value: no sample is assigned to it.
fn model_with_removed_state() -> (Vec<[f64; 2]>, FeatureModel) {
    let poses: Vec<[f64; 2]> = (0..10).map(|i| [i as f64, 0.0]).collect();
    let column: Vec<Option<f64>> = (0..10)
        .map(|i| {
            Some(if i < 4 {
                0.1 * i as f64
            } else {
                10.0 + 0.1 * i as f64
            })
        })
        .collect();
    let hmm = GaussianHmm::new(
        vec![0.5, 0.5, 0.0],
        vec![
            vec![0.8, 0.2, 0.0],
            vec![0.2, 0.8, 0.0],
            vec![0.0, 0.0, 1.0],
        ],
        vec![0.0, 10.0, 1000.0],
        vec![1.0, 1.0, 1.0],
    )
    .unwrap();
    let ll = hmm
        .log_likelihood(&column.iter().map(|v| v.unwrap()).collect::<Vec<_>>())
        .unwrap();
    let f = FeatureModel::from_hmm(
        "bimodal",
        3,
        hmm,
        ll,
        &column,
        &poses,
        AssignmentRule::MaxLikelihood,
    )
    .unwrap();
    (poses, f)
}

#[test]
fn a_complete_model_checks_its_parts() {
    let (poses, f) = model_with_removed_state();
    let frames = FeatureFrames::from_features(poses, vec![f]).unwrap();
    let parts = |validation_errors, track| ModelParts {
        frames: frames.clone(),
        feature_config: None,
        track,
        threshold_learned: false,
        validation_errors,
        group_errors: Vec::new(),
        provenance: Provenance::new(None, 0),
    };
    let bad_threshold = TrackSettings {
        conflict_threshold: ConflictLevel::Finite(-0.1),
        ..TrackSettings::default()
    };
    assert!(EvidentialModel::new(parts(None, bad_threshold)).is_err());
    let ok = TrackSettings::default();
    assert!(EvidentialModel::new(parts(Some(vec![0.1, 0.2]), ok.clone())).is_err());
    assert!(EvidentialModel::new(parts(Some(vec![f64::INFINITY]), ok.clone())).is_err());
    let model = EvidentialModel::new(parts(Some(vec![0.5]), ok)).unwrap();
    assert_eq!(model.validation_errors(), Some(&[0.5][..]));
    // A feature configuration must name the model's features.
    let err = EvidentialModel::new(ModelParts {
        feature_config: Some(evitrack::features::FeatureConfig::default()),
        ..model.parts().clone()
    })
    .unwrap_err();
    assert!(err.to_string().contains("size_line0"), "{err}");
    // Group errors must name existing features, ascending, with a finite error.
    for (features, error) in [(vec![0, 1], 0.5), (vec![], 0.5), (vec![0], f64::NAN)] {
        let err = EvidentialModel::new(ModelParts {
            group_errors: vec![GroupError { features, error }],
            ..model.parts().clone()
        })
        .unwrap_err();
        assert!(err.to_string().contains("group errors"), "{err}");
    }
}

/// Issue 14: whether each feature's EM met its stopping rule reaches the training summary (what
/// `evitrack train` prints as a note), and a loaded model does not claim to know.
#[test]
fn training_summary_reports_em_that_hit_its_iteration_cap() {
    let poses = mesh();
    let (names, rows) = smooth_features(&poses, 3);
    let summary = |settings: &ModelSettings| -> Vec<Option<bool>> {
        let frames = FeatureFrames::train(&poses, &names, &rows, settings).unwrap();
        frames.summary().iter().map(|s| s.em_converged).collect()
    };
    let capped = ModelSettings {
        hmm: evitrack::hmm::HmmSettings {
            max_iterations: 1,
            tolerance: 0.0,
            ..Default::default()
        },
        ..ModelSettings::default()
    };
    assert!(summary(&capped).iter().all(|c| *c == Some(false)));
    assert!(summary(&ModelSettings::default())
        .iter()
        .all(|c| *c == Some(true)));
    let model =
        complete(FeatureFrames::train(&poses, &names, &rows, &ModelSettings::default()).unwrap());
    let back = EvidentialModel::from_json(&model.to_json().unwrap()).unwrap();
    assert!(back
        .frames()
        .summary()
        .iter()
        .all(|s| s.em_converged.is_none()));
}
