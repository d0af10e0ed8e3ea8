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

/// The Cholesky factor of B Bᵀ + I/2, B from a fixed pseudo-random stream: positive definite,
/// no structure.
fn random_positive_definite(n: usize, seed: u64) -> Cholesky<f64, nalgebra::Dyn> {
    let mut state = seed;
    let b = DMatrix::from_fn(n, n, |_, _| {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    });
    let k = &b * b.transpose() + DMatrix::identity(n, n) * 0.5;
    Cholesky::new(k).unwrap()
}

#[test]
fn the_tiled_inverse_matches_the_column_version_bit_for_bit() {
    for n in [1, 2, 3, 4, 5, 6, 7, 8, 9, 13, 33, 64, 101, 150] {
        let chol = random_positive_definite(n, n as u64);
        let ours = upper_inverse(chol.l_dirty());
        let reference = reference_inverse(chol.l_dirty());
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&ours), bits(&reference), "n = {n}");
    }
}

/// The previous `upper_inverse`, column by column (four at a time), kept as the reference the
/// tiled one must match bit for bit. The upper triangle (i ≤ j, column-major, at `i + j·n`) of K⁻¹ = L⁻ᵀL⁻¹ from the lower
/// Cholesky factor (column-major, upper part ignored): n³/3 multiply-adds, four columns at a
/// time so that each loaded value serves four sums (several times faster than solving against
/// the identity).
fn reference_inverse(l: &DMatrix<f64>) -> Vec<f64> {
    let n = l.nrows();
    let l = l.as_slice();
    let width = n.div_ceil(4) * 4;
    // Columns of M = L⁻¹ (lower) by forward substitution, padded with zero columns to a
    // multiple of 4. Column j starts as e_j; its rows above j stay exactly 0 throughout.
    let mut m = vec![0.0; n * width];
    for (b, block) in m.chunks_exact_mut(4 * n).enumerate() {
        let j0 = 4 * b;
        for c in 0..4 {
            if j0 + c < n {
                block[c * n + j0 + c] = 1.0;
            }
        }
        let (x0, rest) = block.split_at_mut(n);
        let (x1, rest) = rest.split_at_mut(n);
        let (x2, x3) = rest.split_at_mut(n);
        for k in j0..n {
            let d = l[k + k * n];
            let a = [x0[k] / d, x1[k] / d, x2[k] / d, x3[k] / d];
            [x0[k], x1[k], x2[k], x3[k]] = a;
            let column = &l[k * n + k + 1..(k + 1) * n];
            let rows = x0[k + 1..]
                .iter_mut()
                .zip(x1[k + 1..].iter_mut())
                .zip(x2[k + 1..].iter_mut().zip(x3[k + 1..].iter_mut()));
            for (((y0, y1), (y2, y3)), lik) in rows.zip(column) {
                *y0 -= a[0] * lik;
                *y1 -= a[1] * lik;
                *y2 -= a[2] * lik;
                *y3 -= a[3] * lik;
            }
        }
    }
    // (K⁻¹)_ij = Σ_k M_ki M_kj, over k ≥ j0 for the block of j0 (the rest is exactly 0).
    let mut inverse = vec![0.0; n * n];
    for j0 in (0..n).step_by(4) {
        let columns: [&[f64]; 4] = std::array::from_fn(|c| &m[(j0 + c) * n + j0..(j0 + c + 1) * n]);
        for i in 0..(j0 + 4).min(n) {
            let mut sums = [0.0; 4];
            for (k, v) in m[i * n + j0..(i + 1) * n].iter().enumerate() {
                for c in 0..4 {
                    sums[c] += v * columns[c][k];
                }
            }
            for (c, sum) in sums.into_iter().enumerate() {
                if i <= j0 + c && j0 + c < n {
                    inverse[i + (j0 + c) * n] = sum;
                }
            }
        }
    }
    inverse
}

#[test]
fn every_tile_shape_of_the_inverse_gives_the_same_bits() {
    // Scratch buffers start as NaN: an entry read before it is written would show.
    for (n, seed) in [(5, 1u64), (8, 2), (13, 3), (30, 4), (61, 5)] {
        let chol = random_positive_definite(n, seed);
        let reference = reference_inverse(chol.l_dirty());
        for tile in [4, 8] {
            let ours = inverse::upper_inverse_with_tiles(chol.l_dirty(), tile);
            for j in 0..n {
                for i in 0..=j {
                    let at = i + j * n;
                    assert_eq!(
                        ours[at].to_bits(),
                        reference[at].to_bits(),
                        "tile {tile}, n {n}"
                    );
                }
            }
        }
    }
}

#[test]
fn an_objective_reusing_its_buffers_gives_the_bits_of_a_fresh_one() {
    let reused = objective();
    let thetas = [
        [0.3, -0.2, 0.1, -1.5],
        [-1.0, 0.7, 0.4, -3.0],
        [0.3, -0.2, 0.1, -1.5],
        [1.2, 1.1, -0.5, -0.5],
    ];
    let bits = |(v, g): (f64, Vec<f64>)| (v.to_bits(), g.iter().map(|x| x.to_bits()).collect());
    for theta in thetas {
        let once: (u64, Vec<u64>) = bits(objective().eval(&theta).unwrap());
        assert_eq!(bits(reused.eval(&theta).unwrap()), once, "θ = {theta:?}");
    }
    // And a whole optimisation, whose line searches drop points mid-way.
    let start = vec![0.0, 0.0, 0.0, (0.1f64).ln()];
    let twice = minimise(&reused, start.clone(), 50).unwrap();
    assert_eq!(twice, minimise(&objective(), start, 50).unwrap());
}

#[test]
fn the_inverse_into_stale_buffers_gives_the_same_upper_triangle() {
    let mut scratch = inverse::InverseScratch::default();
    let mut out = Vec::new();
    // Larger, smaller, then larger again: every buffer holds another matrix's values.
    for (n, seed) in [(37, 1u64), (13, 2), (9, 3), (41, 4)] {
        let chol = random_positive_definite(n, seed);
        let fresh = upper_inverse(chol.l_dirty());
        inverse::upper_inverse_into(chol.l_dirty(), &mut scratch, &mut out);
        for j in 0..n {
            for i in 0..=j {
                let at = i + j * n;
                assert_eq!(out[at].to_bits(), fresh[at].to_bits(), "n {n} ({i}, {j})");
            }
        }
    }
}
