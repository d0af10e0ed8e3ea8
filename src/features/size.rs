//! Size functions of a closed contour: "distance from a line" measuring functions, the
//! 0-dimensional persistence diagram on a cycle (union-find, elder rule), the size function
//! ℓ(x, y), its G × G table over a fixed window and the table mean in closed form.

use super::FeatureError;

/// A fixed window `[a, b]` (in pixels) over which size-function tables are averaged.
///
/// The window is fixed per feature set, never normalised per image: normalising to
/// `[min φ, max φ]` would make a convex blob's feature constant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    a: f64,
    b: f64,
}

impl Window {
    /// A window `[a, b]`; `a < b`, both finite.
    pub fn new(a: f64, b: f64) -> Result<Self, FeatureError> {
        if a.is_finite() && b.is_finite() && a < b {
            Ok(Self { a, b })
        } else {
            Err(FeatureError::BadWindow { a, b })
        }
    }

    /// Lower end `a`.
    pub fn a(&self) -> f64 {
        self.a
    }

    /// Upper end `b`.
    pub fn b(&self) -> f64 {
        self.b
    }
}

/// The 0-dimensional persistence diagram of a function on a cycle graph.
///
/// Pairs are `(birth, death)` with `birth < death`; the essential class of the whole cycle is
/// `(min φ, +∞)` and comes first. Pairs of zero persistence are dropped: they never count in ℓ.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PersistenceDiagram {
    pairs: Vec<(f64, f64)>,
}

impl PersistenceDiagram {
    /// The diagram of `phi` on the cycle `0 – 1 – … – n−1 – 0`, by union-find over the vertices in
    /// increasing order of `phi` (ties broken by index). When two components meet, the younger one
    /// (larger birth value) dies (elder rule). An empty slice gives an empty diagram; a NaN or
    /// infinite value is an error.
    pub fn of_cycle(phi: &[f64]) -> Result<Self, FeatureError> {
        let mut scratch = CycleScratch::default();
        let mut diagram = Self::default();
        diagram.compute_into(phi, &mut scratch)?;
        Ok(diagram)
    }

    /// Recompute into `self`, reusing the buffers of `scratch` (the allocation-free hot path).
    ///
    /// The cycle is first reduced to its alternating local minima and maxima: dropping a vertex
    /// whose value lies between its neighbours' (plateaus included) changes no sublevel set's
    /// components nor which of them meet a lower one, so ℓ — and hence the diagram — is unchanged.
    pub(crate) fn compute_into(
        &mut self,
        phi: &[f64],
        scratch: &mut CycleScratch,
    ) -> Result<(), FeatureError> {
        self.pairs.clear();
        if let Some(i) = phi.iter().position(|v| !v.is_finite()) {
            return Err(FeatureError::NonFinite {
                what: "measuring function value",
                index: i,
            });
        }
        let mut extrema = std::mem::take(&mut scratch.extrema);
        cycle_extrema(phi, &mut extrema);
        self.union_find(&extrema, scratch);
        scratch.extrema = extrema;
        Ok(())
    }

