//! The splitting policy's search: the maximal eligible groups of at least `min_size` features.
//!
//! The search walks the cliques depth first in lexicographic order, and rules a branch out
//! before computing anything below it when the group is beyond the bound (Theorem 4.3: a
//! group's level only grows as features are added, so every larger group is too) or when the
//! group with every candidate lies inside a group already found. It looks ahead: when the group
//! with every candidate is an eligible clique, that is the branch's one maximal group and
//! nothing below it (not even the group's own level) is computed. When such groups are cheap
//! (`GroupLevels::look_ahead_first`), a floor of the level rules groups out uncomputed, and a
//! group's own level waits until its first branch is searched: when that records a group, the
//! level is never needed. Groups are recorded after their branch, only when nothing larger in
//! it is eligible, so the list each branch is checked against stays short. Levels are the
//! memoised ones of the other policies: each group's level is the same bits whatever came
//! before it.

use super::{
    lex_cmp, maximal_cliques, members, sort_alternatives, GroupLevels, GroupMask, Search, TIE,
};

impl<L: GroupLevels> Search<'_, L> {
    /// The splitting policy's alternatives: the maximal eligible groups of at least `min_size`
    /// features, by decreasing size, then increasing level, then feature list.
    pub(super) fn maximal_eligible(
        &mut self,
        usable: GroupMask,
        min_size: usize,
    ) -> Vec<(f64, GroupMask)> {
        let m = min_size.max(1) as u32;
        self.cut = self.threshold.value();
        // An eligible maximal clique is a maximal eligible group; below the others, search.
        let mut found = Found::new(usable);
        for g in maximal_cliques(usable, &self.adj) {
            if g.count_ones() >= m && self.threshold.admits(self.level(g)) {
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
        let mut alternatives: Vec<(f64, GroupMask)> = Vec::new();
        for g in found {
            if !alternatives.iter().any(|&(_, a)| g & a == g) {
                alternatives.push((self.level(g), g));
            }
        }
        sort_alternatives(&mut alternatives);
        alternatives
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
        if ahead_first
            && clique
            && !self.floor_above(reach, bound)
            && self.threshold.admits(self.level(reach))
        {
            found.push(reach);
            return true;
        }
        // A floor beyond the bound rules the branch out uncomputed (Theorem 4.3).
        if ahead_first && self.floor_above(group, bound + TIE) {
            return false;
        }
        // The group's own level rules the branch out when beyond. With the look-ahead first it
        // waits for the branch's first candidate: when that records a group, `group` lies
        // inside an eligible one, so is not beyond (Theorem 4.3), and its level is not needed
        // (the groups that lead to the maximal ones are most of a faulty frame's).
        let mut own = None;
        if !ahead_first {
            let k = self.level(group);
            if Self::beyond(k, bound) {
                return false;
            }
            own = Some(k);
        }
        let mut covered = false;
        if !ahead_first && clique && self.threshold.admits(self.level(reach)) {
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
                if !covered && own.is_none() {
                    let k = self.level(group);
                    if Self::beyond(k, bound) {
                        return false;
                    }
                    own = Some(k);
                }
            }
        }
        if covered {
            return true;
        }
        let k = match own {
            Some(k) => k,
            None => self.level(group),
        };
        // Recorded after its branch, and only when nothing larger in it was: the list the
        // branches below are checked against stays short.
        let eligible = n >= m && self.threshold.admits(k);
        if eligible {
            found.push(group);
        }
        eligible
    }

    /// Whether the floor of `group`'s level ([`GroupLevels::level_floor`]) is above `bound` by
    /// more than its rounding, so the level is too; false once the level is known.
    fn floor_above(&mut self, group: GroupMask, bound: f64) -> bool {
        if group.count_ones() < 3 || self.memo.contains_key(&group) {
            return false;
        }
        let margin = TIE + 1e-9 * (1.0 + bound.abs());
        (self.levels.level_floor(group)).is_some_and(|floor| floor > bound + margin)
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
