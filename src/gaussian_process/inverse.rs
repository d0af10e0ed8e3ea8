//! The inverse of a kernel matrix from its Cholesky factor, K⁻¹ = L⁻ᵀL⁻¹, with n³/3
//! multiply-adds in register tiles of 4 × 4 entries.
//!
//! Each entry is one chain of operations in a fixed order: M = L⁻¹ by forward substitution
//! (s ← δ_ij, s ← s − M_kj·L_ik for k = j … i − 1, M_ij = s / L_ii) and (K⁻¹)_ij = Σ_k M_ki·M_kj
//! for k from j upwards. Tiles change which chains run together, never a chain, so the result
//! is the same to the bit as the column-by-column version it replaced (held to it in the tests).

use nalgebra::DMatrix;

/// Rows and columns of a register tile.
const TILE: usize = 4;

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
    let len = n.div_ceil(TILE) * n * TILE;
    out.resize(n * n, 0.0);
    for buffer in [&mut scratch.rows_of_l, &mut scratch.m] {
        buffer.clear();
        buffer.resize(len, 0.0);
    }
    // Three slices apart, so the compiler knows that no store into one changes the others.
    inverse(l.as_slice(), n, &mut scratch.rows_of_l, &mut scratch.m, out);
}

crate::simd::with_avx!(
    /// [`inverse_of`], with AVX where the processor has it.
    fn inverse(l: &[f64], n: usize, rows_of_l: &mut [f64], m: &mut [f64], out: &mut [f64]) -> () = inverse_of
);

/// [`upper_inverse`] on a column-major slice, into `inverse` (n², only i ≤ j written), with
/// `rows_of_l` and `m` zeroed, ⌈n/4⌉·4n long.
///
/// Both factors are first laid out in panels of four (rows of L, columns of M) so that every
/// tile reads its two operands from consecutive addresses, k after k.
#[inline(always)]
fn inverse_of(l: &[f64], n: usize, rows_of_l: &mut [f64], m: &mut [f64], inverse: &mut [f64]) {
    let panel_len = n * TILE;
    // Rows of L in panels: `rows_of_l[p][k][r]` = L(4p + r, k), zero past n and above the
    // diagonal.
    for k in 0..n {
        for i in k..n {
            rows_of_l[(i / TILE) * panel_len + k * TILE + i % TILE] = l[i + k * n];
        }
    }
    // M = L⁻¹ in column panels: `m[p][k][c]` = M(k, 4p + c); entries above the diagonal stay
    // exactly 0, and so do the padding columns past n.
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
            let earlier = done[j0 * TILE..].chunks_exact(TILE);
            for (mk, lk) in earlier.zip(l_rows[j0 * TILE..i0 * TILE].chunks_exact(TILE)) {
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
            let rows = a[j0 * TILE..panel_len].chunks_exact(TILE);
            let rows = rows.zip(b[j0 * TILE..panel_len].chunks_exact(TILE));
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
            for (mi, mj) in mi_panel[j0 * TILE..].chunks_exact(TILE).zip(mj_rows()) {
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
