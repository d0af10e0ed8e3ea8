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
    let n = l.nrows();
    super::simd::dispatch(|| inverse_of(l.as_slice(), n))
}

/// [`upper_inverse`] on a column-major slice.
#[inline(always)]
fn inverse_of(l: &[f64], n: usize) -> Vec<f64> {
    // M = L⁻¹ row-major, rows padded to a multiple of 4 columns (zero columns): a tile's four
    // values of one row of M are adjacent. Entries above the diagonal stay exactly 0.
    let width = n.div_ceil(TILE) * TILE;
    let mut m = vec![0.0; n * width];
    for j0 in (0..n).step_by(TILE) {
        for i0 in (j0..n).step_by(TILE) {
            let rows = TILE.min(n - i0);
            let mut acc = [[0.0f64; TILE]; TILE];
            for (r, row) in acc.iter_mut().enumerate().take(rows) {
                for (c, value) in row.iter_mut().enumerate() {
                    if i0 + r == j0 + c {
                        *value = 1.0;
                    }
                }
            }
            // Rows j0 … i0 − 1 of M are final: their updates first, in increasing k.
            if rows == TILE {
                let rows_of_m = m[j0 * width..i0 * width].chunks_exact(width);
                let columns_of_l = l[j0 * n..i0 * n].chunks_exact(n);
                for (row, column) in rows_of_m.zip(columns_of_l) {
                    let mk: [f64; TILE] = row[j0..j0 + TILE].try_into().unwrap_or([0.0; TILE]);
                    let lk: [f64; TILE] = column[i0..i0 + TILE].try_into().unwrap_or([0.0; TILE]);
                    for r in 0..TILE {
                        for c in 0..TILE {
                            acc[r][c] -= mk[c] * lk[r];
                        }
                    }
                }
            } else {
                for k in j0..i0 {
                    for (r, row) in acc.iter_mut().enumerate().take(rows) {
                        let lik = l[i0 + r + k * n];
                        for (c, value) in row.iter_mut().enumerate() {
                            *value -= m[k * width + j0 + c] * lik;
                        }
                    }
                }
            }
            // Then the tile's own rows, top down.
            for (r, row) in acc.iter_mut().enumerate().take(rows) {
                let i = i0 + r;
                for k in i0..i {
                    let lik = l[i + k * n];
                    for (c, value) in row.iter_mut().enumerate() {
                        *value -= m[k * width + j0 + c] * lik;
                    }
                }
                let d = l[i + i * n];
                for (c, value) in row.iter().enumerate() {
                    m[i * width + j0 + c] = value / d;
                }
            }
        }
    }
    // (K⁻¹)_ij for the columns j0 … j0 + 3 and every i ≤ j: sums over k ≥ j0 (M_kj = 0 below
    // j, and adding those exact zeros changes no bit).
    let mut inverse = vec![0.0; n * n];
    for j0 in (0..n).step_by(TILE) {
        for i0 in (0..(j0 + TILE).min(n)).step_by(TILE) {
            let mut acc = [[0.0f64; TILE]; TILE];
            for row in m[j0 * width..].chunks_exact(width) {
                let mi: [f64; TILE] = row[i0..i0 + TILE].try_into().unwrap_or([0.0; TILE]);
                let mj: [f64; TILE] = row[j0..j0 + TILE].try_into().unwrap_or([0.0; TILE]);
                for r in 0..TILE {
                    for c in 0..TILE {
                        acc[r][c] += mi[r] * mj[c];
                    }
                }
            }
            for (r, row) in acc.iter().enumerate() {
                for (c, value) in row.iter().enumerate() {
                    let (i, j) = (i0 + r, j0 + c);
                    if i <= j && j < n {
                        inverse[i + j * n] = *value;
                    }
                }
            }
        }
    }
    inverse
}
