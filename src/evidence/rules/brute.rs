//! Brute-force definitions of every rule, written from the formulas and independently of the
//! library: frames of at most 16 elements, subsets as u16 bit masks, every tuple of focal sets
//! enumerated, plain f64.

use std::collections::HashMap;

use super::super::mass::MassFunction;

/// A mass function as (bit mask, mass) pairs.
pub type Bf = Vec<(u16, f64)>;
/// A combined function: mass per bit mask (0 is ∅).
pub type Map = HashMap<u16, f64>;

pub fn to_bf(m: &MassFunction) -> Bf {
    m.focal()
        .map(|(s, x)| (s.iter().fold(0u16, |b, i| b | (1 << i)), x))
        .collect()
}

/// Call `visit` with every tuple (one focal set per function) as a slice of (mask, mass).
pub fn tuples(fs: &[Bf], visit: &mut impl FnMut(&[(u16, f64)])) {
    fn go(fs: &[Bf], chosen: &mut Vec<(u16, f64)>, visit: &mut impl FnMut(&[(u16, f64)])) {
        if chosen.len() == fs.len() {
            visit(chosen);
            return;
        }
        for &pair in &fs[chosen.len()] {
            chosen.push(pair);
            go(fs, chosen, visit);
            chosen.pop();
        }
    }
    go(fs, &mut Vec::new(), visit);
}

fn product(t: &[(u16, f64)]) -> f64 {
    t.iter().map(|p| p.1).product()
}

fn meet(t: &[(u16, f64)]) -> u16 {
    t.iter().fold(u16::MAX, |b, p| b & p.0)
}

fn join(t: &[(u16, f64)]) -> u16 {
    t.iter().fold(0, |b, p| b | p.0)
}

/// m∩, with ∅ at key 0.
pub fn conjunctive(fs: &[Bf]) -> Map {
    let mut out = Map::new();
    tuples(fs, &mut |t| {
        *out.entry(meet(t)).or_insert(0.0) += product(t)
    });
    out
}

/// Dempster's rule and κ; `None` on total conflict.
pub fn dempster(fs: &[Bf]) -> (Option<Map>, f64) {
    let mut c = conjunctive(fs);
    let kappa = c.remove(&0).unwrap_or(0.0);
    if c.values().sum::<f64>() <= 0.0 {
        return (None, kappa);
    }
    let norm = 1.0 - kappa;
    (
        Some(c.into_iter().map(|(a, m)| (a, m / norm)).collect()),
        kappa,
    )
}

pub fn yager(fs: &[Bf], full: u16) -> Map {
    let mut c = conjunctive(fs);
    let kappa = c.remove(&0).unwrap_or(0.0);
    *c.entry(full).or_insert(0.0) += kappa;
    c
}

pub fn dubois_prade(fs: &[Bf]) -> Map {
    let mut out = Map::new();
    tuples(fs, &mut |t| {
        let a = if meet(t) != 0 { meet(t) } else { join(t) };
        *out.entry(a).or_insert(0.0) += product(t);
    });
    out
}

pub fn pcr6(fs: &[Bf]) -> Map {
    let mut out = Map::new();
    tuples(fs, &mut |t| {
        let p = product(t);
        if meet(t) != 0 {
            *out.entry(meet(t)).or_insert(0.0) += p;
        } else {
            let sum: f64 = t.iter().map(|x| x.1).sum();
            for &(a, m) in t {
                *out.entry(a).or_insert(0.0) += p * m / sum;
            }
        }
    });
    out
}

pub fn disjunctive(fs: &[Bf]) -> Map {
    let mut out = Map::new();
    tuples(fs, &mut |t| {
        *out.entry(join(t)).or_insert(0.0) += product(t)
    });
    out
}

/// Murphy: the mean, then Dempster's rule on n copies of it.
pub fn murphy(fs: &[Bf]) -> (Option<Map>, f64) {
    let mut mean = Map::new();
    for f in fs {
        for &(a, m) in f {
            *mean.entry(a).or_insert(0.0) += m / fs.len() as f64;
        }
    }
    let mean: Bf = mean.into_iter().collect();
    dempster(&vec![mean; fs.len()])
}

/// The cautious rule on a frame of `n`: w from q by the decomposition's formula, the minimum,
/// then the conjunctive combination of the simple functions A^w (signed masses when w > 1).
pub fn cautious(fs: &[Bf], n: usize) -> Map {
    let full = (1u32 << n) - 1;
    let supersets = |a: u32| (0..=full).filter(move |b| b & a == a);
    let mut w = vec![f64::INFINITY; full as usize];
    for f in fs {
        let q = |b: u32| -> f64 {
            f.iter()
                .filter(|(a, _)| u32::from(*a) & b == b)
                .map(|p| p.1)
                .sum()
        };
        for a in 0..full {
            let s: f64 = supersets(a)
                .map(|b| {
                    let sign = if (b ^ a).count_ones() % 2 == 0 {
                        1.0
                    } else {
                        -1.0
                    };
                    sign * q(b).ln()
                })
                .sum();
            w[a as usize] = w[a as usize].min((-s).exp());
        }
    }
    // Dense conjunctive combination of A^w(A) for every A ≠ Ω, starting from the vacuous function.
    let mut m = vec![0.0; full as usize + 1];
    m[full as usize] = 1.0;
    for a in 0..full {
        let wa = w[a as usize];
        let mut next = vec![0.0; full as usize + 1];
        for (b, &mb) in m.iter().enumerate() {
            next[b] += mb * wa;
            next[b & a as usize] += mb * (1.0 - wa);
        }
        m = next;
    }
    m.into_iter()
        .enumerate()
        .map(|(b, x)| (b as u16, x))
        .collect()
}
