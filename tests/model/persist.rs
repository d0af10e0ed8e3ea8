//! Removed states and model files: saving, loading bit for bit, wrong versions and corruption.

use super::*;

#[test]
fn unused_state_is_removed_and_recorded() {
    let (poses, f) = model_with_removed_state();
    assert_eq!(f.hmm().n_states(), 3);
    assert_eq!(f.frame_size(), 2);
    assert_eq!(f.kept_states(), &[0, 1]);
    assert_eq!(f.removed_states(), &[2]);
    assert_eq!(f.block_sizes(), vec![4, 6]);
    assert_eq!(f.assignment(), &[0, 0, 0, 0, 1, 1, 1, 1, 1, 1]);
    // Likelihoods cover the kept states only, even for a value nearest the removed state.
    assert_eq!(f.likelihoods(Some(999.0)).unwrap().len(), 2);
    let summary = f.summary();
    assert_eq!(summary.states, 2);
    assert_eq!(summary.requested_states, 3);
    assert!(summary.to_string().contains("removed states [2]"));
    // Removed states survive a save/load round trip.
    let model = complete(FeatureFrames::from_features(poses, vec![f.clone()]).unwrap());
    let back = EvidentialModel::from_json(&model.to_json().unwrap()).unwrap();
    assert_eq!(back.frames().features()[0].removed_states(), &[2]);
    assert_eq!(back.frames().features()[0].refining(), f.refining());
}

#[test]
fn removed_states_that_disagree_with_assignments_are_rejected_on_load() {
    let (poses, f) = model_with_removed_state();
    let model = complete(FeatureFrames::from_features(poses, vec![f]).unwrap());
    let text = model.to_json().unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let mut v2 = v.clone();
    v2["features"][0]["removed_states"] = serde_json::json!([]);
    let err = EvidentialModel::from_json(&v2.to_string()).unwrap_err();
    assert!(err.to_string().contains("removed_states"), "{err}");
    let mut v3 = v;
    v3["features"][0]["states"][0] = serde_json::json!(7);
    let err = EvidentialModel::from_json(&v3.to_string()).unwrap_err();
    assert!(matches!(err, ModelFileError::Corrupted(_)), "{err}");
}

#[test]
fn save_load_round_trip() {
    let poses = mesh();
    let (names, mut rows) = smooth_features(&poses, 6);
    rows[5][1] = None;
    let frames = FeatureFrames::train(&poses, &names, &rows, &ModelSettings::default()).unwrap();
    let model = EvidentialModel::new(ModelParts {
        frames,
        feature_config: None,
        track: TrackSettings {
            conflict_threshold: ConflictLevel::Finite(0.35),
            ..TrackSettings::default()
        },
        threshold_learned: true,
        validation_errors: Some(vec![0.1, 0.2, 0.3, 0.4]),
        group_errors: vec![GroupError {
            features: vec![0, 2],
            error: 0.25,
        }],
        provenance: Provenance::new(Some("round-trip".into()), 9),
    })
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.json");
    model.save(&path).unwrap();
    let back = EvidentialModel::load(&path).unwrap();
    assert_eq!(
        back.track_settings().conflict_threshold,
        ConflictLevel::Finite(0.35)
    );
    assert!(back.threshold_learned());
    assert_eq!(back.validation_errors(), Some(&[0.1, 0.2, 0.3, 0.4][..]));
    assert_eq!(back.group_errors(), model.group_errors());
    assert_eq!(back.provenance(), model.provenance());
    assert_eq!(back.provenance().seed, 9);
    // serde_json without its `float_roundtrip` feature may parse a number 1 ulp away from the
    // value written, so floats are compared to 1e-15 relative; everything else exactly.
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * a.abs().max(b.abs());
    let close_all =
        |a: &[f64], b: &[f64]| a.len() == b.len() && a.iter().zip(b).all(|(x, y)| close(*x, *y));
    for (a, b) in model
        .frames()
        .features()
        .iter()
        .zip(back.frames().features())
    {
        assert_eq!(a.name(), b.name());
        assert_eq!(a.requested_states(), b.requested_states());
        assert_eq!(a.n_observations(), b.n_observations());
        assert_eq!(a.hmm_states(), b.hmm_states());
        assert_eq!(a.kept_states(), b.kept_states());
        assert_eq!(a.removed_states(), b.removed_states());
        assert_eq!(a.refining(), b.refining());
        assert_eq!(a.imputed(), b.imputed());
        assert!(close(a.log_likelihood(), b.log_likelihood()));
        let (ha, hb) = (a.hmm(), b.hmm());
        assert!(close_all(ha.means(), hb.means()));
        assert!(close_all(ha.variances(), hb.variances()));
        assert!(close_all(ha.initial(), hb.initial()));
        for (ra, rb) in ha.transitions().iter().zip(hb.transitions()) {
            assert!(close_all(ra, rb));
        }
    }
    assert_eq!(back.sample_poses(), model.sample_poses());
    // Saving the loaded model again gives a file that loads to the same model.
    let path2 = dir.path().join("again.json");
    back.save(&path2).unwrap();
    assert_eq!(EvidentialModel::load(&path2).unwrap(), back);
    // The file states its format version.
    let text = std::fs::read_to_string(&path).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["format_version"], FORMAT_VERSION);
}

