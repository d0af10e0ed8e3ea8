//! The tables of runs and sweeps (printed by the command line, and in `report.html`): errors per
//! variant and method, faults, plausibility regions, and the report across seeds.

use super::{EvidentialSummary, Interval, MethodSummary, RunSummary, SeedReport, Side, Table};

/// A length in mm with four decimals, or a dash.
pub fn fmt_mm(value: Option<f64>) -> String {
    value
        .map(|v| format!("{v:.4}"))
        .unwrap_or_else(|| "—".into())
}

/// The run's evidential model, on the evidential method's row only.
pub fn evidential_of<'a>(s: &'a RunSummary, m: &MethodSummary) -> Option<&'a EvidentialSummary> {
    s.evidential.as_ref().filter(|_| m.method == "evidential")
}

/// The evidential model's state counts joined by `sep` (empty on other rows).
pub fn states_text(evidential: Option<&EvidentialSummary>, sep: &str) -> String {
    evidential.map_or(String::new(), |e| {
        let states: Vec<String> = e.states.iter().map(usize::to_string).collect();
        states.join(sep)
    })
}

/// One row per variant and method: the evidential model's states and constructor, then each
/// method's errors (the paper's figure beside the evidential row) and its efficiency (RMS error
/// over the limit's on the clean frames); then the variant's `limit` row, the information
/// limit's RMS (what an unbiased estimator cannot beat with these features).
pub fn error_table(summaries: &[&RunSummary]) -> Table {
    let mut table = Table::new([
        "scenario",
        "method",
        "samples",
        "states",
        "constructor",
        "mean",
        "median",
        "RMS",
        "max",
        "paper",
        "no est.",
        "left out",
        "fallback",
        "eff.",
    ]);
    for s in summaries {
        for m in &s.methods {
            let evidential = evidential_of(s, m);
            let states = states_text(evidential, ",");
            table.push([
                s.scenario.clone(),
                m.method.clone(),
                s.samples.to_string(),
                states,
                evidential.map_or(String::new(), |e| e.constructor.clone()),
                fmt_mm(m.error.map(|e| e.mean)),
                fmt_mm(m.error.map(|e| e.median)),
                fmt_mm(m.error.map(|e| e.rms)),
                fmt_mm(m.error.map(|e| e.max)),
                fmt_mm(s.paper_error.filter(|_| evidential.is_some())),
                format!("{}/{}", m.frames_without_estimate, s.frames),
                m.frames_with_features_left_out.to_string(),
                m.frames_fallback.to_string(),
                m.efficiency.map_or("—".to_string(), |e| format!("{e:.2}")),
            ]);
        }
        if let Some(limit) = &s.limit {
            let mut row = vec![String::new(); 14];
            row[0] = s.scenario.clone();
            row[1] = "limit".into();
            row[2] = s.samples.to_string();
            row[7] = fmt_mm(limit.rms);
            row[10] = format!(
                "{}/{}",
                limit.frames_without,
                limit.frames + limit.frames_without
            );
            table.push(row);
        }
    }
    table
}

/// With faults: each method's error on clean and on corrupted frames, how well its detection
/// score tells them apart, and how many of the features it left out were the corrupted ones.
/// `None` when no run had faults.
pub fn fault_table(summaries: &[&RunSummary]) -> Option<Table> {
    let mut table = Table::new([
        "scenario",
        "method",
        "corrupted",
        "clean mean",
        "corr. mean",
        "ratio",
        "corr. no est.",
        "AUC",
        "left-out prec.",
        "recall",
    ]);
    let share = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.3}"));
    let mut any = false;
    for s in summaries {
        for m in &s.methods {
            let Some(f) = &m.faults else { continue };
            any = true;
            let clean = f.error_clean.map(|e| e.mean);
            let corrupted = f.error_corrupted.map(|e| e.mean);
            table.push([
                s.scenario.clone(),
                m.method.clone(),
                format!(
                    "{}/{}",
                    f.corrupted_frames,
                    f.corrupted_frames + f.clean_frames
                ),
                fmt_mm(clean),
                fmt_mm(corrupted),
                share(clean.zip(corrupted).map(|(a, b)| b / a)),
                f.corrupted_without_estimate.to_string(),
                share(f.detection_auc),
                share(f.left_out_precision),
                share(f.left_out_recall),
            ]);
        }
    }
    any.then_some(table)
}

/// Whether each method knows when it is wrong: its calibrated regions' coverage and its
/// abstentions on clean and corrupted frames, the median area of the regions it answered with,
/// and its risk–coverage (AURC beside the oracle's, the mean error of its surest 80 % and 95 %).
/// `None` when no method estimated anything.
pub fn confidence_table(summaries: &[&RunSummary]) -> Option<Table> {
    let mut table = Table::new([
        "scenario",
        "method",
        "coverage",
        "corr. cov.",
        "abstained",
        "corr. abst.",
        "median area",
        "AURC",
        "oracle",
        "err@80%",
        "err@95%",
    ]);
    let share = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.3}"));
    let mut any = false;
    for s in summaries {
        for m in &s.methods {
            let Some(c) = &m.confidence else { continue };
            any = true;
            let corrupted = m.faults.as_ref().map_or(0, |f| f.corrupted_frames);
            let clean = (c.clean_frames).unwrap_or(s.frames - corrupted);
            table.push([
                s.scenario.clone(),
                m.method.clone(),
                share(c.coverage_clean),
                share(c.coverage_corrupted),
                format!("{}/{clean}", c.abstained_clean),
                if corrupted > 0 {
                    format!("{}/{corrupted}", c.abstained_corrupted)
                } else {
                    "—".to_string()
                },
                c.median_area_answered
                    .map_or("—".to_string(), |a| format!("{a:.4}")),
                fmt_mm(Some(c.all.aurc)),
                fmt_mm(Some(c.all.oracle_aurc)),
                fmt_mm(Some(c.all.error_at_80)),
                fmt_mm(Some(c.all.error_at_95)),
            ]);
        }
    }
    any.then_some(table)
}

/// Each variant's mean error across seeds, then each comparison's paired difference.
pub fn seed_tables(report: &SeedReport) -> String {
    let (variants, findings) = seed_table_parts(report);
    format!("{variants}\n{findings}")
}

/// The two tables of [`seed_tables`]: variants across seeds, findings.
pub fn seed_table_parts(report: &SeedReport) -> (Table, Table) {
    let mut variants = Table::new([
        "scenario",
        "method",
        "seeds",
        "mean error ± 95 % (mm)",
        "AURC (mm)",
        "coverage",
        "corr. coverage",
        "abstained",
    ]);
    let text =
        |i: &Option<Interval>, digits| i.as_ref().map_or("—".to_string(), |i| i.text(digits));
    for v in &report.variants {
        variants.push([
            v.side.scenario.clone(),
            v.side.method.clone(),
            v.seeds.len().to_string(),
            v.mean_error.text(4),
            text(&v.aurc, 4),
            text(&v.coverage_clean, 3),
            text(&v.coverage_corrupted, 3),
            text(&v.abstained_clean, 3),
        ]);
    }
    let mut findings = Table::new([
        "finding",
        "left",
        "right",
        "seeds",
        "left − right ± 95 % (mm)",
        "claim",
    ]);
    for f in &report.findings {
        let side = |s: &Side| format!("{} {}", s.scenario, s.method);
        findings.push([
            f.comparison.name.clone(),
            side(&f.comparison.left),
            side(&f.comparison.right),
            f.difference.n.to_string(),
            f.difference.text(4),
            f.statement(),
        ]);
    }
    (variants, findings)
}
