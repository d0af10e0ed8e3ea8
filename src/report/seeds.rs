//! Findings over many seeds: each variant's mean error as a mean ± 95 % confidence interval across
//! master seeds, and each comparison as a paired difference across the same seeds.

use serde::{Deserialize, Serialize};

use super::{ConfidenceSummary, RunSummary};
pub use crate::scenario::{Comparison, Side};

/// A mean across seeds with its 95 % confidence interval (Student's t, n − 1 degrees of freedom).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    /// Mean of the values.
    pub mean: f64,
    /// Half the width of the 95 % interval; `None` with fewer than two values.
    pub half_width: Option<f64>,
    /// Number of values (seeds).
    pub n: usize,
}

impl Interval {
    /// The interval of `values`; `None` when there are none.
    pub fn of(values: &[f64]) -> Option<Self> {
        let n = values.len();
        if n == 0 {
            return None;
        }
        let mean = values.iter().sum::<f64>() / n as f64;
        let half_width = (n > 1).then(|| {
            let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            t_975(n - 1) * (var / n as f64).sqrt()
        });
        Some(Self {
            mean,
            half_width,
            n,
        })
    }

    /// `mean ± half width` (the mean alone with one value).
    pub fn text(&self, digits: usize) -> String {
        match self.half_width {
            Some(h) => format!("{:.digits$} ± {:.digits$}", self.mean, h),
            None => format!("{:.digits$}", self.mean),
        }
    }
}

/// The 97.5 % quantile of Student's t with `dof` degrees of freedom (a table; between tabulated
/// values the smaller dof, so the interval errs wide).
fn t_975(dof: usize) -> f64 {
    const TABLE: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
        2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
        2.052, 2.048, 2.045, 2.042,
    ];
    match dof {
        0 => f64::INFINITY,
        1..=30 => TABLE[dof - 1],
        31..=39 => 2.042,
        40..=59 => 2.021,
        60..=119 => 2.000,
        _ => 1.980,
    }
}

/// What a paired difference shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// The whole interval is below zero: the left side has the lower error.
    LeftLower,
    /// The whole interval is above zero.
    LeftHigher,
    /// The interval contains zero.
    NoMeasurableEffect,
    /// Fewer than two paired seeds: no interval.
    TooFewSeeds,
}

impl Verdict {
    fn of(difference: &Interval) -> Self {
        match difference.half_width {
            None => Verdict::TooFewSeeds,
            Some(h) if difference.mean + h < 0.0 => Verdict::LeftLower,
            Some(h) if difference.mean - h > 0.0 => Verdict::LeftHigher,
            Some(_) => Verdict::NoMeasurableEffect,
        }
    }

    /// A short phrase.
    pub fn text(self) -> &'static str {
        match self {
            Verdict::LeftLower => "left lower",
            Verdict::LeftHigher => "left higher",
            Verdict::NoMeasurableEffect => "no measurable effect",
            Verdict::TooFewSeeds => "one seed: no interval",
        }
    }
}

/// One variant's method across seeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AcrossSeeds {
    /// Variant and method.
    pub side: Side,
    /// The seeds, ascending.
    pub seeds: Vec<u64>,
    /// Mean error (mm) across them.
    pub mean_error: Interval,
    /// Area under the risk–coverage curve (mm) across them.
    #[serde(default)]
    pub aurc: Option<Interval>,
    /// Share of the clean frames its regions held, across them.
    #[serde(default)]
    pub coverage_clean: Option<Interval>,
    /// Share of the corrupted frames its regions held (abstentions cover the workspace).
    #[serde(default)]
    pub coverage_corrupted: Option<Interval>,
    /// Share of the clean frames it abstained on.
    #[serde(default)]
    pub abstained_clean: Option<Interval>,
}

/// A comparison measured: the paired difference of mean errors (mm) and what it shows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Finding {
    /// The comparison.
    pub comparison: Comparison,
    /// Left minus right, over the seeds both sides ran.
    pub difference: Interval,
    /// What the interval shows.
    pub verdict: Verdict,
}

/// What a finding's name claims of left − right, read from the comparison sign between its two
/// sides: `b < a` (lower), `c > a` (higher), `d = a` (no measurable difference).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Claim {
    /// The left side's error is lower.
    Lower,
    /// The left side's error is higher.
    Higher,
    /// No measurable difference.
    Same,
}

impl Claim {
    /// The claim in `name`: exactly one of ` < `, ` > `, ` = ` in it; `None` otherwise (the
    /// pairs of methods a sweep adds, `knn − gp`, claim nothing).
    pub fn of(name: &str) -> Option<Self> {
        let found: Vec<Claim> = [
            (" < ", Claim::Lower),
            (" > ", Claim::Higher),
            (" = ", Claim::Same),
        ]
        .into_iter()
        .filter(|(sign, _)| name.matches(sign).count() == 1)
        .map(|(_, claim)| claim)
        .collect();
        match found.as_slice() {
            [one] => Some(*one),
            _ => None,
        }
    }

