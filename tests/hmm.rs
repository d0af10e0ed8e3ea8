//! Gaussian HMM: parameter recovery, EM monotonicity, long sequences, degenerate data.

use evitrack::hmm::{AssignmentRule, GaussianHmm, HmmError, HmmSettings};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Draws `n` observations (and their hidden states) from `hmm`.
fn sample(hmm: &GaussianHmm, n: usize, seed: u64) -> (Vec<f64>, Vec<usize>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let draw = |p: &[f64], rng: &mut ChaCha8Rng| {
        let mut r: f64 = rng.random();
        for (j, pj) in p.iter().enumerate() {
            if r < *pj {
                return j;
            }
            r -= pj;
        }
        p.len() - 1
    };
    let mut states = Vec::with_capacity(n);
    let mut ys = Vec::with_capacity(n);
    let mut s = draw(hmm.initial(), &mut rng);
    for _ in 0..n {
        let normal = Normal::new(hmm.means()[s], hmm.variances()[s].sqrt()).unwrap();
        ys.push(normal.sample(&mut rng));
        states.push(s);
        s = draw(&hmm.transitions()[s], &mut rng);
    }
    (ys, states)
}

fn known_hmm() -> GaussianHmm {
    GaussianHmm::new(
        vec![0.5, 0.3, 0.2],
        vec![
            vec![0.90, 0.08, 0.02],
            vec![0.05, 0.90, 0.05],
            vec![0.02, 0.08, 0.90],
        ],
        vec![-4.0, 0.0, 5.0],
        vec![1.0, 0.5, 2.0],
    )
    .unwrap()
}

#[test]
fn recovers_parameters_of_a_known_hmm() {
    let truth = known_hmm();
    let (ys, states) = sample(&truth, 5000, 11);
    let fit = GaussianHmm::fit(&ys, 3, &HmmSettings::default(), 5).unwrap();
    let hmm = &fit.hmm;
    assert_eq!(hmm.n_states(), 3);
    for j in 0..3 {
        assert!(
            (hmm.means()[j] - truth.means()[j]).abs() < 0.15,
            "mean {j}: {} vs {}",
            hmm.means()[j],
            truth.means()[j]
        );
        let rel = hmm.variances()[j] / truth.variances()[j];
        assert!((0.85..1.15).contains(&rel), "variance {j} ratio {rel}");
        for i in 0..3 {
            let d = (hmm.transitions()[j][i] - truth.transitions()[j][i]).abs();
            assert!(d < 0.03, "transition {j}->{i} off by {d}");
        }
    }
    assert!(fit.converged);
    // The fitted model explains the data at least as well as the truth (it is the ML estimate).
    let ll_truth = truth.log_likelihood(&ys).unwrap();
    assert!(fit.log_likelihood >= ll_truth - 1e-6);
    // Viterbi decodes almost all hidden states; the paper's rule a little fewer, as it ignores
    // the dynamics.
    let acc = |path: &[usize]| {
        path.iter().zip(&states).filter(|(a, b)| a == b).count() as f64 / states.len() as f64
    };
    let vit = acc(&hmm.assign(&ys, AssignmentRule::Viterbi).unwrap());
    let ml = acc(&hmm.assign(&ys, AssignmentRule::MaxLikelihood).unwrap());
    assert!(vit > 0.97, "viterbi accuracy {vit}");
    assert!(ml > 0.9, "max-likelihood accuracy {ml}");
    assert!(vit >= ml);
}

#[test]
fn em_log_likelihood_never_decreases_on_hmm_data() {
    let truth = known_hmm();
    for seed in 0..5 {
        let (ys, _) = sample(&truth, 400, 100 + seed);
        let settings = HmmSettings {
            tolerance: 0.0,
            max_iterations: 60,
            ..Default::default()
        };
        for k in 1..=5 {
            let fit = GaussianHmm::fit(&ys, k, &settings, seed).unwrap();
            assert!(fit.trace.len() >= 2);
            assert_eq!(fit.trace.len(), fit.iterations + 1);
            for w in fit.trace.windows(2) {
                assert!(w[1] >= w[0] - 1e-9 * w[0].abs(), "k={k}: {:?}", fit.trace);
            }
        }
    }
}

