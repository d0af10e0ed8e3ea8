//! The inverse of a kernel matrix from its Cholesky factor, K⁻¹ = L⁻ᵀL⁻¹, with n³/3
//! multiply-adds in register tiles of 4 × 4 entries.
//!
//! Each entry is one chain of operations in a fixed order: M = L⁻¹ by forward substitution
//! (s ← δ_ij, s ← s − M_kj·L_ik for k = j … i − 1, M_ij = s / L_ii) and (K⁻¹)_ij = Σ_k M_ki·M_kj
//! for k from j upwards. Tiles change which chains run together, never a chain, so the result
//! is the same to the bit as the column-by-column version it replaced (held to it in the tests).

use nalgebra::DMatrix;

/// Rows and columns of a register tile (256-bit vectors), and with AVX-512.
const TILE: usize = 4;
const WIDE_TILE: usize = 8;

/// The upper triangle (i ≤ j, column-major, at `i + j·n`) of K⁻¹ = L⁻ᵀL⁻¹ from the lower
/// Cholesky factor (column-major, upper part ignored); the rest of the returned matrix is 0.
pub fn upper_inverse(l: &DMatrix<f64>) -> Vec<f64> {
    let mut out = Vec::new();
    upper_inverse_into(l, &mut InverseScratch::default(), &mut out);
    out
}

/// The working buffers of [`upper_inverse_into`], kept between calls: a fresh n² buffer each
/// time is a page fault per 4 KiB (the allocator hands large blocks back to the system).
#[derive(Debug, Default)]
pub(crate) struct InverseScratch {
    rows_of_l: Vec<f64>,
    m: Vec<f64>,
}

/// [`upper_inverse`] into `out` (resized to n²), with `scratch`'s buffers: the same bits in the
/// upper triangle; the entries below the diagonal are left as `out` held them (or 0).
pub(crate) fn upper_inverse_into(
    l: &DMatrix<f64>,
    scratch: &mut InverseScratch,
    out: &mut Vec<f64>,
) {
    let n = l.nrows();
    // Room for the wider tiles, whichever copy runs.
    let len = n.div_ceil(WIDE_TILE) * n * WIDE_TILE;
    out.resize(n * n, 0.0);
    // Not cleared: every entry read below is written first (zeroing them all was a tenth of
    // the inverse's time), but for the padding rows of L zeroed there.
    for buffer in [&mut scratch.rows_of_l, &mut scratch.m] {
        buffer.resize(len, 0.0);
    }
    // Three slices apart, so the compiler knows that no store into one changes the others.
    inverse(l.as_slice(), n, &mut scratch.rows_of_l, &mut scratch.m, out);
}

crate::simd::with_avx!(
    /// [`inverse_of`], with AVX (or AVX-512, wider tiles) where the processor has it.
    fn inverse(l: &[f64], n: usize, rows_of_l: &mut [f64], m: &mut [f64], out: &mut [f64]) -> () = narrow,
    avx512 = inverse_of::<WIDE_TILE, true>
);

/// [`inverse_of`] with tiles for 256-bit vectors.
#[inline(always)]
fn narrow(l: &[f64], n: usize, rows_of_l: &mut [f64], m: &mut [f64], out: &mut [f64]) {
    inverse_of::<TILE, false>(l, n, rows_of_l, m, out);
}