    /// Union-find over the vertices of the cycle `phi` in increasing order (ties by index),
    /// elder rule; `phi` is finite.
    fn union_find(&mut self, phi: &[f64], scratch: &mut CycleScratch) {
        self.pairs.clear();
        let n = phi.len();
        if n == 0 {
            return;
        }
        let CycleScratch {
            keyed,
            order,
            parent,
            rank,
            ..
        } = scratch;
        // Sort (key, index) pairs of integers: the key maps f64 to u64 monotonically (the order
        // of `f64::total_cmp`), and the index breaks ties.
        keyed.clear();
        keyed.extend(phi.iter().enumerate().map(|(i, &v)| {
            let b = v.to_bits();
            let key = if b >> 63 == 1 { !b } else { b | (1 << 63) };
            (key, i as u32)
        }));
        keyed.sort_unstable();
        order.clear();
        order.extend(keyed.iter().map(|&(_, i)| i));
        // parent[v] == NONE: v not yet in the filtration. Roots are their component's oldest
        // vertex, so a root's birth value is phi[root].
        const NONE: u32 = u32::MAX;
        parent.clear();
        parent.resize(n, NONE);
        // rank[v] = position of v in `order`: the elder of two roots has the lower rank.
        rank.clear();
        rank.resize(n, 0);
        for (r, &v) in order.iter().enumerate() {
            rank[v as usize] = r as u32;
        }
        fn find(parent: &mut [u32], mut v: u32) -> u32 {
            let mut root = v;
            while parent[root as usize] != root {
                root = parent[root as usize];
            }
            // Path compression keeps later finds short.
            while parent[v as usize] != root {
                let next = parent[v as usize];
                parent[v as usize] = root;
                v = next;
            }
            root
        }
        self.pairs.push((phi[order[0] as usize], f64::INFINITY));
        for &v in order.iter() {
            let vi = v as usize;
            parent[vi] = v;
            let level = phi[vi];
            let left = ((vi + n - 1) % n) as u32;
            let right = ((vi + 1) % n) as u32;
            for w in [left, right] {
                if w == v || parent[w as usize] == NONE {
                    continue;
                }
                let rv = find(parent, v);
                let rw = find(parent, w);
                if rv == rw {
                    continue;
                }
                let (elder, younger) = if rank[rv as usize] < rank[rw as usize] {
                    (rv, rw)
                } else {
                    (rw, rv)
                };
                let birth = phi[younger as usize];
                if level > birth {
                    self.pairs.push((birth, level));
                }
                parent[younger as usize] = elder;
            }
        }
    }

    /// The pairs, essential class first (if the function was not empty).
    pub fn pairs(&self) -> &[(f64, f64)] {
        &self.pairs
    }

    /// ℓ(x, y): the number of connected components of `{φ ≤ y}` that contain a point with
    /// `φ ≤ x`, i.e. `#{(b, d) : b ≤ min(x, y), d > y}`. For `x ≥ y` this is the number of
    /// components of `{φ ≤ y}`. NaN arguments give 0.
    pub fn size_function(&self, x: f64, y: f64) -> usize {
        let x = x.min(y);
        self.pairs.iter().filter(|&&(b, d)| b <= x && d > y).count()
    }

    /// The mean of ℓ over the triangle `a ≤ x < y ≤ b` in closed form: `Σ sᵢ² / (b − a)²` with
    /// `sᵢ = (min(dᵢ, b) − max(bᵢ, a))⁺`.
    pub fn mean_closed_form(&self, window: Window) -> f64 {
        let (a, b) = (window.a, window.b);
        let sum: f64 = self
            .pairs
            .iter()
            .map(|&(birth, death)| {
                let s = (death.min(b) - birth.max(a)).max(0.0);
                s * s
            })
            .sum();
        sum / ((b - a) * (b - a))
    }

    /// The size-function table on a `grid × grid` lattice of cell centres over `window`.
    /// `grid == 0` is an error.
    pub fn table(&self, window: Window, grid: usize) -> Result<SizeTable, FeatureError> {
        if grid == 0 {
            return Err(FeatureError::BadGrid { grid });
        }
        let centres = SizeTable::centres(window, grid);
        let mut values = Vec::with_capacity(grid * grid);
        for &y in &centres {
            for &x in &centres {
                values.push(self.size_function(x, y) as u32);
            }
        }
        Ok(SizeTable {
            window,
            grid,
            values,
        })
    }

    /// The mean of the `grid × grid` table over its cells with `x < y` (the triangle). Tends to
    /// [`Self::mean_closed_form`] as `grid` grows (the error is O(1/grid)).
    pub fn mean_table(&self, window: Window, grid: usize) -> Result<f64, FeatureError> {
        Ok(self.table(window, grid)?.triangle_mean())
    }
}

