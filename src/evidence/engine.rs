//! The combination engine behind [`super::combine`]: the focal sets of the running combination
//! in one flat word arena, identical intersections merged after every step with an
//! open-addressing table, so a step costs one AND, one hash and (rarely) one comparison per pair
//! of focal sets, with no allocation per pair; bounded by [`WorkLimits`].

use super::limits::{WorkLimit, WorkLimits};
use super::mass::MassFunction;
use super::subset::word_count;
use super::EvidenceError;

const EMPTY_SLOT: u64 = u64::MAX;
const MIX: u64 = 0x9E37_79B9_7F4A_7C15;

/// Table slot of a pre-hash in a table of `mask + 1` slots, and its tag: one multiply, the slot
/// from the product's top bits (the best mixed; a multiply's low bits depend on few input bits).
#[inline(always)]
fn slot_and_tag(h: u64, mask: usize) -> (usize, u64) {
    let hf = h.wrapping_mul(MIX);
    (
        (hf >> (mask as u64).leading_zeros()) as usize,
        hf & 0xFFFF_FFFF_0000_0000,
    )
}

const fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(MIX);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// Odd key of word `k` for [`hash_words`]: 31 bits, so that a multiply by it takes an immediate.
const fn key(k: u64) -> u64 {
    (splitmix(k) >> 33) | 1
}

/// Pre-hash of a set: Σ wordₖ·keyₖ with odd per-word keys (one plain multiply per word; the
/// mix is applied once per set by [`slot_and_tag`]). Equal sets hash equally, and collisions only
/// cost a word comparison.
#[inline(always)]
fn hash_words(x: &[u64], keys: &[u64]) -> u64 {
    x.iter()
        .zip(keys)
        .fold(0u64, |h, (xk, key)| h.wrapping_add(xk.wrapping_mul(*key)))
}

/// Focal sets of one function in a flat arena (non-empty sets only; ∅ mass kept apart).
#[derive(Default)]
struct Arena {
    words: Vec<u64>,
    mass: Vec<f64>,
}

impl Arena {
    fn len(&self) -> usize {
        self.mass.len()
    }

    fn clear(&mut self) {
        self.words.clear();
        self.mass.clear();
    }

    /// Load a function; returns its mass on ∅.
    fn load(&mut self, f: &MassFunction) -> f64 {
        self.clear();
        let mut empty = 0.0;
        for (s, &m) in f.set_words().zip(f.masses()) {
            if s.iter().all(|&x| x == 0) {
                empty += m;
            } else {
                self.words.extend_from_slice(s);
                self.mass.push(m);
            }
        }
        empty
    }
}

/// Buffers reused between combinations on the same thread, so that steady-state combination
/// does not allocate (large fresh buffers cost page faults that dominate small combinations).
#[derive(Default)]
struct Scratch {
    cur: Arena,
    next: Arena,
    b: Arena,
    table: Vec<u64>,
}

/// Table slots allocated up front are at most twice this.
#[cfg(not(test))]
const INITIAL_SLOTS: usize = 1 << 16;
/// Tiny in unit tests, so that the property tests exercise [`Engine::grow`].
#[cfg(test)]
const INITIAL_SLOTS: usize = 4;

/// Below this running mass, Dempster mode divides the running result by it instead of scaling
/// the next function's masses by its inverse.
const RESCALE_BELOW: f64 = 1e-150;

/// Buffers larger than this (in words) are released after use instead of being kept.
const KEEP_WORDS: usize = 1 << 20;

impl Scratch {
    fn trim(&mut self) {
        for a in [&mut self.cur, &mut self.next, &mut self.b] {
            if a.words.capacity() > KEEP_WORDS || a.mass.capacity() > KEEP_WORDS {
                *a = Arena::default();
            }
        }
        if self.table.capacity() > KEEP_WORDS {
            self.table = Vec::new();
        }
    }
}

thread_local! {
    static SCRATCH: std::cell::Cell<Option<Box<Scratch>>> = const { std::cell::Cell::new(None) };
}

