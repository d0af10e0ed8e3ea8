//! The splitting policy's search: the maximal eligible groups of at least `min_size` features.
//!
//! The search walks the cliques depth first in lexicographic order, and rules a branch out
//! before computing anything below it when the group is beyond the bound (Theorem 4.3: a
//! group's level only grows as features are added, so every larger group is too) or when the
//! group with every candidate lies inside a group already found. It looks ahead: when the group
//! with every candidate is an eligible clique, that is the branch's one maximal group and
//! nothing below it (not even the group's own level) is computed. When such groups are cheap
//! (`GroupLevels::look_ahead_first`), a group's own level waits until its first branch is
//! searched (when that records a group, the level is never needed), and a group is settled
//! against the threshold by bounds on its level (`GroupLevels::level_bounds`) when they are
//! clear of it, its level computed only otherwise: the levels of the alternatives are
//! computed at the end, together (`GroupLevels::group_levels`), and with a cap on how many
//! the frame keeps only those of the first ones. Groups are recorded after their branch, only
//! when nothing larger in it is eligible, so the list each branch is checked against stays
//! short. Levels are the memoised ones of the other policies: each group's level is the same
//! bits whatever came before it.

use super::{
    choose, lex_cmp, maximal_cliques, members, sort_alternatives, GroupLevels, GroupMask, Search,
    Selection, SelectionPolicy, TIE,
};
use crate::evidence::ConflictLevel;
use std::cmp::Ordering;

/// [`super::select_group`] with the splitting policy's first `keep` alternatives only (what a
/// frame capped at `keep` estimates: their levels are computed, the others' need not be), and
/// the number of alternatives found (0 on fallback).
pub(crate) fn select_group_keeping(
    levels: &mut impl GroupLevels,
    features: usize,
    usable_mask: GroupMask,
    policy: SelectionPolicy,
    threshold: ConflictLevel,
    keep: usize,
) -> (Selection, usize) {
    let exhaustive = !levels.levels_grow_exactly();
    let keep = Some(keep.max(1));
    choose(
        levels,
        features,
        usable_mask,
        policy,
        threshold,
        exhaustive,
        keep,
    )
}