#[test]
fn wrong_version_or_corrupted_file_is_a_clear_error() {
    let poses = mesh();
    let (names, rows) = smooth_features(&poses, 7);
    let model =
        complete(FeatureFrames::train(&poses, &names, &rows, &ModelSettings::default()).unwrap());
    let text = model.to_json().unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();

    // A version-1 file (before models were self-contained) is named as such.
    let mut old = v.clone();
    old["format_version"] = serde_json::json!(1);
    let err = EvidentialModel::from_json(&old.to_string()).unwrap_err();
    assert!(
        err.to_string()
            .contains("format version 1 is not supported")
            && err
                .to_string()
                .contains(&format!("version {FORMAT_VERSION}")),
        "{err}"
    );
    // A file of another method names the method.
    let mut foreign = v.clone();
    foreign["method"] = serde_json::json!("knn");
    let err = EvidentialModel::from_json(&foreign.to_string()).unwrap_err();
    assert!(matches!(err, ModelFileError::WrongMethod { .. }), "{err}");
    assert!(err.to_string().contains("`knn`"), "{err}");
    // A threshold that is not a level of conflict.
    let mut negative = v.clone();
    negative["track"]["conflict_threshold"] = serde_json::json!(-0.5);
    let err = EvidentialModel::from_json(&negative.to_string()).unwrap_err();
    assert!(err.to_string().contains("conflict_threshold"), "{err}");

    let mut future = v.clone();
    future["format_version"] = serde_json::json!(FORMAT_VERSION + 1);
    match EvidentialModel::from_json(&future.to_string()) {
        Err(ModelFileError::UnsupportedVersion { found, supported }) => {
            assert_eq!(found, (FORMAT_VERSION + 1).to_string());
            assert_eq!(supported, FORMAT_VERSION);
        }
        other => panic!("expected UnsupportedVersion, got {other:?}"),
    }
    let mut no_version = v.clone();
    no_version.as_object_mut().unwrap().remove("format_version");
    assert!(matches!(
        EvidentialModel::from_json(&no_version.to_string()),
        Err(ModelFileError::MissingVersion {
            expected: FORMAT_VERSION
        })
    ));
    // Truncated file.
    let err = EvidentialModel::from_json(&text[..text.len() / 2]).unwrap_err();
    assert!(matches!(err, ModelFileError::Corrupted(_)), "{err}");
    // A negative variance is caught by HMM validation.
    let mut neg = v.clone();
    neg["features"][1]["hmm"]["variances"][0] = serde_json::json!(-1.0);
    let err = EvidentialModel::from_json(&neg.to_string()).unwrap_err();
    assert!(err.to_string().contains("variance of state 0"), "{err}");
    // Fewer states than sample poses.
    let mut short = v.clone();
    short["features"][0]["states"].as_array_mut().unwrap().pop();
    let err = EvidentialModel::from_json(&short.to_string()).unwrap_err();
    assert!(
        err.to_string().contains("399 states for 400 sample poses"),
        "{err}"
    );
    // Unknown field.
    let mut extra = v.clone();
    extra["features"][0]["colour"] = serde_json::json!("red");
    let err = EvidentialModel::from_json(&extra.to_string()).unwrap_err();
    assert!(err.to_string().contains("colour"), "{err}");
    // Through load(): the error names the file.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("broken.json");
    std::fs::write(&path, "{\"format_version\": 1, \"sample_poses\": [").unwrap();
    let err = EvidentialModel::load(&path).unwrap_err();
    assert!(err.to_string().contains("broken.json"), "{err}");
    assert!(matches!(
        EvidentialModel::load(dir.path().join("absent.json")),
        Err(ModelFileError::Io { .. })
    ));
}
