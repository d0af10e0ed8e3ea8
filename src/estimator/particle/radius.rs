//! The radius holding a share of the particles' weight (issue 32): the particles sorted by
//! distance from the estimate and their weights accumulated in that order until they reach the
//! share. The sort is a stable radix sort on the bits of the squared distances (non-negative
//! doubles sort as their bit patterns do): linear time, and the order a stable comparison sort
//! gives, so the weights are summed in the same order and the same particle is found.

/// Bits per radix digit; six passes cover the 64 bits of a key.
const DIGIT: u32 = 11;
const BUCKETS: usize = 1 << DIGIT;
const PASSES: usize = 64usize.div_ceil(DIGIT as usize);

/// Scratch kept between frames: (key bits, weight) pairs, their sorted copy and the digit
/// counts (32 bits: half the memory to clear per frame).
pub(super) struct WeightedRadius {
    pairs: Vec<(u64, f64)>,
    spare: Vec<(u64, f64)>,
    counts: Vec<[u32; BUCKETS]>,
}

impl WeightedRadius {
    pub(super) fn with_capacity(n: usize) -> Self {
        Self {
            pairs: Vec::with_capacity(n),
            spare: Vec::with_capacity(n),
            counts: vec![[0; BUCKETS]; PASSES],
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
        self.sort_by_distance(particles, weights, centre);
        crossing(self.pairs.iter().copied(), share)
    }

    /// The particles' (squared distance from `centre`, weight) pairs, nearest first, ties in
    /// the particles' order.
    pub(super) fn sort_by_distance(
        &mut self,
        particles: &[[f64; 2]],
        weights: &[f64],
        centre: [f64; 2],
    ) {
        self.pairs.clear();
        self.pairs
            .extend(particles.iter().zip(weights).map(|(p, &w)| {
                let d = [p[0] - centre[0], p[1] - centre[1]];
                ((d[0] * d[0] + d[1] * d[1]).to_bits(), w)
            }));
        self.sort();
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

/// [`WeightedRadius::radius`] of a set split in two, from each part sorted by
/// [`WeightedRadius::sort_by_distance`] (`first` the earlier particles): the stable merge of the
/// two is the whole set's stable order, so the weights are summed in the same order.
pub(super) fn merged_radius(first: &WeightedRadius, second: &WeightedRadius, share: f64) -> f64 {
    let (a, b) = (&first.pairs, &second.pairs);
    let (mut i, mut j) = (0, 0);
    let merged = std::iter::from_fn(|| {
        // On a tie the earlier particle, from `first`, comes first.
        let take_first = match (a.get(i), b.get(j)) {
            (Some(x), Some(y)) => x.0 <= y.0,
            (x, _) => x.is_some(),
        };
        match take_first {
            true => (a.get(i), i += 1).0,
            false => (b.get(j), j += 1).0,
        }
        .copied()
    });
    crossing(merged, share)
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

    #[test]
    fn the_radius_is_what_a_stable_sort_finds_bit_for_bit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut radius = WeightedRadius::with_capacity(0);
        let mut first = WeightedRadius::with_capacity(0);
        let mut second = WeightedRadius::with_capacity(0);
        for case in 0..120 {
            let n = 1 + case * 17;
            // Coarse positions (ties at equal distance), duplicates, and in every third case
            // equal weights (a resampled set), whose sums the order of ties would not change
            // but whose crossing falls exactly on 0.9 · n.
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
                    _ => rng.random::<f64>(),
                })
                .collect();
            let total: f64 = weights.iter().sum();
            weights.iter_mut().for_each(|w| *w /= total);
            let centre = [0.5, 1.0];
            // A stable comparison sort on the same keys, then the accumulation.
            let mut by_distance: Vec<(f64, f64)> = (particles.iter().zip(&weights))
                .map(|(p, &w)| {
                    let d = [p[0] - centre[0], p[1] - centre[1]];
                    (d[0] * d[0] + d[1] * d[1], w)
                })
                .collect();
            by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut held = 0.0;
            let expected = (by_distance.iter())
                .find(|(_, w)| {
                    held += w;
                    held >= 0.9
                })
                .map_or(0.0, |(d, _)| d.sqrt());
            let found = radius.radius(&particles, &weights, centre, 0.9);
            assert_eq!(found.to_bits(), expected.to_bits(), "case {case}");
            // Split anywhere (halves, or one part empty), the merge finds the same.
            for cut in [n / 2, 0, n, n / 3] {
                first.sort_by_distance(&particles[..cut], &weights[..cut], centre);
                second.sort_by_distance(&particles[cut..], &weights[cut..], centre);
                let merged = merged_radius(&first, &second, 0.9);
                assert_eq!(
                    merged.to_bits(),
                    expected.to_bits(),
                    "case {case} cut {cut}"
                );
            }
        }
        assert_eq!(radius.radius(&[], &[], [0.0; 2], 0.9), 0.0);
        assert_eq!(radius.radius(&[[3.0, 4.0]], &[0.5], [0.0; 2], 0.9), 0.0);
        assert_eq!(radius.radius(&[[3.0, 4.0]], &[1.0], [0.0; 2], 0.9), 5.0);
    }
}