struct Engine {
    w: usize,
    keys: Vec<u64>,
    table: Vec<u64>,
    limits: WorkLimits,
    /// Sets a result may hold within the limits.
    max_sets: usize,
}

/// A step stopped because its result would exceed the [`WorkLimits`].
struct OverLimit;

impl Engine {
    fn new(n: usize, table: Vec<u64>, limits: WorkLimits) -> Self {
        let w = word_count(n);
        Engine {
            w,
            keys: (0..w as u64).map(key).collect(),
            table,
            limits,
            max_sets: limits.max_sets(w),
        }
    }

    /// The limit a function of more than `max_sets` sets breaks, as an error.
    fn over(&self) -> EvidenceError {
        match self.limits.check(self.max_sets.saturating_add(1), self.w) {
            Err(e) => e,
            Ok(()) => EvidenceError::WorkLimit {
                limit: WorkLimit::FocalSets,
                max: self.limits.focal_sets,
            },
        }
    }

    /// out ← merged non-empty intersections of cur × b; returns the masses of the empty and of the
    /// non-empty intersections.
    fn step(&mut self, cur: &Arena, b: &Arena, out: &mut Arena) -> Result<(f64, f64), OverLimit> {
        match self.w {
            1 => self.step_w::<1, false>(cur, b, out),
            2 => self.step_w::<2, false>(cur, b, out),
            3 => self.step_w::<3, false>(cur, b, out),
            4 => self.step_w::<4, false>(cur, b, out),
            5 => self.step_w::<5, false>(cur, b, out),
            6 => self.step_w::<6, false>(cur, b, out),
            7 => self.step_w::<7, false>(cur, b, out),
            8 => self.step_w::<8, false>(cur, b, out),
            _ => self.step_dyn::<false>(cur, b, out),
        }
    }

    /// As [`Engine::step`] with unions in place of intersections (the disjunctive rule).
    fn step_or(
        &mut self,
        cur: &Arena,
        b: &Arena,
        out: &mut Arena,
    ) -> Result<(f64, f64), OverLimit> {
        match self.w {
            1 => self.step_w::<1, true>(cur, b, out),
            2 => self.step_w::<2, true>(cur, b, out),
            4 => self.step_w::<4, true>(cur, b, out),
            7 => self.step_w::<7, true>(cur, b, out),
            _ => self.step_dyn::<true>(cur, b, out),
        }
    }

    /// Clear `out` and size the table for the expected number of sets (at most `INITIAL_SLOTS`
    /// slots up front; [`Engine::grow`] doubles it when it fills, so a huge number of pairs with
    /// few distinct intersections does not allocate a huge table).
    fn prepare(&mut self, pairs: usize, out: &mut Arena) -> usize {
        // 1.5 slots per pair: late steps merge many pairs, and a smaller table stays in cache.
        let cap = (pairs.min(INITIAL_SLOTS) * 3 / 2)
            .next_power_of_two()
            .max(16);
        self.table.clear();
        self.table.resize(cap, EMPTY_SLOT);
        out.clear();
        let expected = pairs.min(self.max_sets);
        out.mass.reserve(expected.min(INITIAL_SLOTS));
        // At most 1 MiB up front: sets of a huge frame are megabytes each.
        out.words
            .reserve((expected.min(1024) * self.w).min(1 << 17));
        cap - 1
    }

    /// Keep the table at most half full: double it and re-insert every set. Returns the new mask.
    #[cold]
    fn grow(&mut self, out: &Arena) -> usize {
        let w = self.w;
        let cap = 2 * self.table.len();
        self.table.clear();
        self.table.resize(cap, EMPTY_SLOT);
        let mask = cap - 1;
        for (i, words) in out.words.chunks_exact(w).enumerate() {
            let h = hash_words(words, &self.keys);
            let (mut pos, tag) = slot_and_tag(h, mask);
            while self.table[pos] != EMPTY_SLOT {
                pos = (pos + 1) & mask;
            }
            self.table[pos] = tag | i as u64;
        }
        mask
    }

