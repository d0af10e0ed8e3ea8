//! Refinings ω: 2^Θ → 2^Ω between a coarse frame Θ and a fine frame Ω (Definition 2.4), with
//! vacuous extension, inner and outer reductions, composition and the coarsening of a partition.

use super::mass::MassFunction;
use super::subset::Subset;
use super::EvidenceError;

/// A refining from a coarse frame Θ (`coarse_size()` elements) onto a fine frame Ω
/// (`fine_size()` elements): disjoint, non-empty blocks ω({θ}) covering Ω.
#[derive(Clone, Debug, PartialEq)]
pub struct Refining {
    blocks: Vec<Subset>,
    /// Coarse element of every fine element.
    assignment: Vec<usize>,
}

impl Refining {
    /// A refining from its blocks ω({θ}), one per coarse element, all on the same fine frame.
    ///
    /// # Errors
    /// [`EvidenceError::NoBlocks`], [`EvidenceError::FrameMismatch`], [`EvidenceError::EmptyBlock`],
    /// [`EvidenceError::OverlappingBlocks`], [`EvidenceError::UncoveredElement`].
    pub fn new(blocks: Vec<Subset>) -> Result<Self, EvidenceError> {
        let first = blocks.first().ok_or(EvidenceError::NoBlocks)?;
        let n = first.frame_size();
        let mut assignment = vec![usize::MAX; n];
        for (b, block) in blocks.iter().enumerate() {
            if block.frame_size() != n {
                return Err(EvidenceError::FrameMismatch {
                    expected: n,
                    found: block.frame_size(),
                });
            }
            if block.is_empty() {
                return Err(EvidenceError::EmptyBlock { block: b });
            }
            for e in block.iter() {
                if assignment[e] != usize::MAX {
                    return Err(EvidenceError::OverlappingBlocks {
                        first: assignment[e],
                        second: b,
                        element: e,
                    });
                }
                assignment[e] = b;
            }
        }
        if let Some(e) = assignment.iter().position(|&a| a == usize::MAX) {
            return Err(EvidenceError::UncoveredElement { element: e });
        }
        Ok(Refining { blocks, assignment })
    }

    /// The coarsening of Ω induced by a partition (Definition 2.5, item 4): the same as
    /// [`Refining::new`], named for what it means.
    ///
    /// # Errors
    /// As [`Refining::new`].
    pub fn coarsening(partition: Vec<Subset>) -> Result<Self, EvidenceError> {
        Self::new(partition)
    }

    /// A refining from the coarse element of every fine element (e.g. HMM state of every sample).
    ///
    /// # Errors
    /// [`EvidenceError::EmptyFrame`] for an empty assignment or `n_coarse == 0`,
    /// [`EvidenceError::IndexOutOfRange`] for a coarse index ≥ `n_coarse`,
    /// [`EvidenceError::UnusedCoarseElement`] naming a coarse element with no fine element.
    pub fn from_assignment(n_coarse: usize, assignment: &[usize]) -> Result<Self, EvidenceError> {
        if assignment.is_empty() || n_coarse == 0 {
            return Err(EvidenceError::EmptyFrame);
        }
        let n = assignment.len();
        if let Some(&c) = assignment.iter().find(|&&c| c >= n_coarse) {
            return Err(EvidenceError::IndexOutOfRange {
                index: c,
                frame: n_coarse,
            });
        }
        // More coarse elements than fine ones: some coarse element is unused; name the first one
        // without allocating n_coarse blocks.
        if n_coarse > n {
            let mut used = assignment.to_vec();
            used.sort_unstable();
            used.dedup();
            let first_unused = used
                .iter()
                .enumerate()
                .find(|(i, &c)| *i != c)
                .map_or(used.len(), |(i, _)| i);
            return Err(EvidenceError::UnusedCoarseElement {
                coarse: first_unused,
            });
        }
        let mut blocks = vec![Subset::empty(n); n_coarse];
        for (e, &c) in assignment.iter().enumerate() {
            blocks[c].insert(e);
        }
        if let Some(c) = blocks.iter().position(Subset::is_empty) {
            return Err(EvidenceError::UnusedCoarseElement { coarse: c });
        }
        Ok(Refining {
            blocks,
            assignment: assignment.to_vec(),
        })
    }

    /// Number of coarse elements |Θ|.
    pub fn coarse_size(&self) -> usize {
        self.blocks.len()
    }

    /// Number of fine elements |Ω|.
    pub fn fine_size(&self) -> usize {
        self.assignment.len()
    }

    /// The block ω({θ}); `None` when θ is out of range.
    pub fn block(&self, theta: usize) -> Option<&Subset> {
        self.blocks.get(theta)
    }

    /// All blocks, indexed by coarse element.
    pub fn blocks(&self) -> &[Subset] {
        &self.blocks
    }

    /// The coarse element whose block holds fine element `omega`; `None` when out of range.
    pub fn coarse_of(&self, omega: usize) -> Option<usize> {
        self.assignment.get(omega).copied()
    }

