//! The plots of a sweep: mean error per variant and method (with across-seed intervals), against
//! the evidential model's state count within one feature set, and against a numeric setting the
//! variants differ in.

use std::collections::BTreeMap;
use std::path::Path;

use super::plot::{plot_errors_by_variant, plot_series, BarSeries, PlotSeries};
use super::run_plots::Written;
use super::{ReportError, RunSummary, SeedReport};

/// What the sweep's plots are drawn from.
#[derive(Debug, Clone, Copy)]
pub struct SweepPlots<'a> {
    /// Each variant's first run, in the sweep's order.
    pub first: &'a [&'a RunSummary],
    /// The report across seeds (its intervals are drawn where a variant ran on several seeds).
    pub across: &'a SeedReport,
    /// Each variant's scenario as TOML, by variant name (empty: no plot against a setting).
    pub settings: &'a [(String, String)],
}

impl SweepPlots<'_> {
    /// Mean error of a variant's method: across its seeds with the interval's half width when it
    /// ran on several, else its one run's.
    fn error(&self, run: &RunSummary, method: &str) -> (Option<f64>, Option<f64>) {
        let across = (self.across.variants.iter())
            .find(|v| v.side.scenario == run.scenario && v.side.method == method)
            .filter(|v| v.mean_error.n > 1);
        match across {
            Some(v) => (Some(v.mean_error.mean), v.mean_error.half_width),
            None => (
                run.method(method).and_then(|m| m.error).map(|e| e.mean),
                None,
            ),
        }
    }

    fn methods(&self) -> Vec<&str> {
        let mut names: Vec<&str> = Vec::new();
        for m in self.first.iter().flat_map(|s| &s.methods) {
            if !names.contains(&m.method.as_str()) {
                names.push(&m.method);
            }
        }
        names
    }

    /// What the values are: `mean over N seeds` or `seed S`.
    fn seeds_said(&self) -> String {
        let most = (self.across.variants.iter())
            .map(|v| v.mean_error.n)
            .max()
            .unwrap_or(1);
        match self.first.first() {
            _ if most > 1 => format!("mean over up to {most} seeds, 95 % intervals"),
            Some(run) => format!("seed {} only", run.seed),
            None => String::new(),
        }
    }
}

/// Writes the sweep's plots into `out`, file names starting with `prefix` (`sweep`).
pub fn write_sweep_plots(
    out: &Path,
    prefix: &str,
    sweep: &SweepPlots<'_>,
) -> Result<Vec<Written>, ReportError> {
    let mut written = Vec::new();
    if sweep.first.is_empty() {
        return Ok(written);
    }
    let names = sweep.methods();
    let series: Vec<BarSeries> = (names.iter())
        .map(|&name| {
            let (values, half_widths) = sweep.first.iter().map(|s| sweep.error(s, name)).unzip();
            BarSeries {
                name: name.to_string(),
                values,
                half_widths,
            }
        })
        .collect();
    let labels: Vec<String> = sweep.first.iter().map(|s| s.scenario.clone()).collect();
    // The paper's figures are the evidential tracker's.
    let paper: Vec<Option<f64>> = (sweep.first.iter())
        .map(|s| s.paper_error.filter(|_| s.evidential.is_some()))
        .collect();
    let has_paper = paper.iter().any(Option::is_some);
    if series.iter().any(|s| s.values.iter().any(Option::is_some)) {
        let path = out.join(format!("{prefix}-errors.png"));
        let title = format!("mean error per variant and method ({})", sweep.seeds_said());
        plot_errors_by_variant(
            &path,
            &title,
            &labels,
            &series,
            has_paper.then_some(&paper[..]),
        )?;
        written.push(Written {
            path,
            caption: "mean error per variant and method; black ticks: the paper's figures".into(),
        });
    }
    if let Some(lines) = state_lines(sweep, &names) {
        let path = out.join(format!("{prefix}-states.png"));
        let title = format!(
            "mean error against the evidential model's states ({})",
            sweep.seeds_said()
        );
        plot_series(
            &path,
            &title,
            "Σ nᵢ (states over all features)",
            "mean error (mm)",
            &lines,
        )?;
        written.push(Written {
            path,
            caption: "error against the total state count; one line per feature set".into(),
        });
    }
    if let Some((key, lines)) = setting_lines(sweep, &names) {
        let path = out.join(format!("{prefix}-setting.png"));
        let title = format!("mean error against {key} ({})", sweep.seeds_said());
        plot_series(&path, &title, &key, "mean error (mm)", &lines)?;
        written.push(Written {
            path,
            caption: format!("error against the swept setting {key}"),
        });
    }
    Ok(written)
}

