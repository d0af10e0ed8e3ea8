//! The radius holding a share of the particles' weight (issue 32): the particles sorted by
//! distance from the estimate and their weights accumulated in that order until they reach the
//! share. The sort is a stable radix sort on the bits of the squared distances (non-negative
//! doubles sort as their bit patterns do): linear time, and the order a stable comparison sort
//! gives, so the weights are summed in the same order and the same particle is found.
//!
//! Most frames need no sort at all: one pass puts the keys in [`SELECT_BUCKETS`] buckets by
//! their high bits with each bucket's weight sum, the running sum over the buckets finds the
//! bucket where the share is crossed, and only that bucket is sorted. Those sums are in another
//! order than the sorted one, so they can differ from it in the last bits: the crossing found is
//! taken only when it is the same key whichever way the sums round within a proven bound
//! ([`WeightedRadius::selected`]); otherwise (equal weights after a resampling, whose sums fall
//! exactly on the share) the full sort decides.

/// Bits per radix digit; six passes cover the 64 bits of a key.
const DIGIT: u32 = 11;
const BUCKETS: usize = 1 << DIGIT;
const PASSES: usize = 64usize.div_ceil(DIGIT as usize);
/// Buckets of the selection's histogram (a power of two), and below how many particles the
/// full sort is as quick.
const SELECT_BUCKETS: usize = 1 << 12;
const SELECT_FROM: usize = 64;

/// Scratch kept between frames: (key bits, weight) pairs, their sorted copy and the digit
/// counts (32 bits: half the memory to clear per frame); the selection's bucket weight sums.
pub(super) struct WeightedRadius {
    pairs: Vec<(u64, f64)>,
    spare: Vec<(u64, f64)>,
    counts: Vec<[u32; BUCKETS]>,
    bucket_sums: Vec<f64>,
}

impl WeightedRadius {
    pub(super) fn with_capacity(n: usize) -> Self {
        Self {
            pairs: Vec::with_capacity(n),
            spare: Vec::with_capacity(n),
            counts: vec![[0; BUCKETS]; PASSES],
            bucket_sums: vec![0.0; SELECT_BUCKETS],
        }
    }

    /// The distance from `centre` within which the particles, taken nearest first, first hold
    /// `share` of the weight; 0 when they never do.
    pub(super) fn radius(
        &mut self,
        particles: &[[f64; 2]],
        weights: &[f64],
        centre: [f64; 2],
        share: f64,
    ) -> f64 {
        self.pairs.clear();
        self.pairs.extend(keyed(particles, weights, centre));
        if let Some(radius) = self.selected(share) {
            return radius;
        }
        self.sort();
        crossing(self.pairs.iter().copied(), share)
    }