    /// The coarse element of every fine element.
    pub fn assignment(&self) -> &[usize] {
        &self.assignment
    }

    fn check_coarse(&self, a: &Subset) -> Result<(), EvidenceError> {
        if a.frame_size() != self.coarse_size() {
            return Err(EvidenceError::FrameMismatch {
                expected: self.coarse_size(),
                found: a.frame_size(),
            });
        }
        Ok(())
    }

    fn check_fine(&self, a: &Subset) -> Result<(), EvidenceError> {
        if a.frame_size() != self.fine_size() {
            return Err(EvidenceError::FrameMismatch {
                expected: self.fine_size(),
                found: a.frame_size(),
            });
        }
        Ok(())
    }

    /// ω(A) = ∪_{θ∈A} ω({θ}).
    ///
    /// # Errors
    /// [`EvidenceError::FrameMismatch`] when `a` is not on the coarse frame.
    pub fn image(&self, a: &Subset) -> Result<Subset, EvidenceError> {
        self.check_coarse(a)?;
        if a.count() == self.coarse_size() {
            return Ok(Subset::full(self.fine_size()));
        }
        let mut out = Subset::empty(self.fine_size());
        for t in a.iter() {
            out.union_with(&self.blocks[t]);
        }
        Ok(out)
    }

    /// Vacuous extension (Definition 4.1): the function on Ω with m(ω(A)) = m(A), so that
    /// Bel_Ω(ω(A)) = Bel_Θ(A) for all A ⊆ Θ.
    ///
    /// # Errors
    /// [`EvidenceError::FrameMismatch`] when `m` is not on the coarse frame.
    pub fn extend(&self, m: &MassFunction) -> Result<MassFunction, EvidenceError> {
        if m.frame_size() != self.coarse_size() {
            return Err(EvidenceError::FrameMismatch {
                expected: self.coarse_size(),
                found: m.frame_size(),
            });
        }
        let mut focal = Vec::with_capacity(m.len());
        for (a, _) in m.focal() {
            focal.push(self.image(a)?);
        }
        // ω is injective on subsets, so distinct focal sets stay distinct.
        Ok(MassFunction::from_parts(
            self.fine_size(),
            focal,
            m.masses().to_vec(),
        ))
    }

    /// Outer reduction θ̄(A) = {θ : ω({θ}) ∩ A ≠ ∅}, in O(|A|).
    ///
    /// # Errors
    /// [`EvidenceError::FrameMismatch`] when `a` is not on the fine frame.
    pub fn outer_reduction(&self, a: &Subset) -> Result<Subset, EvidenceError> {
        self.check_fine(a)?;
        let mut out = Subset::empty(self.coarse_size());
        for e in a.iter() {
            out.insert(self.assignment[e]);
        }
        Ok(out)
    }

    /// Inner reduction θ(A) = {θ : ω({θ}) ⊆ A}, in O(|A| + |Θ|).
    ///
    /// # Errors
    /// [`EvidenceError::FrameMismatch`] when `a` is not on the fine frame.
    pub fn inner_reduction(&self, a: &Subset) -> Result<Subset, EvidenceError> {
        self.check_fine(a)?;
        let mut hits = vec![0usize; self.coarse_size()];
        for e in a.iter() {
            hits[self.assignment[e]] += 1;
        }
        let mut out = Subset::empty(self.coarse_size());
        for (t, (&h, b)) in hits.iter().zip(&self.blocks).enumerate() {
            if h == b.count() {
                out.insert(t);
            }
        }
        Ok(out)
    }

    /// Restriction (marginalisation) of a function on Ω to Θ: m_Θ(B) = Σ_{θ̄(A) = B} m(A).
    ///
    /// # Errors
    /// [`EvidenceError::FrameMismatch`] when `m` is not on the fine frame.
    pub fn restrict(&self, m: &MassFunction) -> Result<MassFunction, EvidenceError> {
        if m.frame_size() != self.fine_size() {
            return Err(EvidenceError::FrameMismatch {
                expected: self.fine_size(),
                found: m.frame_size(),
            });
        }
        let mut focal = Vec::with_capacity(m.len());
        for (a, mass) in m.focal() {
            focal.push((self.outer_reduction(a)?, mass));
        }
        if m.empty_mass() > 0.0 {
            MassFunction::unnormalised(self.coarse_size(), focal)
        } else {
            MassFunction::new(self.coarse_size(), focal)
        }
    }