/// Reusable buffers for [`PersistenceDiagram`] on cycles.
#[derive(Debug, Default, Clone)]
pub(crate) struct CycleScratch {
    extrema: Vec<f64>,
    keyed: Vec<(u64, u32)>,
    order: Vec<u32>,
    parent: Vec<u32>,
    rank: Vec<u32>,
}

/// The cyclic sequence of `phi` reduced to alternating strict local minima and maxima: plateaus
/// collapse to one value, vertices strictly between their neighbours go. A constant (or
/// one-vertex) cycle gives its single value; an empty one gives nothing.
fn cycle_extrema(phi: &[f64], out: &mut Vec<f64>) {
    out.clear();
    let n = phi.len();
    if n == 0 {
        return;
    }
    // Start right after a change of value so that no plateau wraps around the start.
    let Some(start) = (0..n).find(|&i| phi[i] != phi[(i + n - 1) % n]) else {
        out.push(phi[0]);
        return;
    };
    // Collapse plateaus.
    let mut runs: Vec<f64> = Vec::with_capacity(64);
    for k in 0..n {
        let v = phi[(start + k) % n];
        if runs.last() != Some(&v) {
            runs.push(v);
        }
    }
    // `start` differs from its predecessor, so the first and last runs differ: no wrap plateau.
    let m = runs.len();
    for i in 0..m {
        let (a, v, b) = (runs[(i + m - 1) % m], runs[i], runs[(i + 1) % m]);
        let between = (a < v && v < b) || (a > v && v > b);
        if !between {
            out.push(v);
        }
    }
}

/// A size-function table: ℓ at the cell centres of a `grid × grid` lattice over a window.
#[derive(Debug, Clone, PartialEq)]
pub struct SizeTable {
    window: Window,
    grid: usize,
    /// Row-major: `values[j * grid + i] = ℓ(xᵢ, yⱼ)`.
    values: Vec<u32>,
}

impl SizeTable {
    fn centres(window: Window, grid: usize) -> Vec<f64> {
        let h = (window.b - window.a) / grid as f64;
        (0..grid).map(|i| window.a + (i as f64 + 0.5) * h).collect()
    }

    /// The lattice size `G`.
    pub fn grid(&self) -> usize {
        self.grid
    }

    /// The window the table covers.
    pub fn window(&self) -> Window {
        self.window
    }

    /// ℓ(xᵢ, yⱼ) at cell centres `xᵢ = a + (i + ½)(b − a)/G`, `yⱼ` likewise; `None` outside the
    /// lattice.
    pub fn get(&self, i: usize, j: usize) -> Option<u32> {
        if i < self.grid && j < self.grid {
            self.values.get(j * self.grid + i).copied()
        } else {
            None
        }
    }

    /// Mean of ℓ over the cells with `i < j` (so `x < y`); 0 for `G = 1` (no such cell).
    pub fn triangle_mean(&self) -> f64 {
        let g = self.grid;
        let mut sum = 0u64;
        for j in 0..g {
            for i in 0..j {
                sum += u64::from(self.values[j * g + i]);
            }
        }
        let cells = g * g.saturating_sub(1) / 2;
        if cells == 0 {
            0.0
        } else {
            sum as f64 / cells as f64
        }
    }
}

