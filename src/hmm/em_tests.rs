//! Unit tests of `em.rs`.
use super::super::init::init_kmeanspp;
use super::super::AssignmentRule;
use super::*;
use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn em_log_likelihood_never_decreases(
        ys in proptest::collection::vec(-100.0f64..100.0, 1..120),
        k in 1usize..9,
        seed in any::<u64>(),
    ) {
        let fit = GaussianHmm::fit(&ys, k, &HmmSettings::default(), seed).unwrap();
        for w in fit.trace.windows(2) {
            prop_assert!(w[1] >= w[0] - 1e-9 * w[0].abs().max(1.0), "{:?}", fit.trace);
        }
        prop_assert!(fit.log_likelihood.is_finite());
        prop_assert_eq!(fit.log_likelihood, *fit.trace.last().unwrap());
        prop_assert!(fit.hmm.validate().is_ok());
        prop_assert!(fit.hmm.means().windows(2).all(|m| m[0] <= m[1]));
        let states = fit.hmm.assign(&ys, AssignmentRule::MaxLikelihood).unwrap();
        prop_assert!(states.iter().all(|&s| s < fit.hmm.n_states()));
        let path = fit.hmm.viterbi(&ys).unwrap();
        prop_assert_eq!(path.len(), ys.len());
    }

    #[test]
    fn fitted_log_likelihood_matches_forward(
        ys in proptest::collection::vec(-10.0f64..10.0, 5..60),
        seed in any::<u64>(),
    ) {
        let fit = GaussianHmm::fit(&ys, 2, &HmmSettings::default(), seed).unwrap();
        let ll = fit.hmm.log_likelihood(&ys).unwrap();
        prop_assert!((ll - fit.log_likelihood).abs() <= 1e-8 * ll.abs().max(1.0));
    }
}

#[test]
fn forward_matches_brute_force_enumeration() {
    let hmm = GaussianHmm::new(
        vec![0.3, 0.7],
        vec![vec![0.9, 0.1], vec![0.2, 0.8]],
        vec![-1.0, 2.0],
        vec![0.5, 2.0],
    )
    .unwrap();
    let ys = [0.1, -0.7, 2.5, 1.0];
    let dens = |j: usize, y: f64| {
        let mut out = [0.0; 2];
        hmm.likelihoods(y, &mut out).unwrap();
        out[j]
    };
    let mut total = 0.0;
    for code in 0..16u32 {
        let s: Vec<usize> = (0..4).map(|t| ((code >> t) & 1) as usize).collect();
        let mut p = hmm.initial()[s[0]] * dens(s[0], ys[0]);
        for t in 1..4 {
            p *= hmm.transitions()[s[t - 1]][s[t]] * dens(s[t], ys[t]);
        }
        total += p;
    }
    let ll = hmm.log_likelihood(&ys).unwrap();
    assert!((ll - total.ln()).abs() < 1e-12, "{ll} vs {}", total.ln());
}

#[test]
fn specialised_and_general_backward_agree() {
    let ys: Vec<f64> = (0..300)
        .map(|i| ((i as f64) * 0.37).sin() * 3.0 + (i % 7) as f64 * 0.1)
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for k in 1..=6 {
        let p = init_kmeanspp(&ys, k, 1e-3, &mut rng);
        let mut a = Workspace::new(ys.len(), k);
        let mut b = Workspace::new(ys.len(), k);
        let la = a.forward(&ys, &p).unwrap();
        // The general forward recursion, against the specialised one used by `forward`.
        b.emissions(&ys, &p);
        let scale_b = b.forward_dyn(&p).unwrap();
        let last: f64 = b.alpha[(ys.len() - 1) * k..].iter().sum();
        let lb = scale_b + last.ln() + b.offset.iter().sum::<f64>();
        assert!(
            (la - lb).abs() <= 1e-10 * la.abs().max(1.0),
            "k={k} {la} vs {lb}"
        );
        assert!(a
            .alpha
            .iter()
            .zip(&b.alpha)
            .all(|(u, v)| (u - v).abs() <= 1e-12 * u.abs().max(v.abs()).max(1e-300)));
        assert!(a.backward(&ys, &p));
        assert!(b.backward_dyn(&ys, &p));
        let close = |x: &[f64], y: &[f64]| {
            x.iter()
                .zip(y)
                .all(|(u, v)| (u - v).abs() <= 1e-12 * u.abs().max(v.abs()).max(1e-300))
        };
        assert!(close(&a.gamma_sum, &b.gamma_sum), "k={k}");
        assert!(close(&a.gamma_y, &b.gamma_y), "k={k}");
        assert!(close(&a.gamma_yy, &b.gamma_yy), "k={k}");
        assert!(close(&a.gamma_first, &b.gamma_first), "k={k}");
        assert!(close(&a.xi_sum, &b.xi_sum), "k={k}");
        // γ sums to the number of observations, ξ to one fewer.
        assert!((a.gamma_sum.iter().sum::<f64>() - ys.len() as f64).abs() < 1e-9);
        assert!(
            (a.xi_sum.iter().sum::<f64>() - (ys.len() - 1) as f64).abs() < 1e-9,
            "k={k} {:?} {:?}",
            a.xi_sum,
            a.gamma_sum
        );
    }
}