    fn verdict(self) -> Verdict {
        match self {
            Claim::Lower => Verdict::LeftLower,
            Claim::Higher => Verdict::LeftHigher,
            Claim::Same => Verdict::NoMeasurableEffect,
        }
    }
}

impl Finding {
    /// Whether the claim in the finding's name holds: `None` without a claim, with one seed, or
    /// when a claimed direction is not shown (the interval contains zero).
    pub fn holds(&self) -> Option<bool> {
        let claim = Claim::of(&self.comparison.name)?;
        match (claim, self.verdict) {
            (_, Verdict::TooFewSeeds) => None,
            (Claim::Lower | Claim::Higher, Verdict::NoMeasurableEffect) => None,
            (claim, verdict) => Some(claim.verdict() == verdict),
        }
    }

    /// In words, with the numbers: `holds: left − right = −1.2300 ± 0.1000 mm, below 0`,
    /// `does not hold: …` or `not shown: …`; without a claim what the interval shows.
    pub fn statement(&self) -> String {
        let d = &self.difference;
        let shows = match self.verdict {
            Verdict::LeftLower => "below 0: left lower",
            Verdict::LeftHigher => "above 0: left higher",
            Verdict::NoMeasurableEffect => "contains 0: no measurable difference",
            Verdict::TooFewSeeds => {
                return "untested: one seed, no interval (run --seeds N)".into()
            }
        };
        let numbers = format!("left − right = {} mm, {shows}", d.text(4));
        match (self.holds(), Claim::of(&self.comparison.name)) {
            (Some(true), _) => format!("holds: {numbers}"),
            (Some(false), _) => format!("does not hold: {numbers}"),
            (None, Some(_)) => format!("not shown: {numbers}"),
            (None, None) => numbers,
        }
    }
}

/// Every variant and comparison across seeds.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SeedReport {
    /// Per variant and method, in first-seen order.
    pub variants: Vec<AcrossSeeds>,
    /// The comparisons given, then every pair of methods within each variant.
    pub findings: Vec<Finding>,
}

/// Mean error of a side in one run.
fn error_of(run: &RunSummary, side: &Side) -> Option<f64> {
    (run.scenario == side.scenario)
        .then(|| run.method(&side.method)?.error.map(|e| e.mean))
        .flatten()
}