#[test]
fn same_seed_gives_bit_identical_fits() {
    let (ys, _) = sample(&known_hmm(), 300, 3);
    let a = GaussianHmm::fit(&ys, 4, &HmmSettings::default(), 42).unwrap();
    let b = GaussianHmm::fit(&ys, 4, &HmmSettings::default(), 42).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.log_likelihood.to_bits(), b.log_likelihood.to_bits());
}

#[test]
fn more_restarts_never_lower_the_likelihood() {
    let (ys, _) = sample(&known_hmm(), 300, 8);
    let one = HmmSettings {
        restarts: 1,
        ..Default::default()
    };
    let five = HmmSettings {
        restarts: 5,
        ..Default::default()
    };
    let a = GaussianHmm::fit(&ys, 4, &one, 9).unwrap();
    let b = GaussianHmm::fit(&ys, 4, &five, 9).unwrap();
    // The first restart draws the same initialisation in both, so the best of five is no worse.
    assert!(b.log_likelihood >= a.log_likelihood);
}

#[test]
fn long_sequence_with_outliers_stays_finite() {
    let (mut ys, _) = sample(&known_hmm(), 100_000, 21);
    // Far outliers would underflow every emission density without per-step normalisation.
    ys[500] = 1e6;
    ys[70_000] = -3e8;
    let settings = HmmSettings {
        max_iterations: 15,
        restarts: 1,
        ..Default::default()
    };
    let fit = GaussianHmm::fit(&ys, 3, &settings, 1).unwrap();
    assert!(fit.log_likelihood.is_finite());
    assert!(fit.trace.iter().all(|l| l.is_finite()));
    fit.hmm.validate().unwrap();
    let mut out = vec![0.0; fit.hmm.n_states()];
    fit.hmm.log_likelihoods(1e12, &mut out).unwrap();
    assert!(out.iter().all(|l| l.is_finite()));
    let path = fit.hmm.viterbi(&ys).unwrap();
    assert_eq!(path.len(), ys.len());
}

#[test]
fn constant_feature_gives_one_state() {
    let ys = vec![2.5; 50];
    let fit = GaussianHmm::fit(&ys, 3, &HmmSettings::default(), 0).unwrap();
    assert_eq!(fit.hmm.n_states(), 1);
    assert_eq!(fit.hmm.means(), &[2.5]);
    // Variance floor relative to max(mean², 1) when the data has no spread.
    let floor = HmmSettings::default().variance_floor * 2.5 * 2.5;
    assert!((fit.hmm.variances()[0] - floor).abs() < 1e-12);
    assert!(fit.log_likelihood.is_finite());
    assert_eq!(
        fit.hmm.assign(&ys, AssignmentRule::MaxLikelihood).unwrap(),
        vec![0; 50]
    );
    let zeros = GaussianHmm::fit(&[0.0; 10], 2, &HmmSettings::default(), 0).unwrap();
    assert_eq!(zeros.hmm.n_states(), 1);
    assert!(zeros.hmm.variances()[0] > 0.0);
}

#[test]
fn two_distinct_values_give_two_states_at_those_values() {
    let ys: Vec<f64> = (0..40)
        .map(|i| if i % 3 == 0 { 1.0 } else { 7.0 })
        .collect();
    for k in [2, 3, 5] {
        let fit = GaussianHmm::fit(&ys, k, &HmmSettings::default(), 4).unwrap();
        assert_eq!(fit.hmm.n_states(), 2, "k={k}");
        assert!((fit.hmm.means()[0] - 1.0).abs() < 1e-9);
        assert!((fit.hmm.means()[1] - 7.0).abs() < 1e-9);
        assert!(fit.hmm.variances().iter().all(|v| *v > 0.0));
        assert!(fit.log_likelihood.is_finite());
        let states = fit.hmm.assign(&ys, AssignmentRule::MaxLikelihood).unwrap();
        for (y, s) in ys.iter().zip(states) {
            assert_eq!(s, usize::from(*y > 4.0));
        }
    }
}

#[test]
fn fewer_samples_than_states_gives_one_state_per_sample() {
    let ys = [3.0, -1.0];
    let fit = GaussianHmm::fit(&ys, 4, &HmmSettings::default(), 0).unwrap();
    assert_eq!(fit.hmm.n_states(), 2);
    assert_eq!(fit.hmm.means(), &[-1.0, 3.0]);
    assert!(fit.log_likelihood.is_finite());
    let one = GaussianHmm::fit(&[5.0], 3, &HmmSettings::default(), 0).unwrap();
    assert_eq!(one.hmm.n_states(), 1);
}

