//! The splitting policy's search: the maximal eligible groups of at least `min_size` features.
//!
//! The search walks the cliques depth first in lexicographic order, and rules a branch out
//! before computing anything below it when the group is beyond the bound (Theorem 4.3: a
//! group's level only grows as features are added, so every larger group is too) or when the
//! group with every candidate lies inside a group already found. It looks ahead: when the group
//! with every candidate is an eligible clique, that is the branch's one maximal group and
//! nothing below it (not even the group's own level) is computed. Groups are recorded after
//! their branch, only when nothing larger in it is eligible, so the list each branch is checked
//! against stays short. Levels are the memoised ones of the other policies: each group's level
//! is the same bits whatever came before it.

use super::{lex_cmp, maximal_cliques, members, sort_alternatives, GroupLevels, GroupMask, Search};

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
        let mut found: Vec<GroupMask> = Vec::new();
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
        found: &mut Vec<GroupMask>,
    ) -> bool {
        let n = group.count_ones();
        let reach = group | candidates;
        if n + candidates.count_ones() < m || found.iter().any(|&f| reach & !f == 0) {
            return false;
        }
        // Every group below lies inside `reach`: when it is an eligible clique, it is the
        // branch's one maximal group (from three members on only: below three, a look-ahead
        // that fails costs more than it saves). Asked first when such groups are cheap
        // (`GroupLevels::look_ahead_first`): `group` inside it is then eligible too (Theorem
        // 4.3), so its own level is not needed; otherwise the group's level first rules more
        // look-aheads out.
        let clique = candidates != 0
            && n >= 3
            && members(candidates).all(|c| candidates & !(self.adj[c] | 1 << c) == 0);
        let ahead_first = self.look_ahead_first;
        if ahead_first && clique && self.threshold.admits(self.level(reach)) {
            found.push(reach);
            return true;
        }
        let k = self.level(group);
        if Self::beyond(k, self.threshold.value()) {
            return false;
        }
        let eligible = n >= m && self.threshold.admits(k);
        let mut covered = false;
        if !ahead_first && clique && self.threshold.admits(self.level(reach)) {
            found.push(reach);
            covered = true;
        } else {
            let mut rest = candidates;
            while rest != 0 {
                let j = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                covered |= self.split_below(group | 1 << j, rest & self.adj[j], m, found);
            }
        }
        // Recorded after its branch, and only when nothing larger in it was: the list the
        // branches below are checked against stays short.
        if eligible && !covered {
            found.push(group);
        }
        eligible || covered
    }
}
