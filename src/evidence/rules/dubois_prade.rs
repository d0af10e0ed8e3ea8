//! Dubois and Prade's rule: each tuple's product to the intersection, or to the union when the
//! intersection is empty. The running state is the (intersection, union) pair of each partial
//! tuple, identical pairs merged, so the work is bounded by the distinct pairs, not the tuples.

use std::collections::HashMap;

use super::super::limits::WorkLimits;
use super::super::mass::MassFunction;
use super::super::subset::{word_count, Subset};
use super::super::EvidenceError;
use super::from_pairs;

/// Dubois and Prade's combination of normalised functions on a frame of `n` (masses are plain
/// products: the total stays 1, so an underflowing product loses less than 1e-308).
pub(super) fn combine(
    n: usize,
    fs: &[&MassFunction],
    limits: &WorkLimits,
) -> Result<MassFunction, EvidenceError> {
    let w = word_count(n).max(1);
    // Keys (intersection words then union words) in first-seen order, so sums are deterministic.
    let mut cur = Ordered::default();
    for (i, f) in fs.iter().enumerate() {
        limits.check(f.len(), 2 * w)?;
        let mut next = Ordered::default();
        for (s, m) in f.focal() {
            let words = s.words();
            if i == 0 {
                let mut key = words.to_vec();
                key.extend_from_slice(words);
                next.add(key, m);
                continue;
            }
            for (key, &mk) in cur.keys.iter().zip(&cur.mass) {
                let mut k = Vec::with_capacity(2 * w);
                k.extend(key[..w].iter().zip(words).map(|(a, b)| a & b));
                k.extend(key[w..].iter().zip(words).map(|(a, b)| a | b));
                next.add(k, mk * m);
            }
            limits.check(next.keys.len(), 2 * w)?;
        }
        cur = next;
    }
    let pairs = cur
        .keys
        .into_iter()
        .zip(cur.mass)
        .map(|(key, m)| {
            let meet = &key[..w];
            let set = if meet.iter().any(|&x| x != 0) {
                meet
            } else {
                &key[w..]
            };
            (Subset::from_words(n, set), m)
        })
        .collect();
    Ok(from_pairs(n, pairs))
}

/// A map from keys to summed masses that iterates in first-seen order.
#[derive(Default)]
struct Ordered {
    index: HashMap<Vec<u64>, usize>,
    keys: Vec<Vec<u64>>,
    mass: Vec<f64>,
}

impl Ordered {
    fn add(&mut self, key: Vec<u64>, m: f64) {
        match self.index.get(&key) {
            Some(&i) => self.mass[i] += m,
            None => {
                self.index.insert(key.clone(), self.keys.len());
                self.keys.push(key);
                self.mass.push(m);
            }
        }
    }
}
