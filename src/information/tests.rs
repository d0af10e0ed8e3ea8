use super::*;
use crate::estimator::test_maps::{feature_gradient, feature_value, workspace_points};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// tr((GᵀG)⁻¹) σ² by hand: the closed form for independent features of one noise scale.
fn closed_form(gradients: &[[f64; 2]], sigma: f64) -> f64 {
    let (mut xx, mut xy, mut yy) = (0.0, 0.0, 0.0);
    for g in gradients {
        xx += g[0] * g[0];
        xy += g[0] * g[1];
        yy += g[1] * g[1];
    }
    sigma * sigma * (xx + yy) / (xx * yy - xy * xy)
}

#[test]
fn on_the_test_maps_the_bound_is_the_closed_form() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let sigma = 0.01;
    let noise = NoiseModel::diagonal(&[sigma; 8]).unwrap();
    for q in workspace_points(20, &mut rng) {
        let g: Vec<[f64; 2]> = (0..8).map(|i| feature_gradient(i, q)).collect();
        let bound = noise.bound(&g, &[true; 8]).unwrap();
        let expected = closed_form(&g, sigma);
        assert!(
            (bound - expected).abs() < 1e-9 * expected,
            "{bound} {expected}"
        );
        // A feature left out leaves the sum.
        let mut present = [true; 8];
        present[3] = false;
        let without: Vec<[f64; 2]> = (0..8).filter(|&i| i != 3).map(|i| g[i]).collect();
        let partial = noise.bound(&g, &present).unwrap();
        assert!((partial - closed_form(&without, sigma)).abs() < 1e-9 * partial);
        assert!(partial > bound);
    }
}

#[test]
fn the_gradient_is_the_maps_slope() {
    let q = [1.3, 44.0];
    for i in 0..8 {
        let g = feature_gradient(i, q);
        let h = 1e-5;
        let dx =
            (feature_value(i, [q[0] + h, q[1]]) - feature_value(i, [q[0] - h, q[1]])) / (2.0 * h);
        let dy =
            (feature_value(i, [q[0], q[1] + h]) - feature_value(i, [q[0], q[1] - h])) / (2.0 * h);
        assert!(
            (g[0] - dx).abs() < 1e-8 && (g[1] - dy).abs() < 1e-8,
            "{i}: {g:?} {dx} {dy}"
        );
    }
}

#[test]
fn one_feature_or_none_fixes_no_pose() {
    let noise = NoiseModel::diagonal(&[1.0, 1.0]).unwrap();
    let g = [[1.0, 0.5], [0.2, 1.0]];
    assert!(noise.bound(&g, &[true, false]).is_none());
    assert!(noise.bound(&g, &[false, false]).is_none());
    // Parallel slopes: a line of poses fits equally well.
    assert!(noise
        .bound(&[[1.0, 2.0], [2.0, 4.0]], &[true, true])
        .is_none());
    assert!(noise.bound(&g, &[true]).is_none(), "wrong length");
    assert!(noise.bound(&g, &[true, true]).is_some());
}

