//! Subsets of a finite frame of discernment, stored as 64-bit words.
//!
//! Frames of up to [`INLINE_BITS`] elements live inline (no heap allocation per operation), larger
//! frames use one boxed word slice. Bits at or beyond the frame size are always zero, so equality
//! and hashing can look at whole words.

use std::hash::{Hash, Hasher};

use super::EvidenceError;

/// Largest frame accepted by the fallible constructors (2²⁴ elements, 2 MiB per subset), so that
/// a size read from a file cannot exhaust memory.
pub const MAX_FRAME: usize = 1 << 24;

/// Number of 64-bit words stored inline.
const INLINE_WORDS: usize = 8;

/// Largest frame whose subsets need no heap allocation.
pub const INLINE_BITS: usize = INLINE_WORDS * 64;

#[derive(Clone, Debug)]
enum Words {
    Inline([u64; INLINE_WORDS]),
    Heap(Box<[u64]>),
}

/// A subset of a frame of discernment {0, …, n − 1}.
///
/// Binary operations between subsets of different frame sizes are total: a subset is read as a set
/// of indices, and the result lives in the larger of the two frames. Code that combines belief
/// functions checks frame sizes before it gets here.
#[derive(Clone, Debug)]
pub struct Subset {
    n: usize,
    words: Words,
}

/// [`EvidenceError::FrameTooLarge`] beyond [`MAX_FRAME`].
pub(crate) fn check_frame(n: usize) -> Result<(), EvidenceError> {
    if n > MAX_FRAME {
        return Err(EvidenceError::FrameTooLarge {
            frame: n,
            max: MAX_FRAME,
        });
    }
    Ok(())
}

/// Number of words needed for a frame of `n` elements.
#[inline]
pub(crate) fn word_count(n: usize) -> usize {
    n.div_ceil(64)
}

impl Subset {
    /// The empty subset of a frame of `n` elements.
    pub fn empty(n: usize) -> Self {
        let w = word_count(n);
        let words = if w <= INLINE_WORDS {
            Words::Inline([0; INLINE_WORDS])
        } else {
            Words::Heap(vec![0; w].into_boxed_slice())
        };
        Subset { n, words }
    }

    /// The whole frame {0, …, n − 1}.
    pub fn full(n: usize) -> Self {
        let mut s = Subset::empty(n);
        let words = s.words_mut();
        for w in words.iter_mut() {
            *w = u64::MAX;
        }
        s.clear_tail();
        s
    }

    /// The singleton {i}; the empty set when `i` is outside the frame.
    pub fn singleton(n: usize, i: usize) -> Self {
        let mut s = Subset::empty(n);
        s.insert(i);
        s
    }

    /// Subset holding the given indices (duplicates allowed).
    ///
    /// # Errors
    /// [`EvidenceError::IndexOutOfRange`] when an index is not below `n`,
    /// [`EvidenceError::FrameTooLarge`] when `n` exceeds [`MAX_FRAME`].
    pub fn from_indices<I: IntoIterator<Item = usize>>(
        n: usize,
        indices: I,
    ) -> Result<Self, EvidenceError> {
        check_frame(n)?;
        let mut s = Subset::empty(n);
        for i in indices {
            if i >= n {
                return Err(EvidenceError::IndexOutOfRange { index: i, frame: n });
            }
            s.insert(i);
        }
        Ok(s)
    }

    /// Build from raw words; bits beyond the frame are cleared. Missing words are zero.
    #[inline]
    pub(crate) fn from_words(n: usize, src: &[u64]) -> Self {
        let w = word_count(n);
        let mut s = if w <= INLINE_WORDS {
            let mut a = [0u64; INLINE_WORDS];
            for (d, s) in a.iter_mut().zip(src.iter().take(w)) {
                *d = *s;
            }
            Subset {
                n,
                words: Words::Inline(a),
            }
        } else {
            let mut v = vec![0u64; w];
            let k = w.min(src.len());
            v[..k].copy_from_slice(&src[..k]);
            Subset {
                n,
                words: Words::Heap(v.into_boxed_slice()),
            }
        };
        s.clear_tail();
        s
    }

    /// Number of elements of the frame.
    #[inline]
    pub fn frame_size(&self) -> usize {
        self.n
    }