/// Error against the evidential model's total state count, one line per method and feature set
/// (variants with other features are other lines, never joined); `None` when no feature set has
/// two distinct totals.
fn state_lines(sweep: &SweepPlots<'_>, names: &[&str]) -> Option<Vec<PlotSeries>> {
    let mut sets: Vec<&Vec<String>> = Vec::new();
    for s in sweep.first {
        if !sets.contains(&&s.features) {
            sets.push(&s.features);
        }
    }
    let mut lines = Vec::new();
    for (k, set) in sets.iter().enumerate() {
        let runs: Vec<(&RunSummary, f64)> = (sweep.first.iter())
            .filter(|s| &&s.features == set)
            .filter_map(|s| {
                Some((
                    *s,
                    s.evidential.as_ref()?.states.iter().sum::<usize>() as f64,
                ))
            })
            .collect();
        let mut totals: Vec<f64> = runs.iter().map(|r| r.1).collect();
        totals.sort_by(f64::total_cmp);
        totals.dedup();
        if totals.len() < 2 {
            continue;
        }
        for &method in names {
            let points: Vec<(f64, f64, Option<f64>)> = (runs.iter())
                .filter_map(|(s, n)| {
                    let (mean, half) = sweep.error(s, method);
                    Some((*n, mean?, half))
                })
                .collect();
            let label = (sets.len() > 1).then(|| format!("features {}", k + 1));
            lines.extend(method_line(method, label, points));
        }
    }
    (!lines.is_empty()).then_some(lines)
}

/// Keys of a scenario that are not settings (names, expectations, the paper's figure).
const NOT_SETTINGS: [&str; 5] = ["name", "description", "seed", "expect", "paper_error"];

/// Every leaf of a scenario's TOML by its dotted path (arrays are leaves).
fn flatten(prefix: &str, value: &toml::Value, into: &mut BTreeMap<String, toml::Value>) {
    match value {
        toml::Value::Table(table) => {
            for (key, value) in table {
                if prefix.is_empty() && NOT_SETTINGS.contains(&key.as_str()) {
                    continue;
                }
                let path = if prefix.is_empty() {
                    key.clone()
                } else {
                    format!("{prefix}.{key}")
                };
                flatten(&path, value, into);
            }
        }
        other => {
            into.insert(prefix.to_string(), other.clone());
        }
    }
}

fn number(value: Option<&toml::Value>) -> Option<f64> {
    match value? {
        toml::Value::Integer(i) => Some(*i as f64),
        toml::Value::Float(f) => Some(*f),
        _ => None,
    }
}

/// The numeric setting that most variants differ in alone (the variants agreeing on every other
/// setting form one line per method), with its lines; `None` when no numeric setting takes two
/// values among variants that agree on everything else.
fn setting_lines(sweep: &SweepPlots<'_>, names: &[&str]) -> Option<(String, Vec<PlotSeries>)> {
    let variants: Vec<(&RunSummary, BTreeMap<String, toml::Value>)> = (sweep.first.iter())
        .filter_map(|s| {
            let (_, text) = sweep.settings.iter().find(|(n, _)| *n == s.scenario)?;
            let mut leaves = BTreeMap::new();
            let table: toml::Table = toml::from_str(text).ok()?;
            flatten("", &toml::Value::Table(table), &mut leaves);
            Some((*s, leaves))
        })
        .collect();
    let keys: std::collections::BTreeSet<&String> =
        variants.iter().flat_map(|v| v.1.keys()).collect();
    let differing: Vec<&String> = (keys.into_iter())
        .filter(|k| {
            variants
                .iter()
                .any(|v| v.1.get(*k) != variants[0].1.get(*k))
        })
        .collect();
    let mut best: Option<(String, Vec<Vec<usize>>, usize)> = None;
    for key in &differing {
        if variants.iter().any(|v| number(v.1.get(*key)).is_none()) {
            continue;
        }
        // Variants grouped by every other differing setting.
        let mut groups: BTreeMap<String, Vec<usize>> = BTreeMap::new();
        for (i, v) in variants.iter().enumerate() {
            let rest: Vec<String> = (differing.iter())
                .filter(|k| *k != key)
                .map(|k| {
                    format!(
                        "{k}={}",
                        v.1.get(*k).map_or(String::new(), |x| x.to_string())
                    )
                })
                .collect();
            groups.entry(rest.join(", ")).or_default().push(i);
        }
        let kept: Vec<Vec<usize>> = (groups.into_values())
            .filter(|g| {
                let mut values: Vec<f64> = g
                    .iter()
                    .filter_map(|&i| number(variants[i].1.get(*key)))
                    .collect();
                values.sort_by(f64::total_cmp);
                values.dedup();
                values.len() >= 2
            })
            .collect();
        let covered: usize = kept.iter().map(Vec::len).sum();
        if covered > 0 && best.as_ref().is_none_or(|b| covered > b.2) {
            best = Some(((*key).clone(), kept, covered));
        }
    }
    let (key, groups, _) = best?;
    let mut lines = Vec::new();
    for (g, members) in groups.iter().enumerate() {
        for &method in names {
            let points: Vec<(f64, f64, Option<f64>)> = (members.iter())
                .filter_map(|&i| {
                    let (run, leaves) = &variants[i];
                    let (mean, half) = sweep.error(run, method);
                    Some((number(leaves.get(&key))?, mean?, half))
                })
                .collect();
            let label = (groups.len() > 1).then(|| format!("set {}", g + 1));
            lines.extend(method_line(method, label, points));
        }
    }
    (!lines.is_empty()).then_some((key, lines))
}

