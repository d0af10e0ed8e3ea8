//! Mass functions (basic probability assignments) with sparse focal sets.

use std::collections::HashMap;
use std::sync::OnceLock;

use super::subset::{check_frame, word_count, Subset};
use super::EvidenceError;

/// Largest accepted absolute deviation of the sum of the masses from 1 at construction.
///
/// Accepted masses are rescaled by their sum, so the stored masses sum to 1 up to rounding.
pub const MASS_TOLERANCE: f64 = 1e-9;

/// A mass function on a frame of `n` elements: distinct focal sets with positive masses.
///
/// Normalised functions (built with [`MassFunction::new`]) have no mass on ∅; the unconstrained
/// [`MassFunction::unnormalised`] form may, and then [`MassFunction::empty_mass`] is the conflict
/// it carries (Smets' open-world form, as produced by the conjunctive rule).
#[derive(Clone)]
pub struct MassFunction {
    n: usize,
    sets: Sets,
    mass: Vec<f64>,
}

/// The focal sets: as subsets, or as the flat words of a combination's arena, turned into subsets
/// only when asked for (a combination of thousands of sets is often only read through its contour).
#[derive(Clone)]
enum Sets {
    Subsets(Vec<Subset>),
    Words {
        words: Vec<u64>,
        subsets: OnceLock<Vec<Subset>>,
    },
}

impl PartialEq for MassFunction {
    fn eq(&self, other: &Self) -> bool {
        self.n == other.n && self.mass == other.mass && self.set_words().eq(other.set_words())
    }
}

impl std::fmt::Debug for MassFunction {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MassFunction")
            .field("n", &self.n)
            .field("focal", &self.focal_sets())
            .field("mass", &self.mass)
            .finish()
    }
}

impl MassFunction {
    /// A normalised mass function from (focal set, mass) pairs.
    ///
    /// Masses must be finite and non-negative and sum to 1 within [`MASS_TOLERANCE`]; they are then
    /// rescaled by their sum. Zero masses are dropped, repeated focal sets are merged (masses
    /// added), and focal sets keep their first-seen order.
    ///
    /// # Errors
    /// [`EvidenceError::EmptyFrame`], [`EvidenceError::FrameMismatch`],
    /// [`EvidenceError::InvalidMass`], [`EvidenceError::EmptyFocalSet`], [`EvidenceError::MassSum`].
    pub fn new(n: usize, focal: Vec<(Subset, f64)>) -> Result<Self, EvidenceError> {
        Self::build(n, focal, false)
    }

    /// Like [`MassFunction::new`] but mass on the empty set is allowed.
    ///
    /// # Errors
    /// As [`MassFunction::new`], except that empty focal sets are accepted.
    pub fn unnormalised(n: usize, focal: Vec<(Subset, f64)>) -> Result<Self, EvidenceError> {
        Self::build(n, focal, true)
    }

    fn build(
        n: usize,
        focal: Vec<(Subset, f64)>,
        allow_empty: bool,
    ) -> Result<Self, EvidenceError> {
        if n == 0 {
            return Err(EvidenceError::EmptyFrame);
        }
        check_frame(n)?;
        let mut sum = 0.0;
        for (i, (s, m)) in focal.iter().enumerate() {
            if s.frame_size() != n {
                return Err(EvidenceError::FrameMismatch {
                    expected: n,
                    found: s.frame_size(),
                });
            }
            if !m.is_finite() || *m < 0.0 {
                return Err(EvidenceError::InvalidMass { focal: i, mass: *m });
            }
            if *m > 0.0 && !allow_empty && s.is_empty() {
                return Err(EvidenceError::EmptyFocalSet { focal: i });
            }
            sum += m;
        }
        if (sum - 1.0).abs() > MASS_TOLERANCE {
            return Err(EvidenceError::MassSum {
                sum,
                tolerance: MASS_TOLERANCE,
            });
        }
        let mut index: HashMap<Subset, usize> = HashMap::with_capacity(focal.len());
        let mut sets = Vec::with_capacity(focal.len());
        let mut masses: Vec<f64> = Vec::with_capacity(focal.len());
        for (s, m) in focal {
            if m == 0.0 {
                continue;
            }
            match index.get(&s) {
                Some(&k) => masses[k] += m / sum,
                None => {
                    index.insert(s.clone(), sets.len());
                    sets.push(s);
                    masses.push(m / sum);
                }
            }
        }
        Ok(MassFunction {
            n,
            sets: Sets::Subsets(sets),
            mass: masses,
        })
    }

