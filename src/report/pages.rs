//! The pages of `report.html`: a run's and a sweep's tables, what held, and the plots.

use super::html::Page;
use super::run_plots::Written;
use super::tables::{confidence_table, error_table, fault_table, seed_table_parts};
use super::{Finding, ReportError, RunSummary, SeedReport};

/// The tables of `summaries` (errors with the limit rows, faults, confidence), with a line on
/// how to read each.
fn tables(page: &mut Page, summaries: &[&RunSummary]) {
    page.heading(2, "Errors");
    page.paragraph(
        "Errors in mm over the test frames with an estimate; the row \"limit\" is the information \
         limit's RMS (what an unbiased estimator cannot beat with these features), \"eff.\" each \
         method's RMS error over it.",
    );
    page.table(&error_table(summaries));
    if let Some(faults) = fault_table(summaries) {
        page.heading(2, "Faults");
        page.paragraph(
            "Clean against corrupted frames; AUC: how well the detection score tells them apart.",
        );
        page.table(&faults);
    }
    if let Some(confidence) = confidence_table(summaries) {
        page.heading(2, "Confidence");
        page.paragraph(
            "Whether each method knows when it is wrong: its regions' coverage, its abstentions, \
             and its risk–coverage (AURC beside the oracle's).",
        );
        page.table(&confidence);
    }
}

/// What the run's expectations say, in words.
fn expectations(page: &mut Page, summaries: &[&RunSummary]) {
    page.heading(2, "Expectations");
    let missed: Vec<(String, Option<&str>)> = (summaries.iter())
        .flat_map(|s| s.regressions())
        .map(|m| (format!("missed: {m}"), Some("fails")))
        .collect();
    let any = summaries.iter().any(|s| {
        let top = s.expect.evidential();
        top.any() || !s.expect.methods.is_empty()
    });
    if !missed.is_empty() {
        page.list(&missed);
    } else if any {
        page.list(&[("every expectation holds".into(), Some("holds"))]);
    } else {
        page.paragraph("The scenario states no expectations.");
    }
}

fn figures(page: &mut Page, plots: &[Written]) -> Result<(), ReportError> {
    if !plots.is_empty() {
        page.heading(2, "Plots");
    }
    for plot in plots {
        page.image(&plot.path, &plot.caption)?;
    }
    Ok(())
}

/// The page of one run.
///
/// # Errors
/// [`ReportError::Write`] when a plot cannot be read back.
pub fn run_page(summary: &RunSummary, plots: &[Written]) -> Result<String, ReportError> {
    let mut page = Page::new(&format!(
        "evitrack run {} (seed {})",
        summary.scenario, summary.seed
    ));
    page.paragraph(&format!(
        "{} test frames, {} sample poses ({} added by the adaptive trajectory), {} features: {}. \
         Methods: {}.",
        summary.frames,
        summary.samples,
        summary.adaptive_added,
        summary.features.len(),
        summary.features.join(", "),
        (summary.methods.iter())
            .map(|m| m.method.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    ));
    tables(&mut page, &[summary]);
    expectations(&mut page, &[summary]);
    figures(&mut page, plots)?;
    Ok(page.finish())
}

/// What a sweep's page shows.
#[derive(Debug)]
pub struct SweepPage<'a> {
    /// Each variant's first run (the tables' rows).
    pub first: &'a [&'a RunSummary],
    /// Every run (for the number of seeds).
    pub runs: usize,
    /// The report across seeds.
    pub across: &'a SeedReport,
    /// How many of its findings the scenario file stated (`[[sweep.finding]]`, first).
    pub stated: usize,
    /// Runs without results (a killed sweep, failures).
    pub pending: &'a [String],
}

/// The page of a sweep.
///
/// # Errors
/// [`ReportError::Write`] when a plot cannot be read back.
pub fn sweep_page(sweep: &SweepPage<'_>, plots: &[Written]) -> Result<String, ReportError> {
    let variants = sweep.first.len();
    let mut page = Page::new(&format!(
        "evitrack sweep: {variants} variants, {} runs",
        sweep.runs
    ));
    if !sweep.pending.is_empty() {
        page.paragraph(&format!(
            "Incomplete: {} runs have no results yet ({}).",
            sweep.pending.len(),
            sweep.pending.join(", ")
        ));
    }
    page.heading(2, "Findings");
    let (stated, pairs) = sweep
        .across
        .findings
        .split_at(sweep.stated.min(sweep.across.findings.len()));
    if stated.is_empty() {
        page.paragraph("The scenario file states no finding ([[sweep.finding]]).");
    } else {
        let items: Vec<(String, Option<&str>)> = stated.iter().map(claim).collect();
        page.list(&items);
    }
    if sweep.runs > variants {
        page.heading(2, "Across seeds");
        let (across, findings) = seed_table_parts(sweep.across);
        page.table(&across);
        if !pairs.is_empty() {
            page.paragraph("Every pair of methods within a variant, paired by seed:");
        }
        page.table(&findings);
    } else {
        page.paragraph(
            "One seed per variant: no intervals. Run the sweep with --seeds 10 to know which \
             differences are measurable.",
        );
    }
    page.paragraph("The tables below are each variant's first seed.");
    tables(&mut page, sweep.first);
    expectations(&mut page, sweep.first);
    figures(&mut page, plots)?;
    Ok(page.finish())
}

/// A stated finding in words: its claim (from its name, `b < a`, `c > a`, `d = a`) and whether
/// the paired interval bears it out; the CSS class says so at a glance.
fn claim(finding: &Finding) -> (String, Option<&'static str>) {
    let name = &finding.comparison.name;
    let (left, right) = (&finding.comparison.left, &finding.comparison.right);
    let sides = format!(
        "{} {} − {} {}, {} seeds",
        left.scenario, left.method, right.scenario, right.method, finding.difference.n
    );
    let words = finding.statement();
    let class = match finding.holds() {
        Some(true) => "holds",
        Some(false) => "fails",
        None => "open",
    };
    (format!("{name}: {words} ({sides})"), Some(class))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::{Comparison, Interval, Side, Verdict};

    fn finding(name: &str, mean: f64, half: Option<f64>, verdict: Verdict) -> Finding {
        let side = |s: &str| Side {
            scenario: s.into(),
            method: "evidential".into(),
        };
        Finding {
            comparison: Comparison {
                name: name.into(),
                left: side("p-b"),
                right: side("p-a"),
            },
            difference: Interval {
                mean,
                half_width: half,
                n: 10,
            },
            verdict,
        }
    }

    #[test]
    fn claims_say_whether_they_hold() {
        let said = |f: Finding| claim(&f);
        let holds = said(finding("b < a", -1.0, Some(0.2), Verdict::LeftLower));
        assert!(holds.0.starts_with("b < a: holds"), "{}", holds.0);
        assert_eq!(holds.1, Some("holds"));
        let fails = said(finding("b < a", 1.0, Some(0.2), Verdict::LeftHigher));
        assert!(fails.0.contains("does not hold"), "{}", fails.0);
        let open = said(finding(
            "c > a",
            0.1,
            Some(0.2),
            Verdict::NoMeasurableEffect,
        ));
        assert!(open.0.contains("not shown"), "{}", open.0);
        let equal = said(finding(
            "d = a",
            0.1,
            Some(0.2),
            Verdict::NoMeasurableEffect,
        ));
        assert_eq!(equal.1, Some("holds"));
        let one = said(finding("d = a", 0.1, None, Verdict::TooFewSeeds));
        assert!(one.0.contains("one seed"), "{}", one.0);
    }
}
