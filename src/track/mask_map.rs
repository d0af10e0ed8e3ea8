//! Hash maps keyed by group masks, with a hasher cheaper than SipHash.

use super::group_search::{GroupMask, TIE};
use std::collections::HashMap;

/// A hasher for group masks: the splitting search looks thousands of them up a frame (its memo,
/// the per-cell lists of `cell_products`), where SipHash took a tenth of its time. One multiply
/// by an odd constant, the high half folded into the low one (the table's index).
#[derive(Default, Clone, Copy)]
pub(super) struct MaskHasher(u64);

impl std::hash::Hasher for MaskHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    fn write_u64(&mut self, x: u64) {
        let h = (self.0.rotate_left(29) ^ x).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.0 = h ^ (h >> 32);
    }
}

/// A map keyed by group masks, with [`MaskHasher`].
pub(super) type MaskMap<V> = HashMap<GroupMask, V, std::hash::BuildHasherDefault<MaskHasher>>;

/// A group's level (0 for one feature), memoised in `memo`. With a finite `bound`, a group whose
/// prefix (the group without its highest feature) is already known to exceed the bound is not
/// combined: K only grows as features are added (Theorem 4.3), so it cannot be below the bound;
/// it is recorded as +∞.
pub(super) fn memoised_level(
    memo: &mut HashMap<GroupMask, f64>,
    group: GroupMask,
    bound: f64,
    compute: impl FnOnce() -> f64,
) -> f64 {
    if group.count_ones() <= 1 {
        return 0.0;
    }
    if let Some(&k) = memo.get(&group) {
        return k;
    }
    let parent = group & !(1 << (63 - group.leading_zeros()));
    let k = match memo.get(&parent) {
        Some(&kp) if kp.is_nan() || kp > bound + TIE => f64::INFINITY,
        _ => compute(),
    };
    memo.insert(group, k);
    k
}