#[test]
fn bad_input_is_an_error() {
    let s = HmmSettings::default();
    assert_eq!(GaussianHmm::fit(&[], 2, &s, 0), Err(HmmError::Empty));
    assert_eq!(
        GaussianHmm::fit(&[1.0, 2.0], 0, &s, 0),
        Err(HmmError::NoStates)
    );
    match GaussianHmm::fit(&[1.0, 2.0, f64::NAN, 4.0], 2, &s, 0) {
        Err(HmmError::NonFinite { index, value }) => {
            assert_eq!(index, 2);
            assert!(value.is_nan());
        }
        other => panic!("expected NonFinite, got {other:?}"),
    }
    assert!(matches!(
        GaussianHmm::fit(&[1.0, f64::INFINITY], 2, &s, 0),
        Err(HmmError::NonFinite { index: 1, .. })
    ));
    assert_eq!(
        GaussianHmm::fit(&[1e300, -1e300], 2, &s, 0),
        Err(HmmError::DataRange)
    );
    let hmm = known_hmm();
    let mut out = vec![0.0; 3];
    assert!(matches!(
        hmm.likelihoods(f64::NAN, &mut out),
        Err(HmmError::NonFinite { .. })
    ));
    assert!(matches!(
        hmm.likelihoods(0.0, &mut [0.0; 2]),
        Err(HmmError::OutputLength {
            expected: 3,
            got: 2
        })
    ));
    assert!(matches!(
        hmm.assign(&[0.0, f64::NAN], AssignmentRule::Viterbi),
        Err(HmmError::NonFinite { index: 1, .. })
    ));
}

#[test]
fn likelihoods_are_gaussian_densities() {
    let hmm = known_hmm();
    let mut out = vec![0.0; 3];
    hmm.likelihoods(0.3, &mut out).unwrap();
    for (j, got) in out.iter().enumerate() {
        let (m, v) = (hmm.means()[j], hmm.variances()[j]);
        let expected =
            (-(0.3 - m) * (0.3 - m) / (2.0 * v)).exp() / (2.0 * std::f64::consts::PI * v).sqrt();
        assert!((got - expected).abs() < 1e-14, "state {j}");
    }
}

#[test]
fn validate_rejects_broken_parameters() {
    let ok = || {
        (
            vec![0.5, 0.5],
            vec![vec![0.5, 0.5], vec![0.1, 0.9]],
            vec![0.0, 1.0],
            vec![1.0, 1.0],
        )
    };
    let (i, t, m, v) = ok();
    assert!(GaussianHmm::new(i, t, m, v).is_ok());
    let (i, t, m, _) = ok();
    assert!(GaussianHmm::new(i, t, m, vec![1.0, 0.0]).is_err());
    let (i, _, m, v) = ok();
    assert!(GaussianHmm::new(i, vec![vec![0.5, 0.6], vec![0.1, 0.9]], m, v).is_err());
    let (_, t, m, v) = ok();
    assert!(GaussianHmm::new(vec![1.0], t, m, v).is_err());
    let (i, t, _, v) = ok();
    assert!(GaussianHmm::new(i, t, vec![f64::NAN, 1.0], v).is_err());
    let (i, t, m, v) = ok();
    assert!(GaussianHmm::new(i, vec![t[0].clone(), vec![1.0]], m.clone(), v.clone()).is_err());
    assert!(GaussianHmm::new(vec![], vec![], vec![], vec![]).is_err());
}

#[test]
fn json_round_trip_and_deserialisation_validates() {
    let hmm = known_hmm();
    let text = serde_json::to_string(&hmm).unwrap();
    let back: GaussianHmm = serde_json::from_str(&text).unwrap();
    assert_eq!(back, hmm);
    let broken = text.replace("\"variances\":[1.0", "\"variances\":[-1.0");
    assert_ne!(broken, text);
    let err = serde_json::from_str::<GaussianHmm>(&broken).unwrap_err();
    assert!(err.to_string().contains("variance of state 0"), "{err}");
    let unknown = text.replacen('{', "{\"extra\":1,", 1);
    assert!(serde_json::from_str::<GaussianHmm>(&unknown).is_err());
}