impl SeedReport {
    /// The report of `runs` (any number of seeds per variant) for the `comparisons` given, then,
    /// within each variant, every method against every later one (in the runs' method order).
    pub fn new(runs: &[RunSummary], comparisons: &[Comparison]) -> Self {
        let mut sides: Vec<Side> = Vec::new();
        for r in runs {
            for m in &r.methods {
                let side = Side {
                    scenario: r.scenario.clone(),
                    method: m.method.clone(),
                };
                if !sides.contains(&side) {
                    sides.push(side);
                }
            }
        }
        let variants = sides
            .iter()
            .filter_map(|side| {
                let mut pairs: Vec<(u64, f64)> = runs
                    .iter()
                    .filter_map(|r| Some((r.seed, error_of(r, side)?)))
                    .collect();
                pairs.sort_by_key(|p| p.0);
                let errors: Vec<f64> = pairs.iter().map(|p| p.1).collect();
                let across = |figure: &dyn Fn(&ConfidenceSummary, &RunSummary) -> Option<f64>| {
                    let values: Vec<f64> = (runs.iter())
                        .filter(|r| r.scenario == side.scenario)
                        .filter_map(|r| figure(r.method(&side.method)?.confidence.as_ref()?, r))
                        .collect();
                    Interval::of(&values)
                };
                Some(AcrossSeeds {
                    side: side.clone(),
                    seeds: pairs.iter().map(|p| p.0).collect(),
                    mean_error: Interval::of(&errors)?,
                    aurc: across(&|c, _| Some(c.all.aurc)),
                    coverage_clean: across(&|c, _| c.coverage_clean),
                    coverage_corrupted: across(&|c, _| c.coverage_corrupted),
                    abstained_clean: across(&|c, r| {
                        let faults = r.method(&side.method)?.faults.as_ref();
                        let corrupted = faults.map_or(0, |f| f.corrupted_frames);
                        Some(c.abstained_clean_share(r.frames, corrupted))
                    }),
                })
            })
            .collect();
        let mut all = comparisons.to_vec();
        for (k, left) in sides.iter().enumerate() {
            for right in sides[k + 1..]
                .iter()
                .filter(|s| s.scenario == left.scenario)
            {
                all.push(Comparison {
                    name: format!("{} − {}", left.method, right.method),
                    left: left.clone(),
                    right: right.clone(),
                });
            }
        }
        let findings = all
            .into_iter()
            .filter_map(|comparison| {
                let mut differences: Vec<(u64, f64)> = runs
                    .iter()
                    .filter_map(|l| {
                        let a = error_of(l, &comparison.left)?;
                        let b = runs
                            .iter()
                            .filter(|r| r.seed == l.seed)
                            .find_map(|r| error_of(r, &comparison.right))?;
                        Some((l.seed, a - b))
                    })
                    .collect();
                differences.sort_by_key(|d| d.0);
                let values: Vec<f64> = differences.iter().map(|d| d.1).collect();
                let difference = Interval::of(&values)?;
                Some(Finding {
                    verdict: Verdict::of(&difference),
                    comparison,
                    difference,
                })
            })
            .collect();
        Self { variants, findings }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::Expectations;

    #[test]
    fn a_claim_is_read_from_the_sign_between_its_sides() {
        assert_eq!(Claim::of("b < a"), Some(Claim::Lower));
        assert_eq!(Claim::of("c > a"), Some(Claim::Higher));
        assert_eq!(Claim::of("d = a"), Some(Claim::Same));
        assert_eq!(Claim::of("evidential − knn"), None);
        assert_eq!(Claim::of("a < b < c"), None);
    }

    fn run(scenario: &str, seed: u64, errors: &[(&str, f64)]) -> RunSummary {
        RunSummary {
            scenario: scenario.into(),
            seed,
            samples: 1,
            adaptive_added: 0,
            features: vec![],
            frames: 1,
            evidential: None,
            methods: errors
                .iter()
                .map(|&(m, e)| crate::report::records::tests::method(m, &[e], 0))
                .collect(),
            paper_error: None,
            limit: None,
            expect: Expectations::default(),
            calibration_reach: None,
        }
    }

    #[test]
    fn intervals_by_hand() {
        // Mean 2, sample sd 1, n = 3: half width t(2) · 1/√3 = 4.303 / 1.732.
        let i = Interval::of(&[1.0, 2.0, 3.0]).unwrap();
        assert_eq!(i.mean, 2.0);
        assert!((i.half_width.unwrap() - 4.303 / 3f64.sqrt()).abs() < 1e-12);
        assert_eq!(Interval::of(&[5.0]).unwrap().half_width, None);
        assert!(Interval::of(&[]).is_none());
        assert_eq!(t_975(45), 2.021);
    }

    #[test]
    fn paired_differences_pair_by_seed() {
        // b is 1 lower than a on every seed, although both vary a lot across seeds: paired, the
        // difference is exact; c differs from a by ±0.5 alternately: no measurable effect.
        let mut runs = Vec::new();
        for (seed, base) in [(1, 3.0), (2, 7.0), (3, 5.0), (4, 9.0)] {
            let wobble = if seed % 2 == 0 { 0.5 } else { -0.5 };
            runs.push(run(
                "p-a",
                seed,
                &[("evidential", base), ("knn", base - 2.0)],
            ));
            runs.push(run("p-b", seed, &[("evidential", base - 1.0)]));
            runs.push(run("p-c", seed, &[("evidential", base + wobble)]));
        }
        let side = |s: &str| Side {
            scenario: s.into(),
            method: "evidential".into(),
        };
        let comparisons = [
            Comparison {
                name: "b < a".into(),
                left: side("p-b"),
                right: side("p-a"),
            },
            Comparison {
                name: "c vs a".into(),
                left: side("p-c"),
                right: side("p-a"),
            },
        ];
        let report = SeedReport::new(&runs, &comparisons);
        let b = &report.findings[0];
        assert_eq!(b.difference.mean, -1.0);
        assert_eq!(b.difference.half_width, Some(0.0));
        assert_eq!(b.verdict, Verdict::LeftLower);
        let c = &report.findings[1];
        assert_eq!(c.difference.mean, 0.0);
        assert_eq!(c.verdict, Verdict::NoMeasurableEffect);
        // The automatic comparison of a's methods: evidential − knn = 2 on every seed.
        let auto = &report.findings[2];
        assert_eq!(auto.comparison.name, "evidential − knn");
        assert_eq!(
            (auto.difference.mean, auto.verdict),
            (2.0, Verdict::LeftHigher)
        );
        assert_eq!(report.findings.len(), 3);
        // In words: b < a holds; c vs a claims nothing; a claim the interval refutes fails.
        assert_eq!(b.holds(), Some(true));
        assert_eq!(
            b.statement(),
            "holds: left − right = -1.0000 ± 0.0000 mm, below 0: left lower"
        );
        assert_eq!(c.holds(), None);
        assert!(
            c.statement().starts_with("left − right = 0.0000"),
            "{}",
            c.statement()
        );
        let mut refuted = b.clone();
        refuted.comparison.name = "b > a".into();
        assert_eq!(refuted.holds(), Some(false));
        assert!(refuted.statement().starts_with("does not hold: "));
        refuted.comparison.name = "b = a".into();
        assert_eq!(refuted.holds(), Some(false));
        let mut unshown = c.clone();
        unshown.comparison.name = "c < a".into();
        assert_eq!(unshown.holds(), None);
        assert!(unshown.statement().starts_with("not shown: "));
        let a = &report.variants[0];
        assert_eq!((a.side.scenario.as_str(), a.seeds.len()), ("p-a", 4));
        assert_eq!(a.mean_error.mean, 6.0);
    }
}
