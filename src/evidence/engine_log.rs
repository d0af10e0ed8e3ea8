//! The Dempster step of [`super::Engine`] in log scale, apart so that the engine's file stays
//! short.

use super::{hash_words, Arena, Engine, OverLimit};

/// ln(eˣ + eʸ) without overflow or underflow.
pub(super) fn log_add(x: f64, y: f64) -> f64 {
    let (hi, lo) = if x >= y { (x, y) } else { (y, x) };
    if lo == f64::NEG_INFINITY {
        return hi;
    }
    hi + (lo - hi).exp().ln_1p()
}

impl Engine {
    /// The Dempster step in log scale (masses of `cur`, `b` and `out` are natural logs), for when
    /// some product of masses would not be a normal f64 (two masses of 1e-200): out ← the merged
    /// non-empty intersections. Returns the log of their total mass, or `None` when no pair
    /// intersects (total conflict).
    #[cold]
    pub(super) fn step_log(
        &mut self,
        cur: &Arena,
        b: &Arena,
        out: &mut Arena,
    ) -> Result<Option<f64>, OverLimit> {
        let w = self.w;
        let mut mask = self.prepare(cur.len() * b.len(), out);
        let mut x = vec![0u64; w];
        for (a, &la) in cur.words.chunks_exact(w).zip(&cur.mass) {
            for (bw, &lb) in b.words.chunks_exact(w).zip(&b.mass) {
                let mut any = 0u64;
                for ((xk, ak), bk) in x.iter_mut().zip(a).zip(bw) {
                    *xk = ak & bk;
                    any |= *xk;
                }
                if any == 0 || la + lb == f64::NEG_INFINITY {
                    continue;
                }
                let h = hash_words(&x, &self.keys);
                if 2 * out.len() >= mask {
                    mask = self.grow(out);
                }
                Self::insert::<true>(&mut self.table, mask, out, (&x, h, la + lb), self.max_sets)?;
            }
        }
        let total = out
            .mass
            .iter()
            .fold(f64::NEG_INFINITY, |s, &l| log_add(s, l));
        Ok((total > f64::NEG_INFINITY).then_some(total))
    }
}