#[test]
fn settings_reject_unknown_fields_and_fill_defaults() {
    let s: HmmSettings = toml::from_str("restarts = 5\nassignment = \"viterbi\"").unwrap();
    assert_eq!(s.restarts, 5);
    assert_eq!(s.assignment, AssignmentRule::Viterbi);
    assert_eq!(s.max_iterations, HmmSettings::default().max_iterations);
    assert!(toml::from_str::<HmmSettings>("restart = 5").is_err());
}

#[test]
fn large_offset_does_not_spoil_variances() {
    let truth = known_hmm();
    let (ys, _) = sample(&truth, 3000, 12);
    let shifted: Vec<f64> = ys.iter().map(|y| y + 1e9).collect();
    let a = GaussianHmm::fit(&ys, 3, &HmmSettings::default(), 2).unwrap();
    let b = GaussianHmm::fit(&shifted, 3, &HmmSettings::default(), 2).unwrap();
    for j in 0..3 {
        assert!((b.hmm.means()[j] - 1e9 - a.hmm.means()[j]).abs() < 1e-3);
        let rel = b.hmm.variances()[j] / a.hmm.variances()[j];
        assert!((rel - 1.0).abs() < 1e-3, "variance {j} ratio {rel}");
    }
    assert!((a.log_likelihood - b.log_likelihood).abs() < 1e-3 * a.log_likelihood.abs());
}

/// Issue 14: on the simulated rig's 1 mm mesh (the training data of the paper's table), the
/// default EM reaches, for every feature at 2 and 3 states, the best log-likelihood of 20 varied
/// restarts (each kind of start, run to a tight tolerance) to within 1e-3, relative; and it is
/// not stopped by the plateau that ended `size_line0` at 2 states 0.8 % short under the old
/// stopping rule.
#[test]
fn default_em_reaches_the_best_of_twenty_varied_restarts_on_the_mesh() {
    use evitrack::features::FeatureConfig;
    use evitrack::sim::{simulate, Motion, SimSettings};
    let dataset = simulate(
        &SimSettings::default(),
        &Motion::Mesh { spacing: 1.0 },
        7,
        &mut |_, _| {},
    )
    .unwrap();
    let set = FeatureConfig::with_barycentre().check().unwrap();
    let rows = set.extract_batch(dataset.images());
    let tight = HmmSettings {
        restarts: 4,
        max_iterations: 5000,
        tolerance: 1e-12,
        patience: 20,
        ..HmmSettings::default()
    };
    let mut worst: f64 = 0.0;
    for (f, name) in set.names().iter().enumerate() {
        let column: Vec<f64> = rows.iter().map(|r| r[f].unwrap()).collect();
        for k in [2, 3] {
            let fit = GaussianHmm::fit(&column, k, &HmmSettings::default(), 0).unwrap();
            assert!(fit.converged, "{name} at {k} states");
            // 5 seeds × (k-means++, partition, quantiles, random) = 20 varied restarts.
            let best = (0..5u64)
                .map(|seed| GaussianHmm::fit(&column, k, &tight, 1000 + seed).unwrap())
                .map(|f| f.log_likelihood)
                .fold(f64::NEG_INFINITY, f64::max);
            let gap = (best - fit.log_likelihood) / best.abs();
            assert!(
                gap < 1e-3,
                "{name} at {k} states: {} against {best}",
                fit.log_likelihood
            );
            worst = worst.max(gap);
        }
    }
    eprintln!("largest relative gap to the best of 20 varied restarts: {worst:.2e}");
    // The plateau: with the old rule (one iteration below 1e-4 per observation) k-means++ alone
    // stops at 577.6; the default rule carries the same start on to 582.1.
    let line0: Vec<f64> = rows.iter().map(|r| r[0].unwrap()).collect();
    let old = HmmSettings {
        restarts: 1,
        tolerance: 1e-4,
        patience: 1,
        ..HmmSettings::default()
    };
    let new = HmmSettings {
        restarts: 1,
        ..HmmSettings::default()
    };
    let stopped = GaussianHmm::fit(&line0, 2, &old, 0).unwrap().log_likelihood;
    let carried = GaussianHmm::fit(&line0, 2, &new, 0).unwrap().log_likelihood;
    assert!(carried - stopped > 4.0, "{stopped} → {carried}");
}
