//! A dense Cholesky factorisation bit-identical to nalgebra's `Cholesky::new`, several times
//! faster on kernel matrices of a few hundred rows and more.
//!
//! nalgebra computes each entry of L as one chain, s ← A_ij, then s ← s − L_jk·L_ik for k = 0,
//! 1, …, j − 1, then √s on the diagonal or s / L_jj below it, one column at a time with a vector
//! update per k (two loads and a store per multiply-add). The same chains run here, in the same
//! k order, so every bit is the same; only which chains run together changes: columns are taken
//! four at a time, and the updates from the columns before them are applied to tiles of 4 rows
//! × 4 columns held in registers (8 loads per 16 multiply-adds).

use nalgebra::{Cholesky, DMatrix, Dyn};

/// Columns factored together.
const PANEL: usize = 4;
/// Rows of a register tile.
const ROWS: usize = 8;

/// The Cholesky factor of a symmetric positive-definite matrix (its lower triangle is read, its
/// strict upper triangle kept as given, as nalgebra's `l_dirty` shows it), or `None` where a
/// pivot is zero, negative or not a number — exactly where `Cholesky::new` gives `None`, with
/// the same bits otherwise.
pub fn cholesky(mut matrix: DMatrix<f64>) -> Option<Cholesky<f64, Dyn>> {
    let n = matrix.nrows();
    assert_eq!(n, matrix.ncols(), "a Cholesky factor needs a square matrix");
    let factored = factor(matrix.as_mut_slice(), n);
    factored.then(|| Cholesky::pack_dirty(matrix))
}

crate::simd::with_avx!(
    /// [`factor_in_place`], with AVX where the processor has it.
    fn factor(a: &mut [f64], n: usize) -> bool = factor_in_place
);

/// The factorisation of [`cholesky`] on a column-major slice; `false` at a refused pivot.
#[inline(always)]
fn factor_in_place(a: &mut [f64], n: usize) -> bool {
    for j0 in (0..n).step_by(PANEL) {
        let width = PANEL.min(n - j0);
        if width == PANEL {
            update_panel(a, n, j0);
        } else {
            // The last, narrow panel: the updates from earlier columns one chain at a time.
            for j in j0..n {
                for i in j..n {
                    let mut s = a[i + j * n];
                    for k in 0..j0 {
                        s -= a[j + k * n] * a[i + k * n];
                    }
                    a[i + j * n] = s;
                }
            }
        }
        // Within the panel, as nalgebra does: the chains go on with k = j0 … j − 1.
        for j in j0..j0 + width {
            for k in j0..j {
                let factor = a[j + k * n];
                let (before, from_j) = a.split_at_mut(j * n);
                let column_k = &before[k * n + j..(k + 1) * n];
                for (y, x) in from_j[j..n].iter_mut().zip(column_k) {
                    *y -= factor * x;
                }
            }
            let diagonal = a[j + j * n];
            // nalgebra refuses a zero pivot and one without a real square root (negative, NaN).
            if diagonal == 0.0 || diagonal.is_nan() || diagonal < 0.0 {
                return false;
            }
            let root = diagonal.sqrt();
            a[j + j * n] = root;
            for y in &mut a[j * n + j + 1..(j + 1) * n] {
                *y /= root;
            }
        }
    }
    true
}