/// [`upper_inverse`] on a column-major slice, into `inverse` (n², only i ≤ j written), with
/// `rows_of_l` and `m` at least ⌈n/TILE⌉·TILE·n long (their contents do not matter). With `WIDE` (only where the
/// processor has AVX-512F, and TILE 8), the inner loops use AVX-512 instructions written out.
///
/// Both factors are first laid out in panels of TILE (rows of L, columns of M) so that every
/// tile reads its two operands from consecutive addresses, k after k.
#[inline(always)]
fn inverse_of<const TILE: usize, const WIDE: bool>(
    l: &[f64],
    n: usize,
    rows_of_l: &mut [f64],
    m: &mut [f64],
    inverse: &mut [f64],
) {
    let panel_len = n * TILE;
    let len = n.div_ceil(TILE) * panel_len;
    let (rows_of_l, m) = (&mut rows_of_l[..len], &mut m[..len]);
    #[cfg(target_arch = "x86_64")]
    let wide = WIDE && TILE == WIDE_TILE;
    // Rows of L in panels: `rows_of_l[p][k][r]` = L(TILE·p + r, k) for k ≤ TILE·p + r (nothing
    // reads the entries above the diagonal).
    for k in 0..n {
        for i in k..n {
            rows_of_l[(i / TILE) * panel_len + k * TILE + i % TILE] = l[i + k * n];
        }
    }
    // The rows past n of the last panel: tiles read them (and store nothing they make), so
    // they must be finite; a buffer of another size may hold anything there.
    if !n.is_multiple_of(TILE) {
        let last = &mut rows_of_l[(n / TILE) * panel_len..];
        for row in last.chunks_exact_mut(TILE) {
            row[n % TILE..].fill(0.0);
        }
    }
    // M = L⁻¹ in column panels: `m[p][k][c]` = M(k, TILE·p + c) for k ≥ TILE·p (the rows
    // above are never read); the tiles compute the entries above the diagonal, and the padding
    // columns past n, as exact zeros.
    for (p, panel) in m.chunks_exact_mut(panel_len).enumerate() {
        let j0 = p * TILE;
        for i0 in (j0..n).step_by(TILE) {
            let rows = TILE.min(n - i0);
            let l_rows = &rows_of_l[(i0 / TILE) * panel_len..(i0 / TILE + 1) * panel_len];
            let mut acc = [[0.0f64; TILE]; TILE];
            for (r, row) in acc.iter_mut().enumerate() {
                for (c, value) in row.iter_mut().enumerate() {
                    if i0 + r == j0 + c {
                        *value = 1.0;
                    }
                }
            }
            // Rows j0 … i0 − 1 of M are final: their updates first, in increasing k (rows of
            // the tile past n compute on zeros and are never stored).
            let (done, tile_rows) = panel.split_at_mut(i0 * TILE);
            let (done, l_done) = (&done[j0 * TILE..], &l_rows[j0 * TILE..i0 * TILE]);
            #[cfg(target_arch = "x86_64")]
            if wide {
                // SAFETY: `wide` is only set in the copy that runs where the processor has
                // AVX-512F.
                unsafe { subtract_avx512(acc.as_flattened_mut(), done, l_done) };
            }
            #[cfg(target_arch = "x86_64")]
            let done = if wide { &done[..0] } else { done };
            for (mk, lk) in done.chunks_exact(TILE).zip(l_done.chunks_exact(TILE)) {
                for r in 0..TILE {
                    for c in 0..TILE {
                        acc[r][c] -= mk[c] * lk[r];
                    }
                }
            }
            // Then the tile's own rows, top down.
            for (r, row) in acc.iter_mut().enumerate().take(rows) {
                let i = i0 + r;
                for k in i0..i {
                    let lik = l_rows[k * TILE + r];
                    for (c, value) in row.iter_mut().enumerate() {
                        *value -= tile_rows[(k - i0) * TILE + c] * lik;
                    }
                }
                let d = l_rows[i * TILE + r];
                for (c, value) in row.iter().enumerate() {
                    tile_rows[r * TILE + c] = value / d;
                }
            }
        }
    }
    // (K⁻¹)_ij for the columns j0 … j0 + 3 and every i ≤ j: sums over k ≥ j0 (M_kj = 0 below
    // j, and adding those exact zeros changes no bit).
    let mut store = |acc: &[[f64; TILE]; TILE], i0: usize, j0: usize| {
        for (r, row) in acc.iter().enumerate() {
            for (c, value) in row.iter().enumerate() {
                let (i, j) = (i0 + r, j0 + c);
                if i <= j && j < n {
                    inverse[i + j * n] = *value;
                }
            }
        }
    };
    for (q, mj_panel) in m.chunks_exact(panel_len).enumerate() {
        let j0 = q * TILE;
        let mj_rows = || mj_panel[j0 * TILE..].chunks_exact(TILE);
        // Two row tiles at a time: eight independent chains hide the latency of an addition.
        let mut p = 0;
        while p < q {
            let (a, b) = (&m[p * panel_len..], &m[(p + 1) * panel_len..]);
            let (mut acc_a, mut acc_b) = ([[0.0f64; TILE]; TILE], [[0.0f64; TILE]; TILE]);
            let (a, b) = (&a[j0 * TILE..panel_len], &b[j0 * TILE..panel_len]);
            #[cfg(target_arch = "x86_64")]
            if wide {
                let mj = &mj_panel[j0 * TILE..];
                // SAFETY: as above.
                unsafe { add_products_avx512(acc_a.as_flattened_mut(), a, mj) };
                unsafe { add_products_avx512(acc_b.as_flattened_mut(), b, mj) };
            }
            #[cfg(target_arch = "x86_64")]
            let (a, b) = if wide { (&a[..0], &b[..0]) } else { (a, b) };
            let rows = a.chunks_exact(TILE).zip(b.chunks_exact(TILE));
            for ((ma, mb), mj) in rows.zip(mj_rows()) {
                for r in 0..TILE {
                    for c in 0..TILE {
                        acc_a[r][c] += ma[r] * mj[c];
                        acc_b[r][c] += mb[r] * mj[c];
                    }
                }
            }
            store(&acc_a, p * TILE, j0);
            store(&acc_b, (p + 1) * TILE, j0);
            p += 2;
        }
        if p <= q {
            let mi_panel = &m[p * panel_len..(p + 1) * panel_len];
            let mut acc = [[0.0f64; TILE]; TILE];
            let mi_rows = &mi_panel[j0 * TILE..];
            #[cfg(target_arch = "x86_64")]
            if wide {
                // SAFETY: as above.
                unsafe {
                    add_products_avx512(acc.as_flattened_mut(), mi_rows, &mj_panel[j0 * TILE..])
                };
            }
            #[cfg(target_arch = "x86_64")]
            let mi_rows = if wide { &mi_rows[..0] } else { mi_rows };
            for (mi, mj) in mi_rows.chunks_exact(TILE).zip(mj_rows()) {
                for r in 0..TILE {
                    for c in 0..TILE {
                        acc[r][c] += mi[r] * mj[c];
                    }
                }
            }
            store(&acc, p * TILE, j0);
        }
    }
}

