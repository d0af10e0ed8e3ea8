//! The splitting policy's search: the maximal eligible groups of at least `min_size` features.
//!
//! Eligible groups are closed under taking subsets (Theorem 4.3: a group's level only grows as
//! features are added), so the search walks the cliques depth first and, below each group,
//! (1) keeps only the candidates whose addition stays within the bound (a candidate beyond it
//! rules out every larger group holding it, uncomputed), (2) skips the branch when the group and
//! every kept candidate lie inside an alternative already found, and (3) looks ahead: when the
//! group with every kept candidate is itself an eligible clique, it is the one maximal group of
//! the branch, and nothing below it is computed. Levels are the memoised ones of the other
//! policies, so each group's level is the same bits whatever the walk computed before it.

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
    /// clique, not beyond the bound) by `candidates` (each adjacent to every member, above its
    /// highest) and that no group found already holds; with those, possibly some groups inside
    /// others (the caller keeps the maximal ones).
    fn split_below(
        &mut self,
        group: GroupMask,
        candidates: GroupMask,
        m: u32,
        found: &mut Vec<GroupMask>,
    ) {
        let n = group.count_ones();
        let within = |found: &[GroupMask], reach: GroupMask| found.iter().any(|&f| reach & !f == 0);
        if n + candidates.count_ones() < m || within(found, group | candidates) {
            return;
        }
        let bound = self.threshold.value();
        let k = self.level(group);
        if Self::beyond(k, bound) {
            return;
        }
        if n >= m && self.threshold.admits(k) {
            found.push(group);
        }
        // Pairs are edges of the conflict graph: within the threshold already.
        let kept = if n < 2 {
            candidates
        } else {
            members(candidates)
                .filter(|&c| !Self::beyond(self.level(group | 1 << c), bound))
                .fold(0, |kept, c| kept | 1 << c)
        };
        let reach = group | kept;
        if kept == 0 || reach.count_ones() < m || within(found, reach) {
            return;
        }
        // Every group below lies inside `reach`: when it is an eligible clique, it is the
        // branch's one maximal group.
        let clique = members(kept).all(|c| kept & !(self.adj[c] | 1 << c) == 0);
        if clique && self.threshold.admits(self.level(reach)) {
            found.push(reach);
            return;
        }
        let mut rest = kept;
        while rest != 0 {
            let j = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            self.split_below(group | 1 << j, rest & self.adj[j], m, found);
        }
    }
}