/// One method's line through `points` (x, mean error, interval half-width), sorted by x and
/// labelled `method (label)`; none without points.
fn method_line(
    method: &str,
    label: Option<String>,
    mut points: Vec<(f64, f64, Option<f64>)>,
) -> Option<PlotSeries> {
    if points.is_empty() {
        return None;
    }
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    Some(PlotSeries {
        name: label.map_or_else(|| method.to_string(), |l| format!("{method} ({l})")),
        method: method.to_string(),
        points: points.iter().map(|p| (p.0, p.1)).collect(),
        half_widths: points.iter().map(|p| p.2).collect(),
        colour: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::records::tests::method;
    use crate::report::EvidentialSummary;
    use crate::scenario::Expectations;

    fn run(name: &str, features: &[&str], states: &[usize], error: f64) -> RunSummary {
        RunSummary {
            scenario: name.into(),
            seed: 1,
            samples: 1,
            adaptive_added: 0,
            features: features.iter().map(|f| f.to_string()).collect(),
            frames: 1,
            evidential: Some(EvidentialSummary {
                states: states.to_vec(),
                constructor: "consonant".into(),
                conflict_threshold: crate::evidence::ConflictLevel::from_value(f64::INFINITY),
                threshold_learned: false,
            }),
            methods: vec![
                method("evidential", &[error], 0),
                method("knn", &[error / 2.0], 0),
            ],
            paper_error: None,
            limit: None,
            expect: Expectations::default(),
            calibration_reach: None,
        }
    }

    #[test]
    fn state_lines_never_join_feature_sets() {
        let runs = [
            run("a2", &["f", "g"], &[2, 2], 1.0),
            run("a3", &["f", "g"], &[3, 3], 0.8),
            run("b2", &["f", "h", "k"], &[2, 2, 2], 0.5),
            run("b4", &["f", "h", "k"], &[4, 4, 4], 0.4),
            run("c", &["z"], &[5], 0.3),
        ];
        let first: Vec<&RunSummary> = runs.iter().collect();
        let across = SeedReport::new(&runs, &[]);
        let sweep = SweepPlots {
            first: &first,
            across: &across,
            settings: &[],
        };
        let lines = state_lines(&sweep, &["evidential", "knn"]).unwrap();
        let names: Vec<&str> = lines.iter().map(|l| l.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "evidential (features 1)",
                "knn (features 1)",
                "evidential (features 2)",
                "knn (features 2)"
            ]
        );
        assert_eq!(lines[0].points, [(4.0, 1.0), (6.0, 0.8)]);
        assert_eq!(lines[2].points, [(6.0, 0.5), (12.0, 0.4)]);
    }

    #[test]
    fn the_setting_is_the_numeric_value_variants_differ_in_alone() {
        let runs = [
            run("s0", &["f"], &[2], 1.0),
            run("s5", &["f"], &[2], 1.5),
            run("s9", &["f"], &[2], 2.0),
            run("t0", &["f"], &[2], 3.0),
            run("t5", &["f"], &[2], 3.5),
        ];
        let toml = |name: &str, sigma: f64, states: usize| {
            let text = format!(
                "name = \"{name}\"\n[expect]\nmean_error = {sigma}\n[sim.noise]\nsigma = {sigma}\n\
                 [model]\nstates = [{states}]\n"
            );
            (name.to_string(), text)
        };
        let settings = [
            toml("s0", 0.0, 2),
            toml("s5", 5.0, 2),
            toml("s9", 9.0, 2),
            toml("t0", 0.0, 12),
            toml("t5", 5.0, 12),
        ];
        let first: Vec<&RunSummary> = runs.iter().collect();
        let across = SeedReport::new(&runs, &[]);
        let sweep = SweepPlots {
            first: &first,
            across: &across,
            settings: &settings,
        };
        let (key, lines) = setting_lines(&sweep, &["evidential"]).unwrap();
        assert_eq!(key, "sim.noise.sigma");
        let points: Vec<&[(f64, f64)]> = lines.iter().map(|l| &l.points[..]).collect();
        // One line per states setting (`[12]` sorts before `[2]`).
        assert_eq!(
            points,
            [
                &[(0.0, 3.0), (5.0, 3.5)][..],
                &[(0.0, 1.0), (5.0, 1.5), (9.0, 2.0)][..]
            ]
        );
        // Without the scenarios, or when nothing numeric differs alone, no plot.
        let none = SweepPlots {
            settings: &[],
            ..sweep
        };
        assert!(setting_lines(&none, &["evidential"]).is_none());
    }
}