    /// Trusted constructor for results of the algebra: distinct sets, positive masses.
    pub(crate) fn from_parts(n: usize, focal: Vec<Subset>, mass: Vec<f64>) -> Self {
        MassFunction {
            n,
            sets: Sets::Subsets(focal),
            mass,
        }
    }

    /// Trusted constructor from flat words, ⌈n / 64⌉ per set (bits beyond the frame zero): distinct
    /// sets, positive masses.
    pub(crate) fn from_words(n: usize, words: Vec<u64>, mass: Vec<f64>) -> Self {
        debug_assert_eq!(words.len(), mass.len() * word_count(n));
        MassFunction {
            n,
            sets: Sets::Words {
                words,
                subsets: OnceLock::new(),
            },
            mass,
        }
    }

    /// The words of every focal set, in order, without building subsets.
    pub(crate) fn set_words(&self) -> impl Iterator<Item = &[u64]> + '_ {
        let (subsets, flat): (&[Subset], &[u64]) = match &self.sets {
            Sets::Subsets(v) => (v, &[]),
            Sets::Words { words, .. } => (&[], words),
        };
        subsets
            .iter()
            .map(Subset::words)
            .chain(flat.chunks_exact(word_count(self.n).max(1)))
    }

    /// (words of a focal set, mass) pairs.
    fn focal_words(&self) -> impl Iterator<Item = (&[u64], f64)> + '_ {
        self.set_words().zip(self.mass.iter().copied())
    }

    /// The vacuous mass function m(Θ) = 1 (total ignorance).
    ///
    /// # Errors
    /// [`EvidenceError::EmptyFrame`] when `n == 0`, [`EvidenceError::FrameTooLarge`] beyond
    /// [`crate::evidence::MAX_FRAME`].
    pub fn vacuous(n: usize) -> Result<Self, EvidenceError> {
        if n == 0 {
            return Err(EvidenceError::EmptyFrame);
        }
        check_frame(n)?;
        Ok(MassFunction {
            n,
            sets: Sets::Subsets(vec![Subset::full(n)]),
            mass: vec![1.0],
        })
    }

    /// A Bayesian mass function from probabilities of singletons (must sum to 1 within tolerance).
    ///
    /// # Errors
    /// As [`MassFunction::new`].
    pub fn bayesian(p: &[f64]) -> Result<Self, EvidenceError> {
        let n = p.len();
        Self::new(
            n,
            p.iter()
                .enumerate()
                .map(|(i, &m)| (Subset::singleton(n, i), m))
                .collect(),
        )
    }

    /// Frame size.
    pub fn frame_size(&self) -> usize {
        self.n
    }

    /// Number of focal sets (including ∅ if it carries mass).
    pub fn len(&self) -> usize {
        self.mass.len()
    }

    /// Whether there are no focal sets (never true for a constructed function).
    pub fn is_empty(&self) -> bool {
        self.mass.is_empty()
    }

    /// (focal set, mass) pairs.
    pub fn focal(&self) -> impl ExactSizeIterator<Item = (&Subset, f64)> + '_ {
        self.focal_sets().iter().zip(self.mass.iter().copied())
    }

    /// The focal sets.
    pub fn focal_sets(&self) -> &[Subset] {
        match &self.sets {
            Sets::Subsets(v) => v,
            Sets::Words { words, subsets } => subsets.get_or_init(|| {
                let w = word_count(self.n).max(1);
                words
                    .chunks_exact(w)
                    .map(|c| Subset::from_words(self.n, c))
                    .collect()
            }),
        }
    }

    /// The masses, in the order of [`MassFunction::focal_sets`].
    pub fn masses(&self) -> &[f64] {
        &self.mass
    }

    /// Mass on the empty set (0 for normalised functions).
    pub fn empty_mass(&self) -> f64 {
        self.focal_words()
            .filter(|(s, _)| s.iter().all(|&x| x == 0))
            .map(|(_, m)| m)
            .sum()
    }

    /// Whether the function is vacuous (all mass on the whole frame).
    pub fn is_vacuous(&self) -> bool {
        self.len() == 1
            && self
                .set_words()
                .all(|s| s.iter().map(|x| x.count_ones() as usize).sum::<usize>() == self.n)
    }

    /// Bel(A) = Σ m(B) over non-empty B ⊆ A (mass on ∅ is not belief).
    ///
    /// `a` is read as a set of indices; elements outside this frame are ignored.
    pub fn belief(&self, a: &Subset) -> f64 {
        let a = a.words();
        self.focal_words()
            .filter(|(b, _)| b.iter().any(|&x| x != 0) && words_within(b, a))
            .map(|(_, m)| m)
            .sum()
    }

    /// Pl(A) = Σ m(B) over B with B ∩ A ≠ ∅.
    pub fn plausibility(&self, a: &Subset) -> f64 {
        let a = a.words();
        self.focal_words()
            .filter(|(b, _)| b.iter().zip(a).any(|(x, y)| x & y != 0))
            .map(|(_, m)| m)
            .sum()
    }

    /// Q(A) = Σ m(B) over B ⊇ A.
    pub fn commonality(&self, a: &Subset) -> f64 {
        let a = a.words();
        self.focal_words()
            .filter(|(b, _)| words_within(a, b))
            .map(|(_, m)| m)
            .sum()
    }

    /// The contour function: plausibility of every singleton, in O(n + Σ|A|).
    pub fn contour(&self) -> Vec<f64> {
        let mut pl = vec![0.0; self.n];
        // Focal sets of long combinations are tiny, so most words are zero: find the non-zero
        // words, 64 at a time, without a branch per word (which mispredicts often).
        for (s, m) in self.focal_words() {
            for (g, ws) in s.chunks(64).enumerate() {
                let mut nz = 0u64;
                for (k, &word) in ws.iter().enumerate() {
                    nz |= u64::from(word != 0) << k;
                }
                while nz != 0 {
                    let k = nz.trailing_zeros() as usize;
                    nz &= nz - 1;
                    let base = (g * 64 + k) * 64;
                    let mut bits = ws[k];
                    while bits != 0 {
                        if let Some(p) = pl.get_mut(base + bits.trailing_zeros() as usize) {
                            *p += m;
                        }
                        bits &= bits - 1;
                    }
                }
            }
        }
        pl
    }

    /// Shafer's discounting with reliability `alpha`: every mass is multiplied by `alpha` and the
    /// remaining 1 − `alpha` goes to the whole frame (α = 1 keeps the function, α = 0 makes it vacuous).
    ///
    /// # Errors
    /// [`EvidenceError::InvalidReliability`] when `alpha` is NaN or outside [0, 1].
    pub fn discount(&self, alpha: f64) -> Result<MassFunction, EvidenceError> {
        if !(0.0..=1.0).contains(&alpha) {
            return Err(EvidenceError::InvalidReliability { alpha });
        }
        let full = Subset::full(self.n);
        let mut focal = Vec::with_capacity(self.len() + 1);
        let mut mass = Vec::with_capacity(self.len() + 1);
        let mut on_full = 1.0 - alpha;
        for (s, m) in self.focal() {
            if *s == full {
                on_full += alpha * m;
            } else if alpha * m > 0.0 {
                focal.push(s.clone());
                mass.push(alpha * m);
            }
        }
        if on_full > 0.0 {
            focal.push(full);
            mass.push(on_full);
        }
        Ok(MassFunction::from_parts(self.n, focal, mass))
    }
}