    /// The words of the bit set (bit `i % 64` of word `i / 64` is element `i`).
    #[inline]
    pub fn words(&self) -> &[u64] {
        match &self.words {
            Words::Inline(a) => &a[..word_count(self.n)],
            Words::Heap(b) => b,
        }
    }

    #[inline]
    fn words_mut(&mut self) -> &mut [u64] {
        let w = word_count(self.n);
        match &mut self.words {
            Words::Inline(a) => &mut a[..w],
            Words::Heap(b) => b,
        }
    }

    fn clear_tail(&mut self) {
        let r = self.n % 64;
        if r != 0 {
            if let Some(last) = self.words_mut().last_mut() {
                *last &= (1u64 << r) - 1;
            }
        }
    }

    /// Cardinality.
    #[inline]
    pub fn count(&self) -> usize {
        self.words().iter().map(|w| w.count_ones() as usize).sum()
    }

    /// Whether `i` is an element (false outside the frame).
    #[inline]
    pub fn contains(&self, i: usize) -> bool {
        i < self.n && (self.words()[i / 64] >> (i % 64)) & 1 == 1
    }

    /// Add `i`; returns false (and changes nothing) when `i` is outside the frame.
    #[inline]
    pub fn insert(&mut self, i: usize) -> bool {
        if i >= self.n {
            return false;
        }
        self.words_mut()[i / 64] |= 1u64 << (i % 64);
        true
    }

    /// Remove `i`; returns whether it was present.
    pub fn remove(&mut self, i: usize) -> bool {
        if !self.contains(i) {
            return false;
        }
        self.words_mut()[i / 64] &= !(1u64 << (i % 64));
        true
    }

    /// Whether the subset has no element.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.words().iter().all(|&w| w == 0)
    }

    /// Elements in ascending order.
    pub fn iter(&self) -> Iter<'_> {
        let words = self.words();
        Iter {
            words,
            index: 0,
            current: words.first().copied().unwrap_or(0),
        }
    }

    /// Elements as a vector, ascending.
    pub fn to_vec(&self) -> Vec<usize> {
        self.iter().collect()
    }

    fn zip_with(&self, other: &Subset, f: impl Fn(u64, u64) -> u64) -> Subset {
        let mut out = Subset::empty(self.n.max(other.n));
        let (a, b) = (self.words(), other.words());
        for (i, o) in out.words_mut().iter_mut().enumerate() {
            *o = f(
                a.get(i).copied().unwrap_or(0),
                b.get(i).copied().unwrap_or(0),
            );
        }
        out
    }

    /// A ∪ B.
    pub fn union(&self, other: &Subset) -> Subset {
        self.zip_with(other, |a, b| a | b)
    }

    /// A ∩ B.
    pub fn intersection(&self, other: &Subset) -> Subset {
        self.zip_with(other, |a, b| a & b)
    }

    /// A ← A ∪ B, in place; elements of B outside A's frame are ignored.
    pub fn union_with(&mut self, other: &Subset) {
        for (a, b) in self.words_mut().iter_mut().zip(other.words()) {
            *a |= b;
        }
        self.clear_tail();
    }

    /// A \ B.
    pub fn difference(&self, other: &Subset) -> Subset {
        self.zip_with(other, |a, b| a & !b)
    }

    /// Complement within the frame.
    pub fn complement(&self) -> Subset {
        let mut out = self.clone();
        for w in out.words_mut() {
            *w = !*w;
        }
        out.clear_tail();
        out
    }

    /// A ⊆ B (as sets of indices).
    pub fn is_subset_of(&self, other: &Subset) -> bool {
        let b = other.words();
        self.words()
            .iter()
            .enumerate()
            .all(|(i, &a)| a & !b.get(i).copied().unwrap_or(0) == 0)
    }

    /// A ∩ B ≠ ∅.
    pub fn intersects(&self, other: &Subset) -> bool {
        self.words()
            .iter()
            .zip(other.words())
            .any(|(a, b)| a & b != 0)
    }
}

impl PartialEq for Subset {
    fn eq(&self, other: &Self) -> bool {
        self.n == other.n && self.words() == other.words()
    }
}