/// Applies the updates of columns 0 … j0 − 1 to the lower part of columns j0 … j0 + 3, each
/// entry's chain in increasing k; entries above the diagonal are computed but not stored.
#[inline(always)]
fn update_panel(a: &mut [f64], n: usize, j0: usize) {
    let mut i0 = j0;
    while i0 < n {
        let rows = ROWS.min(n - i0);
        let mut acc = [[0.0f64; ROWS]; PANEL];
        for (c, column) in acc.iter_mut().enumerate() {
            for (r, slot) in column.iter_mut().enumerate().take(rows) {
                *slot = a[i0 + r + (j0 + c) * n];
            }
        }
        if rows == ROWS {
            // One column of L per k: two bounds checks, then 16 multiply-subtracts in registers.
            for column in a[..j0 * n].chunks_exact(n) {
                let li: [f64; ROWS] = column[i0..i0 + ROWS].try_into().unwrap_or([0.0; ROWS]);
                let lj: [f64; PANEL] = column[j0..j0 + PANEL].try_into().unwrap_or([0.0; PANEL]);
                for c in 0..PANEL {
                    for r in 0..ROWS {
                        acc[c][r] -= lj[c] * li[r];
                    }
                }
            }
        } else {
            for k in 0..j0 {
                let base = k * n;
                for c in 0..PANEL {
                    let lj = a[base + j0 + c];
                    for r in 0..rows {
                        acc[c][r] -= lj * a[base + i0 + r];
                    }
                }
            }
        }
        for (c, column) in acc.iter().enumerate() {
            for (r, value) in column.iter().enumerate().take(rows) {
                if i0 + r >= j0 + c {
                    a[i0 + r + (j0 + c) * n] = *value;
                }
            }
        }
        i0 += rows;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A random symmetric matrix B Bᵀ + shift·I of size n (seeded), positive definite for a
    /// positive shift.
    fn random_spd(n: usize, shift: f64, seed: u64) -> DMatrix<f64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let b = DMatrix::from_fn(n, n, |_, _| rng.random_range(-1.0..1.0));
        let mut m = &b * b.transpose();
        for i in 0..n {
            m[(i, i)] += shift;
        }
        // An upper triangle that differs from the lower: it must come back untouched.
        for j in 0..n {
            for i in 0..j {
                m[(i, j)] = rng.random_range(-5.0..5.0);
            }
        }
        m
    }

    fn same_bits(a: &DMatrix<f64>, b: &DMatrix<f64>) -> bool {
        a.iter()
            .zip(b.iter())
            .all(|(x, y)| x.to_bits() == y.to_bits())
    }

    #[test]
    fn every_bit_matches_nalgebra() {
        for (seed, n) in [1, 2, 3, 4, 5, 7, 8, 9, 13, 16, 31, 37, 64, 101, 230]
            .into_iter()
            .enumerate()
        {
            let m = random_spd(n, 0.5, seed as u64);
            let ours = cholesky(m.clone()).expect("positive definite");
            let theirs = Cholesky::new(m).expect("positive definite");
            assert!(
                same_bits(ours.l_dirty(), theirs.l_dirty()),
                "n = {n}: the factors differ"
            );
        }
    }

    #[test]
    fn a_kernel_matrix_with_ties_and_tiny_noise_matches_too() {
        // A squared-exponential kernel on points with duplicates: nearly singular.
        let n = 57;
        let x: Vec<f64> = (0..n).map(|i| ((i * 7) % 19) as f64 * 0.1).collect();
        let m = DMatrix::from_fn(n, n, |i, j| {
            (-0.5 * (x[i] - x[j]).powi(2)).exp() + if i == j { 1e-6 } else { 0.0 }
        });
        let ours = cholesky(m.clone()).expect("positive definite");
        let theirs = Cholesky::new(m).expect("positive definite");
        assert!(same_bits(ours.l_dirty(), theirs.l_dirty()));
    }

    #[test]
    fn refuses_exactly_where_nalgebra_refuses() {
        for (n, at) in [(1, 0), (6, 5), (9, 2), (40, 33)] {
            // Positive definite but for one pivot: negative, zero and NaN.
            for bad in [-1.0, 0.0, f64::NAN] {
                let mut m = random_spd(n, 0.5, n as u64);
                for k in 0..n {
                    m[(at, k)] = 0.0;
                    m[(k, at)] = 0.0;
                }
                m[(at, at)] = bad;
                assert!(Cholesky::new(m.clone()).is_none(), "n {n}, pivot {bad}");
                assert!(cholesky(m).is_none(), "n {n}, pivot {bad}");
            }
        }
        // Indefinite with no zero entry: refused by both.
        let m = DMatrix::from_row_slice(3, 3, &[1.0, 2.0, 0.5, 2.0, 1.0, 0.3, 0.5, 0.3, 1.0]);
        assert!(Cholesky::new(m.clone()).is_none());
        assert!(cholesky(m).is_none());
    }
}