/// [`upper_inverse`] with tiles of `tile` (4 or 8) rows and columns, without the AVX-512 loops:
/// the copies the dispatch does not run on this processor.
#[cfg(test)]
pub(super) fn upper_inverse_with_tiles(l: &DMatrix<f64>, tile: usize) -> Vec<f64> {
    let n = l.nrows();
    let len = n.div_ceil(WIDE_TILE) * n * WIDE_TILE;
    let (mut rows_of_l, mut m, mut out) =
        (vec![f64::NAN; len], vec![f64::NAN; len], vec![0.0; n * n]);
    match tile {
        TILE => inverse_of::<TILE, false>(l.as_slice(), n, &mut rows_of_l, &mut m, &mut out),
        _ => inverse_of::<WIDE_TILE, false>(l.as_slice(), n, &mut rows_of_l, &mut m, &mut out),
    }
    out
}

/// Lanes of an AVX-512 register of f64.
#[cfg(target_arch = "x86_64")]
const LANES: usize = 8;

/// acc[r][c] −= mk[c]·lk[r] for each row k of `m_rows` and `l_rows` (8 values a row), in order,
/// on an 8 × 8 tile `acc` (row-major): the chains of the narrow loop, eight columns a register.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn subtract_avx512(acc: &mut [f64], m_rows: &[f64], l_rows: &[f64]) {
    use std::arch::x86_64::{_mm512_mul_pd, _mm512_set1_pd, _mm512_sub_pd};
    let mut tile = load_tile(acc);
    for (mk, lk) in m_rows.chunks_exact(LANES).zip(l_rows.chunks_exact(LANES)) {
        let mk = load(mk);
        for (row, &lkr) in tile.iter_mut().zip(lk) {
            *row = _mm512_sub_pd(*row, _mm512_mul_pd(mk, _mm512_set1_pd(lkr)));
        }
    }
    store_tile(acc, &tile);
}

/// acc[r][c] += mi[r]·mj[c] for each row k of `mi_rows` and `mj_rows` (8 values a row), in order,
/// on an 8 × 8 tile `acc` (row-major).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn add_products_avx512(acc: &mut [f64], mi_rows: &[f64], mj_rows: &[f64]) {
    use std::arch::x86_64::{_mm512_add_pd, _mm512_mul_pd, _mm512_set1_pd};
    let mut tile = load_tile(acc);
    for (mi, mj) in mi_rows.chunks_exact(LANES).zip(mj_rows.chunks_exact(LANES)) {
        let mj = load(mj);
        for (row, &mir) in tile.iter_mut().zip(mi) {
            *row = _mm512_add_pd(*row, _mm512_mul_pd(_mm512_set1_pd(mir), mj));
        }
    }
    store_tile(acc, &tile);
}

/// Eight values into a register.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
fn load(values: &[f64]) -> std::arch::x86_64::__m512d {
    let values: &[f64; LANES] = values[..LANES].try_into().unwrap_or(&[0.0; LANES]);
    // SAFETY: `values` holds eight f64.
    unsafe { std::arch::x86_64::_mm512_loadu_pd(values.as_ptr()) }
}

/// An 8 × 8 row-major tile into eight registers.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
fn load_tile(acc: &[f64]) -> [std::arch::x86_64::__m512d; LANES] {
    let mut tile = [std::arch::x86_64::_mm512_setzero_pd(); LANES];
    for (row, values) in tile.iter_mut().zip(acc.chunks_exact(LANES)) {
        *row = load(values);
    }
    tile
}

/// Eight registers back into an 8 × 8 row-major tile.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
fn store_tile(acc: &mut [f64], tile: &[std::arch::x86_64::__m512d; LANES]) {
    for (values, row) in acc.chunks_exact_mut(LANES).zip(tile) {
        let values: &mut [f64; LANES] = match values.try_into() {
            Ok(values) => values,
            Err(_) => return,
        };
        // SAFETY: `values` holds eight f64.
        unsafe { std::arch::x86_64::_mm512_storeu_pd(values.as_mut_ptr(), *row) };
    }
}