    /// Composition: `self` refines Θ₁ onto Θ₂ and `next` refines Θ₂ onto Θ₃; the result refines
    /// Θ₁ onto Θ₃ (block of θ = union of `next`'s blocks over `self`'s block of θ).
    ///
    /// # Errors
    /// [`EvidenceError::FrameMismatch`] when `self`'s fine frame is not `next`'s coarse frame.
    pub fn compose(&self, next: &Refining) -> Result<Refining, EvidenceError> {
        if self.fine_size() != next.coarse_size() {
            return Err(EvidenceError::FrameMismatch {
                expected: self.fine_size(),
                found: next.coarse_size(),
            });
        }
        let assignment: Vec<usize> = next
            .assignment
            .iter()
            .map(|&mid| self.assignment[mid])
            .collect();
        Refining::from_assignment(self.coarse_size(), &assignment)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(n: usize, v: &[usize]) -> Subset {
        Subset::from_indices(n, v.iter().copied()).unwrap()
    }

    #[test]
    fn validation_names_the_fault() {
        assert_eq!(Refining::new(vec![]), Err(EvidenceError::NoBlocks));
        assert_eq!(
            Refining::new(vec![s(4, &[0, 1]), Subset::empty(4)]),
            Err(EvidenceError::EmptyBlock { block: 1 })
        );
        assert_eq!(
            Refining::new(vec![s(4, &[0, 1]), s(4, &[1, 2, 3])]),
            Err(EvidenceError::OverlappingBlocks {
                first: 0,
                second: 1,
                element: 1
            })
        );
        assert_eq!(
            Refining::new(vec![s(4, &[0, 1]), s(4, &[3])]),
            Err(EvidenceError::UncoveredElement { element: 2 })
        );
        assert_eq!(
            Refining::from_assignment(3, &[0, 2, 0]),
            Err(EvidenceError::UnusedCoarseElement { coarse: 1 })
        );
        assert_eq!(
            Refining::from_assignment(usize::MAX, &[0, 2, 1, 4]),
            Err(EvidenceError::UnusedCoarseElement { coarse: 3 })
        );
        assert_eq!(
            Refining::from_assignment(2, &[0, 2]),
            Err(EvidenceError::IndexOutOfRange { index: 2, frame: 2 })
        );
    }

    #[test]
    fn reductions_by_hand() {
        // Θ = {0,1,2} → Ω = {0..6}: blocks {0,1}, {2,3,4}, {5}.
        let r = Refining::from_assignment(3, &[0, 0, 1, 1, 1, 2]).unwrap();
        assert_eq!(r.block(1).unwrap().to_vec(), vec![2, 3, 4]);
        let a = s(6, &[1, 2, 3, 4]);
        assert_eq!(r.outer_reduction(&a).unwrap().to_vec(), vec![0, 1]);
        assert_eq!(r.inner_reduction(&a).unwrap().to_vec(), vec![1]);
        assert_eq!(r.image(&s(3, &[0, 2])).unwrap().to_vec(), vec![0, 1, 5]);
        let m = MassFunction::new(3, vec![(s(3, &[0]), 0.7), (s(3, &[1, 2]), 0.3)]).unwrap();
        let e = r.extend(&m).unwrap();
        assert!((e.belief(&s(6, &[0, 1])) - 0.7).abs() < 1e-15);
        assert!((e.plausibility(&s(6, &[5])) - 0.3).abs() < 1e-15);
        assert_eq!(r.restrict(&e).unwrap(), m);
        assert!(r.extend(&MassFunction::vacuous(4).unwrap()).is_err());
    }

    #[test]
    fn composition_by_hand() {
        // Θ₁ = {0,1} → Θ₂ = {0,1,2} → Θ₃ = {0..5}.
        let r1 = Refining::from_assignment(2, &[0, 1, 1]).unwrap();
        let r2 = Refining::from_assignment(3, &[0, 1, 2, 2, 1]).unwrap();
        let c = r1.compose(&r2).unwrap();
        assert_eq!(c.assignment(), &[0, 1, 1, 1, 1]);
        assert!(r2.compose(&r1).is_err());
    }

    use crate::evidence::testutil::random_mass;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn vacuous_extension_preserves_belief(
            (coarse, assignment) in (1usize..12).prop_flat_map(|c| (Just(c), proptest::collection::vec(0..c, c..300))),
            seed in any::<u64>(),
        ) {
            // Make every coarse element used: the first `coarse` fine elements take 0..coarse.
            let mut assignment = assignment;
            for (i, a) in assignment.iter_mut().take(coarse).enumerate() {
                *a = i;
            }
            let r = Refining::from_assignment(coarse, &assignment).unwrap();
            let m = random_mass(coarse, 4, seed);
            let e = r.extend(&m).unwrap();
            let probe = random_mass(coarse, 1, seed ^ 5).focal_sets()[0].clone();
            let image = r.image(&probe).unwrap();
            prop_assert!((m.belief(&probe) - e.belief(&image)).abs() < 1e-12);
            prop_assert!((m.plausibility(&probe) - e.plausibility(&image)).abs() < 1e-12);
            // Reductions invert the image, and the contour is the coarse contour spread over blocks.
            prop_assert_eq!(r.outer_reduction(&image).unwrap(), probe.clone());
            prop_assert_eq!(r.inner_reduction(&image).unwrap(), probe);
            let cc = m.contour();
            for (w, p) in e.contour().iter().enumerate() {
                prop_assert!((p - cc[assignment[w]]).abs() < 1e-15);
            }
            for (x, y) in r.restrict(&e).unwrap().contour().iter().zip(&cc) {
                prop_assert!((x - y).abs() < 1e-12);
            }
        }
    }
}