    /// The crossing's distance from the bucket holding it (`pairs` unsorted, in the particles'
    /// order), or `None` when the sums cannot tell it from the sorted order's.
    ///
    /// Every running sum here and in the sorted order is a sum of the same non-negative weights
    /// up to a particle, in some order with at most 2n + buckets additions on any path, so each
    /// is within γ(2n + B)·total of the exact one (γ(k) ≤ 1.01·k·u, u = ε/2): two of them differ
    /// by less than `margin`. So a particle whose sum here is below share − margin is below the
    /// share in the sorted order too, and one above share + margin is above it: the sorted
    /// order's crossing lies between the first particle above share − margin and the first
    /// above share + margin, and is their key when those two have the same key.
    fn selected(&mut self, share: f64) -> Option<f64> {
        let n = self.pairs.len();
        if n < SELECT_FROM {
            return None;
        }
        let (mut lo, mut hi, mut usable) = (u64::MAX, 0, true);
        for &(key, w) in &self.pairs {
            lo = lo.min(key);
            hi = hi.max(key);
            usable &= w >= 0.0;
        }
        // Negative or NaN weights: no bound (the sorted order decides).
        if !usable {
            return None;
        }
        let span_bits = u64::BITS - (hi - lo).leading_zeros();
        let shift = span_bits.saturating_sub(SELECT_BUCKETS.trailing_zeros());
        let bucket = |key: u64| ((key - lo) >> shift) as usize;
        self.bucket_sums.fill(0.0);
        for &(key, w) in &self.pairs {
            self.bucket_sums[bucket(key)] += w;
        }
        let total: f64 = self.bucket_sums.iter().sum();
        if !total.is_finite() {
            return None;
        }
        let paths = (4 * n + 2 * SELECT_BUCKETS + 16) as f64;
        let margin = paths * f64::EPSILON * total + f64::MIN_POSITIVE;
        let (low, high) = (share - margin, share + margin);
        // The first bucket whose end is at least share − margin, and the sum before it.
        let mut before = 0.0;
        let mut found = None;
        for (b, &sum) in self.bucket_sums.iter().enumerate() {
            if before + sum >= low {
                found = Some(b);
                break;
            }
            before += sum;
        }
        let found = found?;
        // That bucket's pairs in the particles' order, sorted stably (ties stay in order).
        self.spare.clear();
        self.spare.extend(
            (self.pairs.iter())
                .filter(|(key, _)| bucket(*key) == found)
                .copied(),
        );
        self.spare.sort_by_key(|&(key, _)| key);
        let mut held = before;
        let mut first_low = None;
        for &(key, w) in &self.spare {
            held += w;
            if first_low.is_none() && held >= low {
                first_low = Some(key);
            }
            if held >= high {
                // Both crossings in this bucket: the same key, or undecided.
                return (first_low == Some(key)).then(|| f64::from_bits(key).sqrt());
            }
        }
        None
    }

    /// Stable LSD radix sort of `pairs` by key; a pass whose digit is the same for every key
    /// is skipped (it would not move anything).
    fn sort(&mut self) {
        let n = self.pairs.len();
        for counts in &mut self.counts {
            counts.fill(0);
        }
        for &(key, _) in &self.pairs {
            for (pass, counts) in self.counts.iter_mut().enumerate() {
                counts[digit(key, pass)] += 1;
            }
        }
        self.spare.resize(n, (0, 0.0));
        // At most 1,000,000 particles (`ParticleSettings::check`); the test's sets are smaller.
        let n = n as u32;
        for (pass, counts) in self.counts.iter_mut().enumerate() {
            if counts.contains(&n) {
                continue;
            }
            let mut start = 0;
            for count in counts.iter_mut() {
                (*count, start) = (start, start + *count);
            }
            for &pair in &self.pairs {
                let slot = &mut counts[digit(pair.0, pass)];
                self.spare[*slot as usize] = pair;
                *slot += 1;
            }
            std::mem::swap(&mut self.pairs, &mut self.spare);
        }
    }
}

/// Each particle's (squared distance from `centre`, as bits; weight).
fn keyed<'a>(
    particles: &'a [[f64; 2]],
    weights: &'a [f64],
    centre: [f64; 2],
) -> impl Iterator<Item = (u64, f64)> + 'a {
    particles.iter().zip(weights).map(move |(p, &w)| {
        let d = [p[0] - centre[0], p[1] - centre[1]];
        ((d[0] * d[0] + d[1] * d[1]).to_bits(), w)
    })
}

/// The distance of the first pair at which the running sum of the weights reaches `share`.
fn crossing(pairs: impl Iterator<Item = (u64, f64)>, share: f64) -> f64 {
    let mut held = 0.0;
    let mut pairs = pairs;
    pairs
        .find(|(_, w)| {
            held += w;
            held >= share
        })
        .map_or(0.0, |(key, _)| f64::from_bits(key).sqrt())
}