    /// Add mass `m` to the set `x` (hash `h`): merge with an equal set already in `out`, or append
    /// unless `out` holds `max_sets` sets already. Table entries hold the set's index in the low
    /// 32 bits and a hash tag in the high 32 bits, so most mismatches are rejected without
    /// touching the arena.
    #[inline(always)]
    fn insert<const LOG: bool>(
        table: &mut [u64],
        mask: usize,
        out: &mut Arena,
        (x, h, m): (&[u64], u64, f64),
        max_sets: usize,
    ) -> Result<(), OverLimit> {
        let w = x.len();
        let (mut pos, tag) = slot_and_tag(h, mask);
        loop {
            let e = table[pos];
            if e == EMPTY_SLOT {
                if out.mass.len() >= max_sets {
                    return Err(OverLimit);
                }
                table[pos] = tag | out.mass.len() as u64;
                out.mass.push(m);
                out.words.extend_from_slice(x);
                return Ok(());
            }
            if e & 0xFFFF_FFFF_0000_0000 == tag {
                let i = (e & 0xFFFF_FFFF) as usize;
                let stored = &out.words[i * w..(i + 1) * w];
                // Word loop rather than slice equality, which would call memcmp.
                if stored.iter().zip(x).all(|(a, b)| a == b) {
                    if LOG {
                        out.mass[i] = log_add(out.mass[i], m);
                    } else {
                        out.mass[i] += m;
                    }
                    return Ok(());
                }
            }
            pos = (pos + 1) & mask;
        }
    }

    fn step_w<const W: usize, const OR: bool>(
        &mut self,
        cur: &Arena,
        b: &Arena,
        out: &mut Arena,
    ) -> Result<(f64, f64), OverLimit> {
        let mut mask = self.prepare(cur.len() * b.len(), out);
        let keys: [u64; W] = std::array::from_fn(|k| key(k as u64));
        let mut empty = 0.0;
        let mut kept = 0.0;
        for (a, &ma) in cur.words.chunks_exact(W).zip(&cur.mass) {
            for (bw, &mb) in b.words.chunks_exact(W).zip(&b.mass) {
                let mut x = [0u64; W];
                let mut any = 0u64;
                for k in 0..W {
                    x[k] = if OR { a[k] | bw[k] } else { a[k] & bw[k] };
                    any |= x[k];
                }
                if any == 0 {
                    empty += ma * mb;
                    continue;
                }
                let h = hash_words(&x, &keys);
                if 2 * out.len() >= mask {
                    mask = self.grow(out);
                }
                kept += ma * mb;
                Self::insert::<false>(&mut self.table, mask, out, (&x, h, ma * mb), self.max_sets)?;
            }
        }
        Ok((empty, kept))
    }

    fn step_dyn<const OR: bool>(
        &mut self,
        cur: &Arena,
        b: &Arena,
        out: &mut Arena,
    ) -> Result<(f64, f64), OverLimit> {
        let w = self.w;
        let mut mask = self.prepare(cur.len() * b.len(), out);
        let mut empty = 0.0;
        let mut kept = 0.0;
        let mut x = vec![0u64; w];
        for (a, &ma) in cur.words.chunks_exact(w).zip(&cur.mass) {
            for (bw, &mb) in b.words.chunks_exact(w).zip(&b.mass) {
                let mut any = 0u64;
                for ((xk, ak), bk) in x.iter_mut().zip(a).zip(bw) {
                    *xk = if OR { ak | bk } else { ak & bk };
                    any |= *xk;
                }
                if any == 0 {
                    empty += ma * mb;
                    continue;
                }
                let h = hash_words(&x, &self.keys);
                if 2 * out.len() >= mask {
                    mask = self.grow(out);
                }
                kept += ma * mb;
                Self::insert::<false>(&mut self.table, mask, out, (&x, h, ma * mb), self.max_sets)?;
            }
        }
        Ok((empty, kept))
    }
}

