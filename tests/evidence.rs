//! Integration tests of the evidence algebra through the public API: the `combine` exchange
//! format, and a measurement → refining → combination → estimate round trip.

use evitrack::evidence::{
    combine_json, contour_product, dempster_all, from_likelihoods, pointwise_estimate,
    relative_plausibility, Constructor, EvidenceError, MassFunction, Refining, Subset,
};

fn bad_input(text: &str) -> (usize, Option<usize>, String) {
    match combine_json(text) {
        Err(EvidenceError::BadInput {
            mass_function,
            focal_set,
            reason,
        }) => (mass_function, focal_set, reason),
        other => panic!("expected BadInput, got {other:?}"),
    }
}

#[test]
fn combine_json_names_the_mass_function_and_focal_set_at_fault() {
    let (mf, fs, why) = bad_input(
        r#"{"frame": 400, "rule": "dempster", "mass_functions": [
            {"focal": [[0, 5, 7], [1, 2]], "mass": [0.6, 0.4]},
            {"focal": [[3], [1, 400]], "mass": [0.5, 0.5]}]}"#,
    );
    assert_eq!((mf, fs), (1, Some(1)));
    assert!(why.contains("400"), "{why}");

    let (mf, fs, _) = bad_input(
        r#"{"frame": 4, "rule": "dempster", "mass_functions": [
            {"focal": [[0], []], "mass": [0.6, 0.4]}]}"#,
    );
    assert_eq!((mf, fs), (0, Some(1)));

    let (mf, fs, why) = bad_input(
        r#"{"frame": 4, "rule": "conjunctive", "mass_functions": [
            {"focal": [[0]], "mass": [1.0]},
            {"focal": [[0], [1]], "mass": [0.6, 0.3]}]}"#,
    );
    assert_eq!((mf, fs), (1, None));
    assert!(why.contains("sum"), "{why}");

    let (mf, fs, _) = bad_input(
        r#"{"frame": 4, "rule": "dempster", "mass_functions": [
            {"focal": [[0], [1]], "mass": [1.5, -0.5]}]}"#,
    );
    assert_eq!((mf, fs), (0, Some(1)));

    let (mf, fs, _) = bad_input(
        r#"{"frame": 4, "rule": "dempster", "mass_functions": [
            {"focal": [[0], [1]], "mass": [1.0]}]}"#,
    );
    assert_eq!((mf, fs), (0, None));
}

#[test]
fn combine_json_rejects_unknown_fields_and_bad_shapes() {
    let e = combine_json(r#"{"frame": 4, "rule": "dempster", "mass_functions": [], "extra": 1}"#)
        .unwrap_err();
    assert!(
        matches!(&e, EvidenceError::Json(m) if m.contains("extra") && m.contains("line")),
        "{e}"
    );
    let e = combine_json(
        r#"{"frame": 4, "rule": "dempster", "mass_functions": [{"focal": [[0]], "mass": [1.0], "weight": 2}]}"#,
    )
    .unwrap_err();
    assert!(
        matches!(&e, EvidenceError::Json(m) if m.contains("weight")),
        "{e}"
    );
    let e = combine_json(r#"{"frame": 4, "rule": "smets", "mass_functions": []}"#).unwrap_err();
    assert!(
        matches!(&e, EvidenceError::Json(m) if m.contains("dubois_prade")),
        "the valid rules are listed: {e}"
    );
    assert_eq!(
        combine_json(r#"{"frame": 4, "rule": "dempster", "mass_functions": []}"#),
        Err(EvidenceError::NothingToCombine)
    );
    assert_eq!(
        combine_json(
            r#"{"frame": 0, "rule": "dempster", "mass_functions": [{"focal": [[0]], "mass": [1.0]}]}"#
        ),
        Err(EvidenceError::EmptyFrame)
    );
    // A frame size read from a file cannot make us allocate terabytes.
    assert!(matches!(
        combine_json(
            r#"{"frame": 1000000000000, "rule": "dempster", "mass_functions": [{"focal": [[0]], "mass": [1.0]}]}"#
        ),
        Err(EvidenceError::FrameTooLarge { .. })
    ));
}

#[test]
fn combine_json_output_has_the_exchange_shape() {
    let r = combine_json(
        r#"{"frame": 5, "rule": "conjunctive", "mass_functions": [
            {"focal": [[0, 1], [2, 3, 4]], "mass": [0.5, 0.5]},
            {"focal": [[1, 2]], "mass": [1.0]}]}"#,
    )
    .unwrap();
    let v = serde_json::to_value(&r).unwrap();
    let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
    let mut keys = keys;
    keys.sort_unstable();
    assert_eq!(
        keys,
        [
            "conflict_level",
            "conflict_mass",
            "focal",
            "mass",
            "plausibility"
        ]
    );
    // {0,1}∩{1,2} = {1}, {2,3,4}∩{1,2} = {2}: no conflict, equal masses, sorted by elements.
    assert_eq!(r.focal, vec![vec![1], vec![2]]);
    assert_eq!(r.mass, vec![0.5, 0.5]);
    assert_eq!(r.conflict_mass, 0.0);
    assert_eq!(r.plausibility, vec![0.0, 0.5, 0.5, 0.0, 0.0]);
    assert_eq!(v["conflict_level"], 0.0);
}

#[test]
fn measurement_refining_combination_estimate_round_trip() {
    // Fine frame: 6 points on a line; feature A splits {0,1,2}|{3,4,5}, feature B {0,1}|{2,3}|{4,5}.
    let points: Vec<[f64; 1]> = (0..6).map(|i| [i as f64]).collect();
    let ra = Refining::from_assignment(2, &[0, 0, 0, 1, 1, 1]).unwrap();
    let rb = Refining::from_assignment(3, &[0, 0, 1, 1, 2, 2]).unwrap();
    for c in [Constructor::Bayesian, Constructor::Consonant] {
        let a = from_likelihoods(c, &[1.0, 0.0]).unwrap().mass;
        let b = from_likelihoods(c, &[0.0, 1.0, 0.0]).unwrap().mass;
        let ea = ra.extend(&a).unwrap();
        let eb = rb.extend(&b).unwrap();
        let comb = dempster_all([&ea, &eb]).unwrap();
        assert_eq!(comb.conflict_level, 0.0);
        let m = comb.mass.unwrap();
        assert_eq!(m.focal_sets(), &[Subset::singleton(6, 2)]);
        let p = relative_plausibility(&m).unwrap();
        assert_eq!(pointwise_estimate(&p, &points).unwrap(), [2.0]);
        assert_eq!(contour_product([&ea, &eb]).unwrap().unwrap(), p);
    }
    // A NaN measurement is vacuous, flagged, and leaves the other evidence untouched.
    let nan = from_likelihoods(Constructor::Bayesian, &[f64::NAN, 1.0]).unwrap();
    assert!(nan.issue.is_some());
    let b = MassFunction::bayesian(&[0.2, 0.3, 0.5]).unwrap();
    let comb = dempster_all([&ra.extend(&nan.mass).unwrap(), &rb.extend(&b).unwrap()]).unwrap();
    assert_eq!(comb.conflict_level, 0.0);
    assert!(
        (comb
            .mass
            .unwrap()
            .plausibility(&Subset::from_indices(6, [4, 5]).unwrap())
            - 0.5)
            .abs()
            < 1e-15
    );
}
