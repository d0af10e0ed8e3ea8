use super::optimiser::{bounds, project};
use super::*;
use nalgebra::{Cholesky, DMatrix};

/// A small fit problem: a smooth function of 2 features on an 8 × 8 grid, plus noise of
/// standard deviation about 0.1 (a fixed pseudo-random sequence), so the optimum is interior.
fn objective() -> Objective {
    let n = 64;
    let inputs: Vec<f64> = (0..n)
        .flat_map(|i| [(i % 8) as f64 / 4.0 - 1.0, (i / 8) as f64 / 4.0 - 1.0])
        .collect();
    let mut state: u64 = 12345;
    let mut noise = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.35
    };
    let outputs: Vec<f64> = inputs
        .chunks(2)
        .flat_map(|x| {
            [
                x[0] * x[1] + 0.5 * x[0] + noise(),
                (x[0] - x[1]).sin() + noise(),
            ]
        })
        .collect();
    Objective::new(&inputs, &outputs, 2, &(0..n).collect::<Vec<_>>())
}

#[test]
fn analytic_gradient_matches_finite_differences() {
    let objective = objective();
    let theta = [0.3, -0.2, 0.1, -1.5];
    let (_, grad) = objective.eval(&theta).unwrap();
    for k in 0..theta.len() {
        let h = 1e-6;
        let (mut up, mut down) = (theta, theta);
        up[k] += h;
        down[k] -= h;
        let numeric =
            (objective.eval(&up).unwrap().0 - objective.eval(&down).unwrap().0) / (2.0 * h);
        assert!(
            (numeric - grad[k]).abs() < 1e-6 * (1.0 + numeric.abs()),
            "θ[{k}]: analytic {} vs numeric {numeric}",
            grad[k]
        );
    }
}

#[test]
fn the_optimiser_improves_the_likelihood_and_respects_the_bounds() {
    let objective = objective();
    let start = vec![0.0, 0.0, 0.0, (0.1f64).ln()];
    let (f0, _) = objective.eval(&start).unwrap();
    let (theta, f) = minimise(&objective, start, 200).unwrap();
    assert!(f < f0 - 0.01, "{f} vs {f0}");
    let (lower, upper) = bounds(2);
    let mut projected = theta.clone();
    project(&mut projected, &lower, &upper);
    assert_eq!(projected, theta);
    assert!(
        theta[3] > lower[3] + 1.0,
        "the noise found no interior optimum: {theta:?}"
    );
    // At an interior optimum the gradient vanishes on the free coordinates.
    let (_, grad) = objective.eval(&theta).unwrap();
    for (k, g) in grad.iter().enumerate() {
        if theta[k] > lower[k] + 1e-3 && theta[k] < upper[k] - 1e-3 {
            assert!(g.abs() < 1e-4, "gradient {g} on θ[{k}] at {theta:?}");
        }
    }
}

#[test]
fn the_blocked_inverse_matches_solving_against_the_identity() {
    for n in [1, 2, 3, 4, 5, 7, 8, 33] {
        let k = DMatrix::from_fn(n, n, |i, j| {
            (-((i as f64 - j as f64) / 3.0).powi(2)).exp() + if i == j { 0.1 } else { 0.0 }
        });
        let chol = Cholesky::new(k).unwrap();
        let reference = chol.inverse();
        let upper = upper_inverse(chol.l_dirty());
        for j in 0..n {
            for i in 0..=j {
                let diff = (reference[(i, j)] - upper[i + j * n]).abs();
                assert!(diff < 1e-10, "n {n}, ({i}, {j}): off by {diff}");
            }
        }
    }
}