/// Two features measure x with noise of correlation ρ and a third measures y: the best
/// unbiased x is their mean, of variance (1 + ρ)/2 σ², so the bound is ((1 + ρ)/2 + 1) σ²;
/// taken as independent they would promise σ²/2 on x.
#[test]
fn correlated_noise_gives_the_full_covariances_bound_not_the_diagonals() {
    let (rho, sigma, frames) = (0.8f64, 0.5, 20_000);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let residuals: Vec<Vec<Option<f64>>> = (0..frames)
        .map(|_| {
            let (a, b, c) = (
                normal.sample(&mut rng),
                normal.sample(&mut rng),
                normal.sample(&mut rng),
            );
            let second = rho * a + (1.0 - rho * rho).sqrt() * b;
            vec![Some(sigma * a), Some(sigma * second), Some(sigma * c)]
        })
        .collect();
    let g = [[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
    let full = NoiseModel::from_residuals(&[sigma; 3], &residuals).unwrap();
    let diagonal = NoiseModel::diagonal(&[sigma; 3]).unwrap();
    let s2 = sigma * sigma;
    let right = ((1.0 + rho) / 2.0 + 1.0) * s2;
    let measured = full.bound(&g, &[true; 3]).unwrap();
    assert!(
        (measured - right).abs() < 0.02 * right,
        "{measured} vs {right}"
    );
    let naive = diagonal.bound(&g, &[true; 3]).unwrap();
    assert!((naive - 1.5 * s2).abs() < 1e-12);
    assert!(measured > 1.15 * naive);
    assert_eq!(full.floored().0, 0);
}

#[test]
fn a_singular_correlation_is_floored_and_stays_usable() {
    // Two features with identical residuals: correlation 1, a zero eigenvalue.
    let residuals: Vec<Vec<Option<f64>>> = (0..100)
        .map(|k| {
            let r = (k as f64 * 0.37).sin();
            vec![
                Some(r),
                Some(r),
                if k % 2 == 0 { Some(r.cos()) } else { None },
            ]
        })
        .collect();
    let noise = NoiseModel::from_residuals(&[1.0; 3], &residuals).unwrap();
    let (floored, floor) = noise.floored();
    assert_eq!(floored, 1);
    assert!(
        (floor - 1.0 / 50.0).abs() < 1e-12,
        "the fewest rows a pair shares: 50"
    );
    assert!(
        (noise.covariance()[(0, 0)] - 1.0).abs() < 1e-12,
        "σ stays the given one"
    );
    let bound = noise.bound(&[[1.0, 0.0], [1.0, 0.1], [0.0, 1.0]], &[true; 3]);
    assert!(bound.is_some_and(f64::is_finite));
}

#[test]
fn bad_inputs_are_named() {
    assert_eq!(NoiseModel::diagonal(&[]), Err(InformationError::Empty));
    assert!(matches!(
        NoiseModel::diagonal(&[1.0, 0.0]),
        Err(InformationError::Scale { feature: 1, .. })
    ));
    assert_eq!(
        NoiseModel::from_residuals(&[1.0, 1.0], &[vec![Some(1.0)]]),
        Err(InformationError::Length {
            expected: 2,
            found: 1
        })
    );
}

#[test]
fn features_left_out_of_correlated_noise_match_the_model_of_the_rest() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let rows: Vec<Vec<Option<f64>>> = (0..500)
        .map(|_| {
            let common = normal.sample(&mut rng);
            (0..8)
                .map(|i| Some((1.0 + 0.1 * i as f64) * (0.7 * common + normal.sample(&mut rng))))
                .collect()
        })
        .collect();
    let sigmas: Vec<f64> = (0..8).map(|i| 1.2 + 0.1 * i as f64).collect();
    let model = NoiseModel::from_residuals(&sigmas, &rows).unwrap();
    assert_eq!(model.floored().0, 0);
    let q = [2.0, 50.0];
    let g: Vec<[f64; 2]> = (0..8).map(|i| feature_gradient(i, q)).collect();
    // Two gone (the cached precision's Schur complement) and five gone (the block factored).
    for gone in [&[2usize, 5][..], &[0, 1, 3, 4, 6]] {
        let present: Vec<bool> = (0..8).map(|i| !gone.contains(&i)).collect();
        let keep: Vec<usize> = (0..8).filter(|i| present[*i]).collect();
        let rest = NoiseModel::from_residuals(
            &keep.iter().map(|&i| sigmas[i]).collect::<Vec<_>>(),
            &(rows.iter())
                .map(|r| keep.iter().map(|&i| r[i]).collect())
                .collect::<Vec<_>>(),
        )
        .unwrap();
        let expected = rest
            .bound(
                &keep.iter().map(|&i| g[i]).collect::<Vec<_>>(),
                &vec![true; keep.len()],
            )
            .unwrap();
        let found = model.bound(&g, &present).unwrap();
        assert!(
            (found - expected).abs() < 1e-9 * expected,
            "{gone:?}: {found} vs {expected}"
        );
    }
}