impl<L: GroupLevels> Search<'_, L> {
    /// The splitting policy's alternatives: the maximal eligible groups of at least `min_size`
    /// features, by decreasing size, then increasing level, then feature list (with
    /// [`Search::keep`], the first ones only), and how many there are.
    pub(super) fn maximal_eligible(
        &mut self,
        usable: GroupMask,
        min_size: usize,
    ) -> (Vec<(f64, GroupMask)>, usize) {
        let m = min_size.max(1) as u32;
        self.cut = self.threshold.value();
        // An eligible maximal clique is a maximal eligible group; below the others, search.
        let mut found = Found::new(usable);
        for g in maximal_cliques(usable, &self.adj) {
            if g.count_ones() >= m && self.admitted(g, 0) {
                found.push(g);
            }
        }
        let mut rest = usable;
        while rest != 0 {
            let j = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            self.split_below(1 << j, rest & self.adj[j], m, &mut found);
        }
        // Largest first, so that a group inside an accepted one is seen after it.
        let mut found = found.groups;
        found.sort_by(|&a, &b| b.count_ones().cmp(&a.count_ones()).then(lex_cmp(b, a)));
        let mut maximal: Vec<GroupMask> = Vec::new();
        for g in found {
            if !maximal.iter().any(|&a| g & a == g) {
                maximal.push(g);
            }
        }
        let count = maximal.len();
        if let Some(keep) = self.keep.filter(|&keep| count > keep) {
            maximal = self.may_come_first(maximal, keep);
        }
        // Their levels at the end, together (a group's level is the same bits whatever is
        // computed before it): the search settled most of them by bounds alone.
        self.compute_levels(&maximal);
        let mut alternatives: Vec<(f64, GroupMask)> =
            maximal.iter().map(|&g| (self.level(g), g)).collect();
        sort_alternatives(&mut alternatives);
        alternatives.truncate(self.keep.unwrap_or(count));
        (alternatives, count)
    }

    /// Of the maximal eligible groups, those that may be among the first `keep` (at least
    /// one) in the policy's order: every size class before the one that holds the `keep`-th,
    /// and of that class the groups whose floor is at most its r-th lowest ceiling (r the
    /// places left): r groups of the class are at or below that ceiling, so a group above it
    /// comes after them (bounds as [`Search::level_range`], cached from the search).
    fn may_come_first(&mut self, mut maximal: Vec<GroupMask>, keep: usize) -> Vec<GroupMask> {
        maximal.sort_by_key(|g| std::cmp::Reverse(g.count_ones()));
        let mut kept = Vec::new();
        let mut start = 0;
        while start < maximal.len() && kept.len() < keep.max(1) {
            let size = maximal[start].count_ones();
            let class_size = (maximal[start..].iter())
                .take_while(|g| g.count_ones() == size)
                .count();
            let class = &maximal[start..start + class_size];
            let room = keep.max(1) - kept.len();
            if class.len() <= room {
                kept.extend_from_slice(class);
            } else {
                let ranges: Vec<(f64, f64)> =
                    class.iter().map(|&g| self.level_range(g, 0)).collect();
                let mut ceilings: Vec<f64> = ranges.iter().map(|r| r.1).collect();
                ceilings.sort_by(f64::total_cmp);
                let cut = ceilings[room - 1];
                kept.extend(
                    (class.iter().zip(&ranges))
                        // A NaN floor settles nothing: the group stays.
                        .filter(|(_, range)| range.0.partial_cmp(&cut) != Some(Ordering::Greater))
                        .map(|(&g, _)| g),
                );
            }
            start += class_size;
        }
        kept
    }

    /// Records in `found` the eligible groups of at least `m` features that extend `group` (a
    /// clique) by `candidates` (each adjacent to every member, above its highest) and that no
    /// group found already holds, each only when no larger group of its branch is eligible
    /// (some may still lie inside others: the caller keeps the maximal ones). Returns whether
    /// `group` or a larger group of the branch is eligible and recorded.
    fn split_below(
        &mut self,
        group: GroupMask,
        candidates: GroupMask,
        m: u32,
        found: &mut Found,
    ) -> bool {
        let n = group.count_ones();
        let reach = group | candidates;
        if n + candidates.count_ones() < m || found.holds(reach) {
            return false;
        }
        let bound = self.threshold.value();
        let ahead_first = self.look_ahead_first;
        // Every group below lies inside `reach`: when it is an eligible clique, it is the
        // branch's one maximal group (from three members on only: below three, a look-ahead
        // that fails costs more than it saves). Asked first when such groups are cheap
        // (`GroupLevels::look_ahead_first`): `group` inside it is then eligible too (Theorem
        // 4.3), so its own level is not needed; otherwise the group's level first rules more
        // look-aheads out.
        let clique = candidates != 0
            && n >= 3
            && members(candidates).all(|c| candidates & !(self.adj[c] | 1 << c) == 0);
        if ahead_first && clique && self.admitted(reach, group) {
            found.push(reach);
            return true;
        }
        // Bounds clear of the threshold settle the branch uncomputed (Theorem 4.3).
        if ahead_first && self.settled_beyond(group, bound) == Some(true) {
            return false;
        }
        // The group's own level rules the branch out when beyond. With the look-ahead first it
        // waits for the branch's first candidate: when that records a group, `group` lies
        // inside an eligible one, so is not beyond (Theorem 4.3), and its level is not needed
        // (the groups that lead to the maximal ones are most of a faulty frame's).
        let mut checked = false;
        if !ahead_first {
            if self.is_beyond(group, bound) {
                return false;
            }
            checked = true;
        }
        let mut covered = false;
        if !ahead_first && clique && self.admitted(reach, group) {
            found.push(reach);
            covered = true;
        } else {
            let mut rest = candidates;
            while rest != 0 {
                // The branches left lie inside `group` with the candidates left: once a group
                // found holds that, none of them records anything.
                if rest != candidates && found.holds(group | rest) {
                    break;
                }
                let j = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                covered |= self.split_below(group | 1 << j, rest & self.adj[j], m, found);
                if !covered && !checked {
                    if self.is_beyond(group, bound) {
                        return false;
                    }
                    checked = true;
                }
            }
        }
        if covered {
            return true;
        }
        // Recorded after its branch, and only when nothing larger in it was: the list the
        // branches below are checked against stays short.
        let eligible = n >= m && self.admitted(group, group);
        if eligible {
            found.push(group);
        }
        eligible
    }

    /// The levels of `groups` not yet known, computed together
    /// ([`GroupLevels::group_levels`]) and memoised.
    fn compute_levels(&mut self, groups: &[GroupMask]) {
        let mut missing: Vec<GroupMask> = (groups.iter().copied())
            .filter(|g| g.count_ones() >= 2 && !self.memo.contains_key(g))
            .collect();
        missing.sort_by(|&a, &b| lex_cmp(a, b));
        missing.dedup();
        let levels = self.levels.group_levels(&missing);
        self.memo.extend(missing.into_iter().zip(levels));
    }

    /// The level of `group` as known, else its bounds ([`GroupLevels::level_bounds`], with
    /// the look-ahead first and from three features on) widened by their rounding, else
    /// (−∞, +∞). `walked`: the walk's group, a prefix of `group`.
    fn level_range(&mut self, group: GroupMask, walked: GroupMask) -> (f64, f64) {
        if group.count_ones() <= 1 {
            return (0.0, 0.0);
        }
        if let Some(&k) = self.memo.get(&group) {
            return (k, k);
        }
        if !self.look_ahead_first || group.count_ones() < 3 {
            return (f64::NEG_INFINITY, f64::INFINITY);
        }
        if let Some(&range) = self.ranges.get(&group) {
            return range;
        }
        // Far more than the bounds' rounding: a group this close is computed instead.
        let widen = |x: f64| TIE + 1e-9 * (1.0 + x.abs());
        let range = self
            .levels
            .level_bounds(group, walked)
            .map_or((f64::NEG_INFINITY, f64::INFINITY), |b| {
                (b.floor - widen(b.floor), b.ceiling + widen(b.ceiling))
            });
        self.ranges.insert(group, range);
        range
    }

    /// Whether `group`'s level is within the threshold, settled by its bounds when they are
    /// clear of it, else computed.
    fn admitted(&mut self, group: GroupMask, walked: GroupMask) -> bool {
        if self.look_ahead_first {
            let (floor, ceiling) = self.level_range(group, walked);
            if self.threshold.admits(ceiling) {
                return true;
            }
            if floor > self.threshold.value() {
                return false;
            }
        }
        self.threshold.admits(self.level(group))
    }

    /// Whether `group`'s level is beyond `bound` ([`Search::beyond`]) as its bounds settle it
    /// (`None` when they do not).
    fn settled_beyond(&mut self, group: GroupMask, bound: f64) -> Option<bool> {
        let (floor, ceiling) = self.level_range(group, group);
        if floor > bound + TIE {
            Some(true)
        } else if ceiling.is_finite() && ceiling <= bound + TIE {
            Some(false)
        } else {
            None
        }
    }

    /// Whether `group`'s level is beyond `bound`, settled by its bounds or computed.
    fn is_beyond(&mut self, group: GroupMask, bound: f64) -> bool {
        let settled = (self.look_ahead_first)
            .then(|| self.settled_beyond(group, bound))
            .flatten();
        settled.unwrap_or_else(|| Self::beyond(self.level(group), bound))
    }
}
/// The groups found so far, in order, and by the lowest usable feature each leaves out: whether
/// one holds a group is then a look through the lists of the few features that group leaves out
/// (a faulty frame finds thousands of groups, each leaving out a few features, and checks every
/// branch against them).
struct Found {
    usable: GroupMask,
    groups: Vec<GroupMask>,
    /// Index 64: the groups that leave nothing out.
    by_lowest_out: Vec<Vec<GroupMask>>,
}

impl Found {
    fn new(usable: GroupMask) -> Self {
        Found {
            usable,
            groups: Vec::new(),
            by_lowest_out: vec![Vec::new(); 65],
        }
    }

    fn push(&mut self, group: GroupMask) {
        self.groups.push(group);
        let out = self.usable & !group;
        let lowest = if out == 0 { 64 } else { out.trailing_zeros() };
        self.by_lowest_out[lowest as usize].push(group);
    }

    /// Whether a group found holds `group` (usable features): one that leaves out only features
    /// `group` leaves out.
    fn holds(&self, group: GroupMask) -> bool {
        !self.by_lowest_out[64].is_empty()
            || members(self.usable & !group).any(|i| {
                // In blocks without an early exit inside, which the compiler vectorises.
                self.by_lowest_out[i].chunks(16).any(|block| {
                    block
                        .iter()
                        .fold(0, |held, &f| held | u8::from(group & !f == 0))
                        != 0
                })
            })
    }
}