#[path = "engine_log.rs"]
mod log;
use log::log_add;

pub(super) fn frame_of<'a, I: IntoIterator<Item = &'a MassFunction>>(
    fs: I,
) -> Result<(usize, Vec<&'a MassFunction>), EvidenceError> {
    let fs: Vec<&MassFunction> = fs.into_iter().collect();
    let first = fs.first().ok_or(EvidenceError::NothingToCombine)?;
    let n = first.frame_size();
    for f in &fs {
        if f.frame_size() != n {
            return Err(EvidenceError::FrameMismatch {
                expected: n,
                found: f.frame_size(),
            });
        }
    }
    Ok((n, fs))
}

/// What the engine hands to the caller's `finish`.
pub(super) struct Outcome<'s> {
    n: usize,
    arena: &'s Arena,
    /// Mass on ∅ (disjunctive mode only: the inputs' mass on ∅ that met only ∅).
    empty: f64,
    /// Accumulated level of conflict (Dempster mode only).
    pub(super) level: f64,
}

/// How [`run`] combines.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum Mode {
    /// Dempster's rule: renormalised after every step, the steps' levels added.
    Dempster,
    /// The unnormalised disjunctive rule (unions; the total mass stays 1).
    Disjunctive,
}

/// The smallest product of masses the fast Dempster step may form: below it a product would be
/// subnormal or 0 and its focal set lost or imprecise, so the rest of the combination runs in
/// log scale.
const SMALLEST_PRODUCT: f64 = f64::MIN_POSITIVE;