fn digit(key: u64, pass: usize) -> usize {
    ((key >> (pass as u32 * DIGIT)) & (BUCKETS as u64 - 1)) as usize
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The radius a stable comparison sort of the squared distances finds, summing the
    /// weights nearest first.
    fn sorted_radius(particles: &[[f64; 2]], weights: &[f64], centre: [f64; 2]) -> f64 {
        let mut by_distance: Vec<(f64, f64)> = (particles.iter().zip(weights))
            .map(|(p, &w)| {
                let d = [p[0] - centre[0], p[1] - centre[1]];
                (d[0] * d[0] + d[1] * d[1], w)
            })
            .collect();
        by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut held = 0.0;
        (by_distance.iter())
            .find(|(_, w)| {
                held += w;
                held >= 0.9
            })
            .map_or(0.0, |(d, _)| d.sqrt())
    }

    #[test]
    fn the_radius_is_what_a_stable_sort_finds_bit_for_bit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut radius = WeightedRadius::with_capacity(0);
        let (mut selected, mut random_weights) = (0, 0);
        for case in 0..160 {
            let n = 1 + case * 17 + (case / 40) * 5_000;
            // Coarse positions (ties at equal distance), duplicates, and in every third case
            // equal weights (a resampled set), whose sums the order of ties would not change
            // but whose crossing falls exactly on 0.9 · n; every seventh case's weights hold
            // less than the share (no crossing: 0).
            let particles: Vec<[f64; 2]> = (0..n)
                .map(|k| match k % 5 {
                    0 => [0.25, -0.5],
                    _ => [
                        (rng.random::<f64>() * 40.0).floor() * 0.1,
                        rng.random::<f64>() * 3.0,
                    ],
                })
                .collect();
            let mut weights: Vec<f64> = (0..n)
                .map(|_| match case % 3 {
                    0 => 1.0,
                    _ => rng.random::<f64>().powi(8),
                })
                .collect();
            let total: f64 = weights.iter().sum::<f64>() * if case % 7 == 3 { 2.0 } else { 1.0 };
            weights.iter_mut().for_each(|w| *w /= total);
            let centre = [0.5, 1.0];
            let expected = sorted_radius(&particles, &weights, centre);
            let found = radius.radius(&particles, &weights, centre, 0.9);
            assert_eq!(found.to_bits(), expected.to_bits(), "case {case}");
            // The selection alone, where it decides, and the full sort alone.
            radius.pairs.clear();
            radius.pairs.extend(keyed(&particles, &weights, centre));
            if let Some(r) = radius.selected(0.9) {
                assert_eq!(r.to_bits(), expected.to_bits(), "selected, case {case}");
                selected += 1;
            }
            radius.sort();
            let full = crossing(radius.pairs.iter().copied(), 0.9);
            assert_eq!(full.to_bits(), expected.to_bits(), "sorted, case {case}");
            random_weights += usize::from(case % 3 != 0 && case % 7 != 3 && n >= SELECT_FROM);
        }
        // The selection decides nearly every set of unequal weights.
        assert!(
            selected >= random_weights * 9 / 10,
            "{selected} of {random_weights}"
        );
        assert_eq!(radius.radius(&[], &[], [0.0; 2], 0.9), 0.0);
        assert_eq!(radius.radius(&[[3.0, 4.0]], &[0.5], [0.0; 2], 0.9), 0.0);
        assert_eq!(radius.radius(&[[3.0, 4.0]], &[1.0], [0.0; 2], 0.9), 5.0);
    }

    #[test]
    fn the_selection_leaves_a_crossing_within_its_bound_to_the_sort() {
        // 1,000 equal weights: the sums reach 0.9 at the 900th particle, within rounding.
        let particles: Vec<[f64; 2]> = (0..1000).map(|k| [k as f64 * 0.01, 0.0]).collect();
        let weights = vec![1.0 / 1000.0; 1000];
        let mut radius = WeightedRadius::with_capacity(0);
        radius.pairs.extend(keyed(&particles, &weights, [0.0; 2]));
        assert_eq!(radius.selected(0.9), None);
        let expected = sorted_radius(&particles, &weights, [0.0; 2]);
        let found = radius.radius(&particles, &weights, [0.0; 2], 0.9);
        assert_eq!(found.to_bits(), expected.to_bits());
        // NaN weights: never selected; the sum never reaches the share.
        let nan = vec![f64::NAN; 1000];
        radius.pairs.clear();
        radius.pairs.extend(keyed(&particles, &nan, [0.0; 2]));
        assert_eq!(radius.selected(0.9), None);
        assert_eq!(radius.radius(&particles, &nan, [0.0; 2], 0.9), 0.0);
    }
}