/// "Distance from a line": for each point, its distance from the line through `centre` with
/// direction angle `angle` (radians, from the +x axis toward +y, i.e. image columns toward rows).
/// `signed` keeps the side of the line (the projection on the line's normal); unsigned is the
/// default used by the features. Appends to `out` after clearing it.
pub fn distance_from_line(
    points: &[[f64; 2]],
    centre: [f64; 2],
    angle: f64,
    signed: bool,
    out: &mut Vec<f64>,
) {
    let (s, c) = angle.sin_cos();
    out.clear();
    out.extend(points.iter().map(|p| {
        let h = -(p[0] - centre[0]) * s + (p[1] - centre[1]) * c;
        if signed {
            h
        } else {
            h.abs()
        }
    }));
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn sorted(mut p: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
        p.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
        p
    }

    #[test]
    fn hexagon_example_of_design_notes() {
        let d = PersistenceDiagram::of_cycle(&[0.0, 3.0, 1.0, 4.0, 2.0, 5.0]).unwrap();
        assert_eq!(d.pairs()[0], (0.0, f64::INFINITY));
        assert_eq!(
            sorted(d.pairs().to_vec()),
            vec![(0.0, f64::INFINITY), (1.0, 3.0), (2.0, 4.0)]
        );
        assert_eq!(d.size_function(1.5, 2.5), 2);
        assert_eq!(d.size_function(1.5, 3.5), 1);
        assert_eq!(d.size_function(-1.0, 2.0), 0);
        let w = Window::new(0.0, 5.0).unwrap();
        assert_eq!(d.mean_closed_form(w), 33.0 / 25.0);
        assert!((d.mean_closed_form(w) - 1.32).abs() < 1e-15);
    }

    #[test]
    fn table_mean_converges_to_closed_form() {
        let d = PersistenceDiagram::of_cycle(&[0.0, 3.0, 1.0, 4.0, 2.0, 5.0]).unwrap();
        let w = Window::new(0.0, 5.0).unwrap();
        let exact = d.mean_closed_form(w);
        let mut last = f64::INFINITY;
        for g in [10, 40, 160, 640] {
            let err = (d.mean_table(w, g).unwrap() - exact).abs();
            assert!(err <= 4.0 / g as f64, "G = {g}: error {err}");
            assert!(err <= last, "error grew at G = {g}");
            last = err;
        }
        assert!(last < 1e-2);
    }

    #[test]
    fn table_entries_match_size_function() {
        let d = PersistenceDiagram::of_cycle(&[0.0, 3.0, 1.0, 4.0, 2.0, 5.0]).unwrap();
        let t = d.table(Window::new(0.0, 5.0).unwrap(), 5).unwrap();
        // centres 0.5, 1.5, 2.5, 3.5, 4.5
        assert_eq!(t.get(1, 2), Some(2));
        assert_eq!(t.get(1, 3), Some(1));
        assert_eq!(t.get(0, 4), Some(1));
        assert_eq!(t.get(5, 0), None);
        assert_eq!(t.grid(), 5);
    }

    #[test]
    fn bad_inputs_are_errors() {
        assert!(matches!(
            PersistenceDiagram::of_cycle(&[0.0, f64::NAN]),
            Err(FeatureError::NonFinite { index: 1, .. })
        ));
        assert!(Window::new(1.0, 1.0).is_err());
        assert!(Window::new(f64::NAN, 1.0).is_err());
        let d = PersistenceDiagram::of_cycle(&[]).unwrap();
        assert!(d.pairs().is_empty());
        assert!(d.table(Window::new(0.0, 1.0).unwrap(), 0).is_err());
        let one = PersistenceDiagram::of_cycle(&[2.0]).unwrap();
        assert_eq!(one.pairs(), &[(2.0, f64::INFINITY)]);
    }

    #[test]
    fn distance_from_line_signed_and_unsigned() {
        let pts = [[1.0, 3.0], [1.0, -1.0], [4.0, 1.0]];
        let mut out = Vec::new();
        distance_from_line(&pts, [1.0, 1.0], 0.0, true, &mut out);
        assert_eq!(out, vec![2.0, -2.0, 0.0]);
        distance_from_line(&pts, [1.0, 1.0], 0.0, false, &mut out);
        assert_eq!(out, vec![2.0, 2.0, 0.0]);
        distance_from_line(
            &pts,
            [1.0, 1.0],
            std::f64::consts::FRAC_PI_2,
            false,
            &mut out,
        );
        assert!((out[2] - 3.0).abs() < 1e-12 && out[0].abs() < 1e-12);
    }

    /// ℓ(x, y) straight from the definition: components of {φ ≤ y} on the cycle that hold a
    /// vertex with φ ≤ x.
    fn brute_force(phi: &[f64], x: f64, y: f64) -> usize {
        let n = phi.len();
        let inside: Vec<bool> = phi.iter().map(|&v| v <= y).collect();
        if inside.iter().all(|&b| b) {
            return usize::from(phi.iter().any(|&v| v <= x));
        }
        // Start just after a vertex outside D_y and walk once around, cutting runs.
        let start = inside.iter().position(|&b| !b).unwrap();
        let mut count = 0;
        let mut run_has_x = false;
        let mut in_run = false;
        for k in 1..=n {
            let i = (start + k) % n;
            if inside[i] {
                in_run = true;
                run_has_x |= phi[i] <= x;
            } else if in_run {
                count += usize::from(run_has_x);
                in_run = false;
                run_has_x = false;
            }
        }
        count
    }

    proptest! {
        #[test]
        fn reduction_to_extrema_keeps_the_diagram(
            phi in prop::collection::vec(0u8..6, 0..40),
        ) {
            let phi: Vec<f64> = phi.into_iter().map(f64::from).collect();
            let mut full = PersistenceDiagram::default();
            full.union_find(&phi, &mut CycleScratch::default());
            let reduced = PersistenceDiagram::of_cycle(&phi).unwrap();
            prop_assert_eq!(sorted(full.pairs().to_vec()), sorted(reduced.pairs().to_vec()));
            let mut ext = Vec::new();
            cycle_extrema(&phi, &mut ext);
            // Extrema alternate: each value is below both or above both of its neighbours.
            let m = ext.len();
            if m > 1 {
                prop_assert!(m % 2 == 0);
                for i in 0..m {
                    let (a, v, b) = (ext[(i + m - 1) % m], ext[i], ext[(i + 1) % m]);
                    prop_assert!((v < a && v < b) || (v > a && v > b));
                }
            }
        }

        #[test]
        fn persistence_matches_brute_force_definition(
            phi in prop::collection::vec(0u8..12, 1..40),
            probes in prop::collection::vec((-1i32..26, -1i32..26), 1..30),
        ) {
            // Small integer values make ties frequent; half-integers probe between levels too.
            let phi: Vec<f64> = phi.into_iter().map(f64::from).collect();
            let d = PersistenceDiagram::of_cycle(&phi).unwrap();
            for (x2, y2) in probes {
                let (x, y) = (f64::from(x2) / 2.0, f64::from(y2) / 2.0);
                prop_assert_eq!(d.size_function(x, y), brute_force(&phi, x, y), "x={} y={}", x, y);
            }
            // One essential class, born at the minimum.
            let min = phi.iter().cloned().fold(f64::INFINITY, f64::min);
            prop_assert_eq!(d.pairs()[0], (min, f64::INFINITY));
            prop_assert_eq!(d.pairs().iter().filter(|p| p.1.is_infinite()).count(), 1);
        }

        #[test]
        fn closed_form_is_triangle_integral(
            phi in prop::collection::vec(-20.0f64..20.0, 1..30),
            a in -25.0f64..0.0, len in 1.0f64..50.0,
        ) {
            let d = PersistenceDiagram::of_cycle(&phi).unwrap();
            let w = Window::new(a, a + len).unwrap();
            let exact = d.mean_closed_form(w);
            let table = d.mean_table(w, 400).unwrap();
            // Each pair's error is at most ~2 cells' worth of its side over the triangle.
            let bound = 4.0 * d.pairs().len() as f64 / 400.0;
            prop_assert!((exact - table).abs() <= bound, "exact {} table {}", exact, table);
        }
    }
}