/// Combine in `mode`. In Dempster mode the running result is renormalised after every step and
/// the step's level of conflict added (Theorem 4.3); when a product of masses could leave the
/// normal range, the rest runs in log scale, so no focal set is lost to underflow and the level
/// is exact whatever the order. Returns `None` in Dempster mode on total conflict, else `finish`
/// of the outcome.
///
/// # Errors
/// [`EvidenceError::WorkLimit`] when an input or a running result exceeds `limits`.
pub(super) fn run<R>(
    n: usize,
    fs: &[&MassFunction],
    (mode, limits): (Mode, &WorkLimits),
    finish: impl FnOnce(Outcome<'_>) -> R,
) -> Result<Option<R>, EvidenceError> {
    let mut scratch = SCRATCH.with(|c| c.take()).unwrap_or_default();
    let engine = Engine::new(n, std::mem::take(&mut scratch.table), *limits);
    let result = run_in(&mut scratch, engine, fs, mode, finish);
    scratch.trim();
    SCRATCH.with(|c| c.set(Some(scratch)));
    result
}

fn min_mass(a: &Arena) -> f64 {
    a.mass.iter().fold(f64::INFINITY, |m, &x| m.min(x))
}

fn run_in<R>(
    scratch: &mut Scratch,
    mut engine: Engine,
    fs: &[&MassFunction],
    mode: Mode,
    finish: impl FnOnce(Outcome<'_>) -> R,
) -> Result<Option<R>, EvidenceError> {
    let n = fs.first().map_or(0, |f| f.frame_size());
    let normalise = mode == Mode::Dempster;
    let over = |engine: Engine, scratch_table: &mut Vec<u64>| {
        let e = engine.over();
        *scratch_table = engine.table;
        e
    };
    if fs.iter().any(|f| f.len() > engine.max_sets) {
        return Err(over(engine, &mut scratch.table));
    }
    let Scratch {
        cur,
        next,
        b,
        table: scratch_table,
    } = scratch;
    let mut empty = 0.0;
    let mut level = 0.0;
    // In Dempster mode the running result has total mass `s` instead of 1; rather than rescale
    // its many focal sets after every step, the next function's few masses are scaled by 1/s
    // (same products up to rounding), and only the final result is rescaled.
    let mut s = 1.0;
    // Whether `cur` holds normalised log masses (Dempster mode only).
    let mut logged = false;
    let mut low = 0.0;
    for (i, f) in fs.iter().enumerate() {
        if i == 0 {
            empty = cur.load(f);
            s = cur.mass.iter().sum();
            low = min_mass(cur);
        } else {
            let b_empty = b.load(f);
            if normalise {
                if !logged {
                    // `low` bounds the running masses from below; the exact minimum is looked
                    // up only when the bound is too low, so the usual step costs no pass.
                    let bs = min_mass(b) / s;
                    if low * bs < SMALLEST_PRODUCT {
                        low = min_mass(cur);
                    }
                    if low * bs < SMALLEST_PRODUCT {
                        for m in &mut cur.mass {
                            *m = m.ln() - s.ln();
                        }
                        logged = true;
                    } else {
                        low *= bs;
                    }
                }
                if logged {
                    for m in &mut b.mass {
                        *m = m.ln();
                    }
                    let Ok(total) = engine.step_log(cur, b, next) else {
                        return Err(over(engine, scratch_table));
                    };
                    let Some(total) = total else {
                        *scratch_table = engine.table;
                        return Ok(None);
                    };
                    for m in &mut next.mass {
                        *m -= total;
                    }
                    level += (-total).max(0.0);
                } else {
                    for m in &mut b.mass {
                        *m /= s;
                    }
                    let Ok((_, kept)) = engine.step(cur, b, next) else {
                        return Err(over(engine, scratch_table));
                    };
                    s = kept;
                }
            } else {
                let b_total: f64 = b_empty + b.mass.iter().sum::<f64>();
                let cur_total: f64 = cur.mass.iter().sum();
                let total = (empty + cur_total) * b_total;
                let Ok((conflict, kept)) = engine.step_or(cur, b, next) else {
                    return Err(over(engine, scratch_table));
                };
                empty = empty * b_empty + conflict;
                // The masses sum to `total` (1 for mass functions): when ∅ is the larger part,
                // total − kept is the more precise.
                if empty > 0.5 * total {
                    empty = (total - kept).clamp(0.0, 1.0);
                }
            }
            std::mem::swap(cur, next);
        }
        if normalise && !logged {
            if cur.len() == 0 || s <= 0.0 {
                *scratch_table = engine.table;
                return Ok(None);
            }
            level += (-s.ln()).max(0.0);
            // A running mass this small would overflow 1/s on the next function: rescale the
            // running result itself.
            if s < RESCALE_BELOW {
                for m in &mut cur.mass {
                    *m /= s;
                }
                low /= s;
                s = cur.mass.iter().sum();
            }
        }
    }
    *scratch_table = engine.table;
    if logged {
        // Back from logs: sets whose mass is below the smallest f64 are dropped from the result
        // (the level already counts them).
        let w = engine.w;
        let mut kept = 0;
        for k in 0..cur.mass.len() {
            let m = cur.mass[k].exp();
            if m > 0.0 {
                cur.mass[kept] = m;
                cur.words.copy_within(k * w..(k + 1) * w, kept * w);
                kept += 1;
            }
        }
        cur.mass.truncate(kept);
        cur.words.truncate(kept * w);
        s = cur.mass.iter().sum();
    }
    if normalise {
        for m in &mut cur.mass {
            *m /= s;
        }
        empty = 0.0;
    }
    Ok(Some(finish(Outcome {
        n,
        arena: cur,
        empty,
        level,
    })))
}

/// The result as a function that keeps the arena's words; subsets are built only when asked for.
pub(super) fn to_mass_function(out: Outcome<'_>, keep_empty: bool) -> MassFunction {
    let w = word_count(out.n).max(1);
    let with_empty = keep_empty && out.empty > 0.0;
    let sets = out.arena.len() + usize::from(with_empty);
    let mut words = Vec::with_capacity(sets * w);
    words.extend_from_slice(&out.arena.words);
    let mut mass = Vec::with_capacity(sets);
    mass.extend_from_slice(&out.arena.mass);
    if with_empty {
        words.resize(sets * w, 0);
        mass.push(out.empty);
    }
    MassFunction::from_words(out.n, words, mass)
}
