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

/// Columns factored together, and rows of a register tile: with 256-bit vectors, two vectors
/// of rows per column make eight independent chains (enough to hide an addition's latency).
const PANEL: usize = 4;
const ROWS: usize = 8;
/// The same with 512-bit vectors (AVX-512): eight columns, sixteen rows, sixteen chains.
const WIDE_PANEL: usize = 8;
const WIDE_ROWS: usize = 16;

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
    /// [`factor_in_place`], with AVX (or AVX-512, wider tiles) where the processor has it.
    fn factor(a: &mut [f64], n: usize) -> bool = narrow,
    avx512 = factor_in_place::<WIDE_PANEL, WIDE_ROWS, { WIDE_ROWS / 2 }, true>
);

/// [`factor_in_place`] with tiles for 256-bit vectors.
#[inline(always)]
fn narrow(a: &mut [f64], n: usize) -> bool {
    factor_in_place::<PANEL, ROWS, { ROWS / 2 }, false>(a, n)
}

/// The factorisation of [`cholesky`] on a column-major slice; `false` at a refused pivot.
#[inline(always)]
/// With `WIDE` (only where the processor has AVX-512F), the tiles of eight columns use AVX-512
/// instructions written out: the compiler's own vectorisation of them gathered and scattered.
fn factor_in_place<const PANEL: usize, const ROWS: usize, const HALF: usize, const WIDE: bool>(
    a: &mut [f64],
    n: usize,
) -> bool {
    for j0 in (0..n).step_by(PANEL) {
        let width = PANEL.min(n - j0);
        if width == PANEL {
            update_panel::<PANEL, ROWS, HALF, WIDE>(a, n, j0);
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

/// Applies the updates of columns 0 … j0 − 1 to the lower part of columns j0 … j0 + PANEL − 1,
/// each entry's chain in increasing k; entries above the diagonal are computed but not stored.
/// Rows go in tiles of `ROWS`, then one of `HALF` where that many are left, then the rest.
#[inline(always)]
fn update_panel<const PANEL: usize, const ROWS: usize, const HALF: usize, const WIDE: bool>(
    a: &mut [f64],
    n: usize,
    j0: usize,
) {
    let mut i0 = j0;
    #[cfg(target_arch = "x86_64")]
    if WIDE && PANEL == WIDE_PANEL && ROWS == WIDE_ROWS {
        while n - i0 >= WIDE_ROWS {
            // SAFETY: `WIDE` is only set in the copy that runs where the processor has AVX-512F.
            unsafe { update_tile_avx512::<2>(a, n, j0, i0) };
            i0 += WIDE_ROWS;
        }
    }
    while n - i0 >= ROWS {
        update_tile::<PANEL, ROWS>(a, n, j0, i0);
        i0 += ROWS;
    }
    if n - i0 >= HALF {
        #[cfg(target_arch = "x86_64")]
        if WIDE && PANEL == WIDE_PANEL && HALF == WIDE_ROWS / 2 {
            // SAFETY: as above.
            unsafe { update_tile_avx512::<1>(a, n, j0, i0) };
        } else {
            update_tile::<PANEL, HALF>(a, n, j0, i0);
        }
        #[cfg(not(target_arch = "x86_64"))]
        update_tile::<PANEL, HALF>(a, n, j0, i0);
        i0 += HALF;
    }
    if i0 == n {
        return;
    }
    let rows = n - i0;
    let mut acc = [[0.0f64; ROWS]; PANEL];
    for (c, column) in acc.iter_mut().enumerate() {
        for (r, slot) in column.iter_mut().enumerate().take(rows) {
            *slot = a[i0 + r + (j0 + c) * n];
        }
    }
    for k in 0..j0 {
        let base = k * n;
        for c in 0..PANEL {
            let lj = a[base + j0 + c];
            for r in 0..rows {
                acc[c][r] -= lj * a[base + i0 + r];
            }
        }
    }
    store_tile(a, n, j0, i0, &acc, rows);
}

/// [`update_panel`] on the `ROWS` rows from `i0` (all below n).
#[inline(always)]
fn update_tile<const PANEL: usize, const ROWS: usize>(
    a: &mut [f64],
    n: usize,
    j0: usize,
    i0: usize,
) {
    let mut acc = [[0.0f64; ROWS]; PANEL];
    for (c, column) in acc.iter_mut().enumerate() {
        column.copy_from_slice(&a[i0 + (j0 + c) * n..i0 + ROWS + (j0 + c) * n]);
    }
    // One column of L per k: two bounds checks, then the tile's multiply-subtracts in registers.
    for column in a[..j0 * n].chunks_exact(n) {
        let li: [f64; ROWS] = column[i0..i0 + ROWS].try_into().unwrap_or([0.0; ROWS]);
        let lj: [f64; PANEL] = column[j0..j0 + PANEL].try_into().unwrap_or([0.0; PANEL]);
        for c in 0..PANEL {
            for r in 0..ROWS {
                acc[c][r] -= lj[c] * li[r];
            }
        }
    }
    store_tile(a, n, j0, i0, &acc, ROWS);
}

/// [`update_tile`] on eight columns and `GROUPS` × 8 rows, with AVX-512 registers: the same
/// chains (a multiply, then a subtraction, each rounded) in the same order of k.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn update_tile_avx512<const GROUPS: usize>(a: &mut [f64], n: usize, j0: usize, i0: usize) {
    use std::arch::x86_64::{
        __m512d, _mm512_loadu_pd, _mm512_mul_pd, _mm512_set1_pd, _mm512_setzero_pd,
        _mm512_storeu_pd, _mm512_sub_pd,
    };
    const LANES: usize = 8;
    let rows = GROUPS * LANES;
    let mut acc: [[__m512d; GROUPS]; WIDE_PANEL] = [[_mm512_setzero_pd(); GROUPS]; WIDE_PANEL];
    for (c, column) in acc.iter_mut().enumerate() {
        let start = i0 + (j0 + c) * n;
        let entries = &a[start..start + rows];
        for (g, value) in column.iter_mut().enumerate() {
            // SAFETY: `entries` holds GROUPS × 8 values.
            *value = unsafe { _mm512_loadu_pd(entries.as_ptr().add(g * LANES)) };
        }
    }
    for column in a[..j0 * n].chunks_exact(n) {
        let li = &column[i0..i0 + rows];
        let lj = &column[j0..j0 + WIDE_PANEL];
        let mut rows_k = [_mm512_setzero_pd(); GROUPS];
        for (g, value) in rows_k.iter_mut().enumerate() {
            // SAFETY: `li` holds GROUPS × 8 values.
            *value = unsafe { _mm512_loadu_pd(li.as_ptr().add(g * LANES)) };
        }
        for (column_acc, &ljc) in acc.iter_mut().zip(lj) {
            let factor = _mm512_set1_pd(ljc);
            for (value, &row) in column_acc.iter_mut().zip(&rows_k) {
                *value = _mm512_sub_pd(*value, _mm512_mul_pd(factor, row));
            }
        }
    }
    let mut values = [[0.0f64; WIDE_ROWS]; WIDE_PANEL];
    for (column, column_acc) in values.iter_mut().zip(&acc) {
        for (g, value) in column_acc.iter().enumerate() {
            // SAFETY: a column of `values` holds 16 ≥ GROUPS × 8 values.
            unsafe { _mm512_storeu_pd(column.as_mut_ptr().add(g * LANES), *value) };
        }
    }
    store_tile(a, n, j0, i0, &values, rows);
}

/// Writes the first `rows` rows of a tile at (i0, j0), on and below the diagonal only.
#[inline(always)]
fn store_tile<const PANEL: usize, const ROWS: usize>(
    a: &mut [f64],
    n: usize,
    j0: usize,
    i0: usize,
    acc: &[[f64; ROWS]; PANEL],
    rows: usize,
) {
    for (c, column) in acc.iter().enumerate() {
        for (r, value) in column.iter().enumerate().take(rows) {
            if i0 + r >= j0 + c {
                a[i0 + r + (j0 + c) * n] = *value;
            }
        }
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
    fn every_tile_shape_matches_nalgebra_whichever_copy_runs_here() {
        // The dispatch runs one copy on this processor; the others' tiles are checked here.
        type Factor = fn(&mut [f64], usize) -> bool;
        let shapes: [(&str, Factor); 3] = [
            ("narrow", narrow),
            (
                "wide tiles",
                factor_in_place::<WIDE_PANEL, WIDE_ROWS, { WIDE_ROWS / 2 }, false>,
            ),
            ("dispatched", factor),
        ];
        for (seed, n) in [3, 8, 9, 17, 24, 31, 40, 57, 100].into_iter().enumerate() {
            let m = random_spd(n, 0.5, 100 + seed as u64);
            let theirs = Cholesky::new(m.clone()).expect("positive definite");
            for (name, shape) in shapes {
                let mut ours = m.clone();
                assert!(shape(ours.as_mut_slice(), n), "{name}, n = {n}: refused");
                assert!(
                    same_bits(&ours, theirs.l_dirty()),
                    "{name}, n = {n}: the factors differ"
                );
            }
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