#[test]
fn scaled_emissions_are_floored_and_best_is_one() {
    let ys = [0.0, 1.0, -2.0, 1e6, -1e6, 3.5];
    let p = Params {
        k: 3,
        initial: vec![0.2, 0.3, 0.5],
        trans: vec![1.0 / 3.0; 9],
        means: vec![-1.0, 0.5, 2.0],
        variances: vec![0.1, 1.0, 4.0],
    };
    let mut ws = Workspace::new(ys.len(), 3);
    ws.emissions(&ys, &p);
    for t in 0..ys.len() {
        let col: Vec<f64> = (0..3).map(|j| ws.emis[j * ys.len() + t]).collect();
        assert_eq!(
            col.iter().cloned().fold(0.0, f64::max),
            1.0,
            "t={t} {col:?}"
        );
        assert!(col.iter().all(|&b| b >= 0.999e-150), "t={t} {col:?}");
        let mut logs = [0.0; 3];
        let hmm = GaussianHmm::new(
            p.initial.clone(),
            vec![vec![1.0 / 3.0; 3]; 3],
            p.means.clone(),
            p.variances.clone(),
        )
        .unwrap();
        hmm.log_likelihoods(ys[t], &mut logs).unwrap();
        for j in 0..3 {
            let expected = (logs[j] - ws.offset[t]).exp().max(1e-150);
            assert!(
                (col[j] - expected).abs() <= 1e-12 * expected,
                "t={t} j={j} {} vs {expected}",
                col[j]
            );
        }
    }
}

#[test]
fn fast_exp_matches_std_exp() {
    let mut worst: f64 = 0.0;
    for i in 0..=200_000 {
        let x = -(i as f64) * (700.0 / 200_000.0);
        let rel = (exp_nonpositive(x) - x.exp()).abs() / x.exp();
        worst = worst.max(rel);
    }
    assert!(worst < 1e-14, "worst relative error {worst}");
    assert_eq!(exp_nonpositive(0.0), 1.0);
}

/// The general recursions as sums per state, one state after another: the vectorised
/// `forward_dyn` and `backward_dyn` must give these bits exactly.
#[test]
fn general_recursions_are_the_sums_per_state_bit_for_bit() {
    let ys: Vec<f64> = (0..250)
        .map(|i| ((i as f64) * 0.23).sin() * 4.0 + ((i * 7) % 11) as f64 * 0.05)
        .collect();
    let n = ys.len();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for k in [2, 7, 9, 16, 24] {
        let p = init_kmeanspp(&ys, k, 1e-3, &mut rng);
        let mut fast = Workspace::new(n, k);
        fast.emissions(&ys, &p);
        let scale = fast.forward_dyn(&p).unwrap();
        assert!(fast.backward_dyn(&ys, &p));

        let mut direct = Workspace::new(n, k);
        direct.emissions(&ys, &p);
        let mut direct_scale = 0.0;
        for j in 0..k {
            direct.alpha[j] = p.initial[j] * direct.emis[j * n];
        }
        direct_scale +=
            Workspace::rescale(&mut direct.alpha[..k], &mut direct.inv_scale[0]).unwrap();
        for t in 1..n {
            for j in 0..k {
                let mut s = 0.0;
                for i in 0..k {
                    s += direct.alpha[(t - 1) * k + i] * p.trans[i * k + j];
                }
                direct.alpha[t * k + j] = s * direct.emis[j * n + t];
            }
            let (_, cur) = direct.alpha.split_at_mut(t * k);
            direct_scale += Workspace::rescale(&mut cur[..k], &mut direct.inv_scale[t]).unwrap();
        }
        assert_eq!(scale.to_bits(), direct_scale.to_bits(), "k={k}");
        assert!(fast
            .alpha
            .iter()
            .zip(&direct.alpha)
            .all(|(a, b)| a.to_bits() == b.to_bits()));

        let mut beta = vec![1.0; k];
        let mut xi = vec![0.0; k * k];
        let mut gamma = vec![0.0; k];
        for t in (1..n).rev() {
            for i in 0..k {
                gamma[i] += direct.alpha[t * k + i] * beta[i];
            }
            let w: Vec<f64> = (0..k)
                .map(|j| direct.emis[j * n + t] * beta[j] * direct.inv_scale[t])
                .collect();
            for i in 0..k {
                let mut s = 0.0;
                for j in 0..k {
                    s += p.trans[i * k + j] * w[j];
                    xi[i * k + j] += direct.alpha[(t - 1) * k + i] * w[j];
                }
                beta[i] = s;
            }
        }
        for i in 0..k {
            gamma[i] += direct.alpha[i] * beta[i];
        }
        let total: f64 = direct.alpha[(n - 1) * k..].iter().sum();
        let r = 1.0 / total;
        for i in 0..k {
            assert_eq!(
                fast.gamma_sum[i].to_bits(),
                (gamma[i] * r).to_bits(),
                "k={k} γ {i}"
            );
            for j in 0..k {
                let expected = xi[i * k + j] * (p.trans[i * k + j] * r);
                assert_eq!(
                    fast.xi_sum[i * k + j].to_bits(),
                    expected.to_bits(),
                    "k={k} ξ {i},{j}"
                );
            }
        }
    }
}