impl Eq for Subset {}

impl Hash for Subset {
    fn hash<H: Hasher>(&self, state: &mut H) {
        self.n.hash(state);
        self.words().hash(state);
    }
}

/// Ascending iterator over the elements of a [`Subset`].
#[derive(Clone, Debug)]
pub struct Iter<'a> {
    words: &'a [u64],
    index: usize,
    current: u64,
}

impl Iterator for Iter<'_> {
    type Item = usize;

    #[inline]
    fn next(&mut self) -> Option<usize> {
        loop {
            if self.current != 0 {
                let bit = self.current.trailing_zeros() as usize;
                self.current &= self.current - 1;
                return Some(self.index * 64 + bit);
            }
            self.index += 1;
            self.current = *self.words.get(self.index)?;
        }
    }
}

impl<'a> IntoIterator for &'a Subset {
    type Item = usize;
    type IntoIter = Iter<'a>;
    fn into_iter(self) -> Iter<'a> {
        self.iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::BTreeSet;

    #[test]
    fn basic_operations_by_hand() {
        let a = Subset::from_indices(10, [1, 3, 5]).unwrap();
        let b = Subset::from_indices(10, [3, 4]).unwrap();
        assert_eq!(a.union(&b).to_vec(), vec![1, 3, 4, 5]);
        assert_eq!(a.intersection(&b).to_vec(), vec![3]);
        assert_eq!(a.difference(&b).to_vec(), vec![1, 5]);
        assert_eq!(a.complement().to_vec(), vec![0, 2, 4, 6, 7, 8, 9]);
        assert_eq!(a.count(), 3);
        assert!(!a.is_subset_of(&b));
        assert!(a.intersection(&b).is_subset_of(&b));
        assert!(a.intersects(&b));
        assert!(!a.contains(10));
        assert!(Subset::from_indices(10, [10]).is_err());
        assert_eq!(Subset::full(70).count(), 70);
        assert_eq!(Subset::full(70).complement().count(), 0);
    }

    #[test]
    fn large_frames_use_heap_and_behave_the_same() {
        let n = 100_000;
        let a = Subset::from_indices(n, [0, 64, 99_999]).unwrap();
        assert_eq!(a.to_vec(), vec![0, 64, 99_999]);
        assert_eq!(a.complement().count(), n - 3);
        assert!(matches!(a.words, Words::Heap(_)));
        assert!(matches!(Subset::empty(INLINE_BITS).words, Words::Inline(_)));
    }

    #[test]
    fn mismatched_frames_are_index_sets() {
        let a = Subset::from_indices(10, [1, 2]).unwrap();
        let b = Subset::from_indices(200, [2, 150]).unwrap();
        let u = a.union(&b);
        assert_eq!(u.frame_size(), 200);
        assert_eq!(u.to_vec(), vec![1, 2, 150]);
        assert_eq!(a.intersection(&b).to_vec(), vec![2]);
        assert!(!b.is_subset_of(&a));
        assert!(Subset::singleton(10, 2).is_subset_of(&b));
    }

    fn arb_set(n: usize) -> impl Strategy<Value = BTreeSet<usize>> {
        proptest::collection::btree_set(0..n, 0..n.min(40))
    }

    proptest! {
        #[test]
        fn matches_btreeset((n, x, y) in (1usize..600).prop_flat_map(|n| (Just(n), arb_set(n), arb_set(n)))) {
            let a = Subset::from_indices(n, x.iter().copied()).unwrap();
            let b = Subset::from_indices(n, y.iter().copied()).unwrap();
            prop_assert_eq!(a.to_vec(), x.iter().copied().collect::<Vec<_>>());
            prop_assert_eq!(a.union(&b).to_vec(), x.union(&y).copied().collect::<Vec<_>>());
            prop_assert_eq!(a.intersection(&b).to_vec(), x.intersection(&y).copied().collect::<Vec<_>>());
            prop_assert_eq!(a.complement().count(), n - x.len());
            prop_assert_eq!(a.is_subset_of(&b), x.is_subset(&y));
            prop_assert_eq!(a.intersects(&b), !x.is_disjoint(&y));
            prop_assert_eq!(a == b, x == y);
        }
    }
}