/// A ⊆ B on words, as [`Subset::is_subset_of`]: words of A beyond B's must be zero.
fn words_within(a: &[u64], b: &[u64]) -> bool {
    a.iter()
        .enumerate()
        .all(|(i, &x)| x & !b.get(i).copied().unwrap_or(0) == 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(n: usize, v: &[usize]) -> Subset {
        Subset::from_indices(n, v.iter().copied()).unwrap()
    }

    #[test]
    fn belief_plausibility_commonality_by_hand() {
        // m({0}) = 0.2, m({0,1}) = 0.3, m({1,2,3}) = 0.5 on 4 elements.
        let m = MassFunction::new(
            4,
            vec![
                (s(4, &[0]), 0.2),
                (s(4, &[0, 1]), 0.3),
                (s(4, &[1, 2, 3]), 0.5),
            ],
        )
        .unwrap();
        let a = s(4, &[0, 1]);
        assert!((m.belief(&a) - 0.5).abs() < 1e-15);
        assert!((m.plausibility(&a) - 1.0).abs() < 1e-15);
        assert!((m.commonality(&s(4, &[1])) - 0.8).abs() < 1e-15);
        assert!((m.commonality(&a) - 0.3).abs() < 1e-15);
        let c = m.contour();
        let want = [0.5, 0.8, 0.5, 0.5];
        for (x, y) in c.iter().zip(want) {
            assert!((x - y).abs() < 1e-15);
        }
        assert_eq!(m.belief(&Subset::full(4)), 1.0);
    }

    #[test]
    fn validation_rejects_bad_masses() {
        let n = 3;
        assert_eq!(MassFunction::new(0, vec![]), Err(EvidenceError::EmptyFrame));
        assert!(matches!(
            MassFunction::new(n, vec![(s(n, &[0]), f64::NAN)]),
            Err(EvidenceError::InvalidMass { focal: 0, .. })
        ));
        assert!(matches!(
            MassFunction::new(n, vec![(s(n, &[0]), 1.5), (s(n, &[1]), -0.5)]),
            Err(EvidenceError::InvalidMass { focal: 1, .. })
        ));
        assert!(matches!(
            MassFunction::new(n, vec![(s(n, &[0]), 0.5)]),
            Err(EvidenceError::MassSum { .. })
        ));
        assert_eq!(
            MassFunction::new(n, vec![(s(n, &[0]), 0.5), (Subset::empty(n), 0.5)]),
            Err(EvidenceError::EmptyFocalSet { focal: 1 })
        );
        let u = MassFunction::unnormalised(n, vec![(s(n, &[0]), 0.5), (Subset::empty(n), 0.5)])
            .unwrap();
        assert_eq!(u.empty_mass(), 0.5);
        assert!(matches!(
            MassFunction::new(n, vec![(s(4, &[0]), 1.0)]),
            Err(EvidenceError::FrameMismatch {
                expected: 3,
                found: 4
            })
        ));
    }

    #[test]
    fn duplicates_merge_and_tolerance_rescales() {
        let n = 3;
        let m = MassFunction::new(
            n,
            vec![
                (s(n, &[0]), 0.25),
                (s(n, &[1]), 0.5),
                (s(n, &[0]), 0.25 + 5e-10),
            ],
        )
        .unwrap();
        assert_eq!(m.len(), 2);
        assert!((m.masses().iter().sum::<f64>() - 1.0).abs() < 1e-15);
        assert!((m.masses()[0] - 0.5).abs() < 1e-9);
    }

    #[test]
    fn combination_results_read_like_built_ones() {
        // Results keep the engine's words; every query must match the same function as subsets.
        for seed in 0..20 {
            let n = [3, 64, 70, 200, 600][seed % 5];
            let fs: Vec<_> = (0..4)
                .map(|k| crate::evidence::testutil::random_mass(n, 5, 40 * seed as u64 + k))
                .collect();
            for c in [
                crate::evidence::conjunctive_all(&fs).unwrap(),
                crate::evidence::dempster_all(&fs).unwrap().mass.unwrap(),
            ] {
                let built =
                    MassFunction::from_parts(n, c.focal_sets().to_vec(), c.masses().to_vec());
                assert_eq!(c, built);
                assert_eq!(format!("{c:?}"), format!("{built:?}"));
                assert_eq!(c.clone(), built);
                assert_eq!(c.contour(), built.contour());
                assert_eq!(c.empty_mass().to_bits(), built.empty_mass().to_bits());
                assert_eq!(c.is_vacuous(), built.is_vacuous());
                for a in fs.iter().flat_map(|f| f.focal_sets()).chain(c.focal_sets()) {
                    assert_eq!(c.belief(a).to_bits(), built.belief(a).to_bits());
                    assert_eq!(c.plausibility(a).to_bits(), built.plausibility(a).to_bits());
                    assert_eq!(c.commonality(a).to_bits(), built.commonality(a).to_bits());
                }
            }
        }
    }

    #[test]
    fn discounting_moves_mass_to_frame() {
        let n = 3;
        let m = MassFunction::new(n, vec![(s(n, &[0]), 0.6), (Subset::full(n), 0.4)]).unwrap();
        let d = m.discount(0.5).unwrap();
        assert!((d.plausibility(&s(n, &[1])) - 0.7).abs() < 1e-15);
        assert!((d.belief(&s(n, &[0])) - 0.3).abs() < 1e-15);
        assert!(d.discount(0.0).unwrap().is_vacuous());
        assert_eq!(m.discount(1.0).unwrap().contour(), m.contour());
        assert!(m.discount(f64::NAN).is_err());
        assert!(m.discount(1.1).is_err());
    }
}
