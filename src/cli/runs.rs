//! Commands that run scenarios: `run`, `sweep`, `merge`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};

use super::{fmt_mm, load_scenarios};
use evitrack::experiment::{self, Workbench};
use evitrack::report::{self, write_run, EvidentialSummary, MethodSummary, RunSummary, Table};
use evitrack::report::{Comparison, SeedReport};
use evitrack::scenario::{CheckedScenario, ScenarioSet, SeedList};

fn parse_seeds(text: &str) -> Result<SeedList, String> {
    SeedList::parse(text)
}

/// What `sweep.json` holds: every run, the comparisons asked for, and the report across seeds.
#[derive(serde::Serialize, serde::Deserialize)]
struct SweepFile {
    runs: Vec<RunSummary>,
    comparisons: Vec<Comparison>,
    across_seeds: SeedReport,
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Scenario file (TOML); default: the built-in paper setup (a). A file with a [sweep]
    /// section runs its base scenario only (use `sweep` for the variants).
    scenario: Option<PathBuf>,
    /// Output folder; results go to <OUT>/<scenario name>/.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Override the scenario's master seed.
    #[arg(long)]
    seed: Option<u64>,
}

#[derive(Debug, Args)]
pub struct SweepArgs {
    /// Scenario files (TOML) whose [sweep] variants to run.
    #[arg(required = true)]
    scenarios: Vec<PathBuf>,
    /// Variants run at once (default: the number of cores).
    #[arg(long)]
    jobs: Option<usize>,
    /// Compare against each variant's expectations (on its own seed); exit 1 with a list of what
    /// regressed.
    #[arg(long)]
    check: bool,
    /// Master seeds for every variant: a count (`10`: each variant's own seed and the next 9) or
    /// a list (`1,4,7`). Prints each variant's mean ± 95 % interval across them and each
    /// comparison as a paired difference. Default: the file's `[sweep] seeds`, else each
    /// variant's own seed.
    #[arg(long, value_parser = parse_seeds)]
    seeds: Option<SeedList>,
    /// Run only slice i of n (1-based, e.g. `2/4`) of the variants, for batch schedulers; merge
    /// the shards' JSON files with `evitrack merge`.
    #[arg(long)]
    shard: Option<String>,
    /// Output folder.
    #[arg(long, default_value = "out")]
    out: PathBuf,
}

#[derive(Debug, Args)]
pub struct MergeArgs {
    /// Shard result files (`sweep-shard-*.json`) written by `sweep --shard`.
    #[arg(required = true)]
    shards: Vec<PathBuf>,
    /// Output folder for the merged table, CSV, JSON and plots.
    #[arg(long)]
    out: PathBuf,
    /// Compare against the expectations; exit 1 with a list of what regressed.
    #[arg(long)]
    check: bool,
}

/// The run's evidential model, on the evidential method's row only.
fn evidential_of<'a>(s: &'a RunSummary, m: &MethodSummary) -> Option<&'a EvidentialSummary> {
    s.evidential.as_ref().filter(|_| m.method == "evidential")
}

/// The evidential model's state counts joined by `sep` (empty on other rows).
fn states_text(evidential: Option<&EvidentialSummary>, sep: &str) -> String {
    evidential.map_or(String::new(), |e| {
        let states: Vec<String> = e.states.iter().map(usize::to_string).collect();
        states.join(sep)
    })
}

/// One row per variant and method: the evidential model's states and constructor, then each
/// method's errors (the paper's figure beside the evidential row).
fn error_table(summaries: &[&RunSummary]) -> Table {
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
            ]);
        }
    }
    table
}

/// With faults: each method's error on clean and on corrupted frames, how well its detection
/// score tells them apart, and how many of the features it left out were the corrupted ones.
/// `None` when no run had faults.
fn fault_table(summaries: &[&RunSummary]) -> Option<Table> {
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

/// For methods with plausibility regions: on the clean frames, the share of regions holding the
/// true pose and their size. `None` when no method gave regions.
fn region_table(summaries: &[&RunSummary]) -> Option<Table> {
    let mut table = Table::new([
        "scenario",
        "method",
        "clean frames",
        "no region",
        "coverage",
        "mean area (mm²)",
        "median area (mm²)",
    ]);
    let mut any = false;
    for s in summaries {
        for m in &s.methods {
            let Some(r) = &m.region else { continue };
            any = true;
            table.push([
                s.scenario.clone(),
                m.method.clone(),
                r.frames.to_string(),
                r.frames_without_region.to_string(),
                format!("{:.3}", r.coverage),
                format!("{:.5}", r.mean_area),
                format!("{:.5}", r.median_area),
            ]);
        }
    }
    any.then_some(table)
}

/// Prints the error table, the fault table when runs had faults, and the region table when a
/// method gave plausibility regions.
fn print_tables(summaries: &[&RunSummary]) {
    println!("{}", error_table(summaries));
    if let Some(faults) = fault_table(summaries) {
        println!("{faults}");
    }
    if let Some(regions) = region_table(summaries) {
        println!("{regions}");
    }
}

/// Progress bars for the stages of runs, one line per variant.
struct StageBars {
    multi: MultiProgress,
    bars: Vec<ProgressBar>,
}

impl StageBars {
    fn new(names: &[String]) -> Self {
        let multi = MultiProgress::new();
        let style = ProgressStyle::with_template("{prefix:>24} {msg:>14} [{bar:30}] {pos}/{len}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> ");
        let bars = names
            .iter()
            .map(|name| {
                let bar = multi.add(ProgressBar::new(0));
                bar.set_style(style.clone());
                bar.set_prefix(name.clone());
                bar
            })
            .collect();
        Self { multi, bars }
    }

    fn update(&self, variant: usize, stage: &str, done: usize, total: usize) {
        if let Some(bar) = self.bars.get(variant) {
            if bar.message() != stage {
                bar.set_message(stage.to_string());
            }
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
    }

    fn finish(&self) {
        for bar in &self.bars {
            bar.finish_and_clear();
        }
        let _ = self.multi.clear();
    }
}

pub fn run(args: &RunArgs) -> Result<ExitCode> {
    let set = load_scenarios(args.scenario.as_deref())?;
    let scenario = match args.seed {
        Some(seed) => set.base.with_seed(seed)?,
        None => set.base,
    };
    let bench = Workbench::new();
    let bars = StageBars::new(&[scenario.name().to_string()]);
    let output = experiment::run(&scenario, &bench, &mut |stage, done, total| {
        bars.update(0, stage, done, total)
    });
    bars.finish();
    let output = output.with_context(|| format!("running scenario `{}`", scenario.name()))?;
    let dir = args.out.join(scenario.name());
    let written = write_run(&dir, &output)?;
    print_tables(&[&output.summary]);
    for m in &output.summary.methods {
        if m.per_motion.len() > 1 {
            for (label, stats) in &m.per_motion {
                println!(
                    "  {} {label}: mean {}",
                    m.method,
                    fmt_mm(stats.map(|s| s.mean))
                );
            }
        }
    }
    eprintln!(
        "errors in mm; wrote {} files to {}",
        written.len(),
        dir.display()
    );
    let missed = output.summary.regressions();
    for line in &missed {
        eprintln!("regression: {line}");
    }
    Ok(if missed.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

/// Parses `i/n` (1-based) into a zero-based slice index and the slice count.
fn parse_shard(text: &str) -> Result<(usize, usize)> {
    let parsed = text.split_once('/').and_then(|(i, n)| {
        Some((
            i.trim().parse::<usize>().ok()?,
            n.trim().parse::<usize>().ok()?,
        ))
    });
    match parsed {
        Some((i, n)) if n >= 1 && (1..=n).contains(&i) => Ok((i - 1, n)),
        _ => bail!("--shard `{text}` must look like `i/n` with 1 ≤ i ≤ n, e.g. `2/4`"),
    }
}

pub fn sweep(args: &SweepArgs) -> Result<ExitCode> {
    let mut variants: Vec<CheckedScenario> = Vec::new();
    let mut runs = Vec::new();
    let mut comparisons = Vec::new();
    for path in &args.scenarios {
        let set = ScenarioSet::load(path)?;
        runs.extend(set.seeded(args.seeds.as_ref())?);
        comparisons.extend(set.comparisons.iter().cloned());
        variants.extend(set.variants);
    }
    let names: std::collections::HashSet<&str> = variants.iter().map(|v| v.name()).collect();
    if names.len() != variants.len() {
        bail!("two variants of these scenario files have the same name: rename one scenario");
    }
    // Expectations hold for each variant's own seed.
    let own: std::collections::HashSet<(String, u64)> = variants
        .iter()
        .map(|v| (v.name().to_string(), v.seed))
        .collect();
    let seeded = runs.len() > variants.len();
    let total = runs.len();
    let shard = args.shard.as_deref().map(parse_shard).transpose()?;
    if let Some((i, n)) = shard {
        runs = runs
            .into_iter()
            .enumerate()
            .filter(|(k, _)| k % n == i)
            .map(|(_, v)| v)
            .collect();
        eprintln!("shard {}/{n}: {} of {total} runs", i + 1, runs.len());
    }
    let jobs = args.jobs.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let bench = Workbench::new();
    let folder = |run: &CheckedScenario| {
        let dir = args.out.join(run.name());
        if seeded {
            dir.join(format!("seed-{}", run.seed))
        } else {
            dir
        }
    };
    let labels: Vec<String> = runs
        .iter()
        .map(|v| match seeded {
            true => format!("{} seed {}", v.name(), v.seed),
            false => v.name().to_string(),
        })
        .collect();
    let bars = StageBars::new(&labels);
    let clock = std::time::Instant::now();
    let outputs = experiment::run_all(&runs, jobs, &bench, &|i, stage, done, total| {
        bars.update(i, stage, done, total)
    });
    bars.finish();
    let elapsed = clock.elapsed().as_secs_f64();
    let mut summaries = Vec::new();
    let mut failures = Vec::new();
    for ((run, output), label) in runs.iter().zip(outputs).zip(&labels) {
        match output {
            Ok(output) => {
                // A run whose files cannot be written is reported, not the whole sweep lost.
                if let Err(error) = write_run(&folder(run), &output) {
                    failures.push(format!("{label}: {error}"));
                }
                summaries.push(output.summary);
            }
            Err(error) => failures.push(format!("{label}: {error}")),
        }
    }
    let file_name = match shard {
        Some((i, n)) => format!("sweep-shard-{}-of-{n}.json", i + 1),
        None => "sweep.json".to_string(),
    };
    write_sweep_report(&args.out, &file_name, &summaries, &comparisons)?;
    eprintln!(
        "{} runs in {elapsed:.1} s on {jobs} jobs; per-run outputs in {}/<variant>/{}",
        summaries.len(),
        args.out.display(),
        if seeded { "seed-<seed>/" } else { "" }
    );
    let checked: Vec<RunSummary> = summaries
        .into_iter()
        .filter(|s| own.contains(&(s.scenario.clone(), s.seed)))
        .collect();
    finish_sweep(&checked, &failures, args.check)
}

/// Prints the table, writes JSON, CSV and plots of a set of run summaries.
fn write_sweep_report(
    out: &Path,
    json_name: &str,
    all_runs: &[RunSummary],
    comparisons: &[Comparison],
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let across_seeds = SeedReport::new(all_runs, comparisons);
    // Tables and plots show each variant's first run; with several seeds per variant, the
    // tables across seeds follow.
    let mut first: Vec<&RunSummary> = Vec::new();
    for run in all_runs {
        if !first.iter().any(|f| f.scenario == run.scenario) {
            first.push(run);
        }
    }
    print_tables(&first);
    if first.len() < all_runs.len() {
        println!("{}", seed_tables(&across_seeds));
    }
    let summaries: Vec<RunSummary> = first.iter().map(|&s| s.clone()).collect();
    let summaries = summaries.as_slice();
    let json_path = out.join(json_name);
    let file = SweepFile {
        runs: all_runs.to_vec(),
        comparisons: comparisons.to_vec(),
        across_seeds,
    };
    std::fs::write(&json_path, serde_json::to_string_pretty(&file)? + "\n")
        .with_context(|| format!("writing {}", json_path.display()))?;
    let csv_path = out.join(json_name.replace(".json", ".csv"));
    let mut csv = csv::Writer::from_path(&csv_path)
        .with_context(|| format!("writing {}", csv_path.display()))?;
    csv.write_record([
        "scenario",
        "seed",
        "method",
        "samples",
        "states",
        "constructor",
        "threshold",
        "mean",
        "median",
        "rms",
        "max",
        "paper",
        "frames",
        "without_estimate",
        "with_missing_features",
        "with_features_left_out",
        "fallback",
        "fit_seconds",
        "expected_max_mean",
        "corrupted_frames",
        "mean_clean",
        "mean_corrupted",
        "corrupted_without_estimate",
        "detection_auc",
        "left_out_precision",
        "left_out_recall",
        "region_coverage",
        "region_mean_area",
    ])?;
    let num = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
    for s in all_runs {
        for m in &s.methods {
            let evidential = evidential_of(s, m);
            let states = states_text(evidential, " ");
            let f = m.faults.as_ref();
            let expected = match evidential {
                Some(_) => s.expect.max_mean_error,
                None => s
                    .expect
                    .methods
                    .get(&m.method)
                    .and_then(|e| e.max_mean_error),
            };
            csv.write_record([
                s.scenario.clone(),
                s.seed.to_string(),
                m.method.clone(),
                s.samples.to_string(),
                states,
                evidential.map_or(String::new(), |e| e.constructor.clone()),
                evidential.map_or(String::new(), |e| e.conflict_threshold.value().to_string()),
                num(m.error.map(|e| e.mean)),
                num(m.error.map(|e| e.median)),
                num(m.error.map(|e| e.rms)),
                num(m.error.map(|e| e.max)),
                num(s.paper_error.filter(|_| evidential.is_some())),
                s.frames.to_string(),
                m.frames_without_estimate.to_string(),
                m.frames_with_missing_features.to_string(),
                m.frames_with_features_left_out.to_string(),
                m.frames_fallback.to_string(),
                m.fit_seconds.to_string(),
                num(expected),
                f.map_or(String::new(), |f| f.corrupted_frames.to_string()),
                num(f.and_then(|f| f.error_clean).map(|e| e.mean)),
                num(f.and_then(|f| f.error_corrupted).map(|e| e.mean)),
                f.map_or(String::new(), |f| f.corrupted_without_estimate.to_string()),
                num(f.and_then(|f| f.detection_auc)),
                num(f.and_then(|f| f.left_out_precision)),
                num(f.and_then(|f| f.left_out_recall)),
                num(m.region.as_ref().map(|r| r.coverage)),
                num(m.region.as_ref().map(|r| r.mean_area)),
            ])?;
        }
    }
    csv.flush()?;
    if summaries.is_empty() {
        return Ok(());
    }
    // One series per method, in the order the methods first appear.
    let mut names: Vec<&str> = Vec::new();
    for m in summaries.iter().flat_map(|s| &s.methods) {
        if !names.contains(&m.method.as_str()) {
            names.push(&m.method);
        }
    }
    let mean_of = |s: &RunSummary, name: &str| s.method(name).and_then(|m| m.error).map(|e| e.mean);
    let series: Vec<report::BarSeries> = names
        .iter()
        .map(|&name| report::BarSeries {
            name: name.to_string(),
            values: summaries.iter().map(|s| mean_of(s, name)).collect(),
        })
        .collect();
    let labels: Vec<String> = summaries.iter().map(|s| s.scenario.clone()).collect();
    // The paper's figures are the evidential tracker's.
    let paper: Vec<Option<f64>> = summaries
        .iter()
        .map(|s| s.paper_error.filter(|_| s.evidential.is_some()))
        .collect();
    let has_paper = paper.iter().any(Option::is_some);
    let any_error = series.iter().any(|s| s.values.iter().any(Option::is_some));
    if any_error {
        report::plot_errors_by_variant(
            &out.join(json_name.replace(".json", "-errors.png")),
            "mean estimation error per variant and method",
            &labels,
            &series,
            has_paper.then_some(paper.as_slice()),
        )?;
    }
    // Where the variants differ in their evidential state counts, error against the total count.
    let totals: Vec<Option<usize>> = summaries
        .iter()
        .map(|s| s.evidential.as_ref().map(|e| e.states.iter().sum()))
        .collect();
    let distinct: std::collections::HashSet<_> = totals.iter().flatten().collect();
    if distinct.len() > 1 {
        let lines: Vec<report::PlotSeries> = series
            .iter()
            .map(|line| {
                let mut points: Vec<(f64, f64)> = totals
                    .iter()
                    .zip(&line.values)
                    .filter_map(|(n, e)| Some((n.as_ref().copied()? as f64, (*e)?)))
                    .collect();
                points.sort_by(|a, b| a.0.total_cmp(&b.0));
                report::PlotSeries {
                    name: line.name.clone(),
                    points,
                }
            })
            .filter(|line| !line.points.is_empty())
            .collect();
        report::plot_series(
            &out.join(json_name.replace(".json", "-states.png")),
            "mean error against the evidential model's total number of states",
            "Σ nᵢ (states over all features)",
            "mean error (mm)",
            &lines,
        )?;
    }
    Ok(())
}

/// Reports failures and regressions. Exit status 2 when a variant failed to run or write, else
/// 1 when `check` finds a regression, else 0.
fn finish_sweep(summaries: &[RunSummary], failures: &[String], check: bool) -> Result<ExitCode> {
    for failure in failures {
        eprintln!("failed: {failure}");
    }
    if check {
        let regressions: Vec<String> = summaries.iter().flat_map(RunSummary::regressions).collect();
        if regressions.is_empty() {
            eprintln!(
                "check: all {} variants meet their expectations",
                summaries.len()
            );
        } else {
            eprintln!("check: {} regressions", regressions.len());
            for line in &regressions {
                eprintln!("  - {line}");
            }
        }
        if failures.is_empty() && !regressions.is_empty() {
            return Ok(ExitCode::from(1));
        }
    }
    Ok(if failures.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(2)
    })
}

pub fn merge(args: &MergeArgs) -> Result<ExitCode> {
    let mut summaries: Vec<RunSummary> = Vec::new();
    let mut comparisons: Vec<Comparison> = Vec::new();
    for path in &args.shards {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let shard: SweepFile = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a sweep result file", path.display()))?;
        summaries.extend(shard.runs);
        for c in shard.comparisons {
            if !comparisons.contains(&c) {
                comparisons.push(c);
            }
        }
    }
    let mut seen = std::collections::HashSet::new();
    if let Some(dup) = summaries
        .iter()
        .find(|s| !seen.insert((s.scenario.clone(), s.seed)))
    {
        bail!(
            "variant `{}` with seed {} appears in two shard files: merge each shard once",
            dup.scenario,
            dup.seed
        );
    }
    write_sweep_report(&args.out, "sweep.json", &summaries, &comparisons)?;
    finish_sweep(&summaries, &[], args.check)
}

/// Each variant's mean error across seeds, then each comparison's paired difference.
fn seed_tables(report: &SeedReport) -> String {
    let mut variants = Table::new(["scenario", "method", "seeds", "mean error ± 95 % (mm)"]);
    for v in &report.variants {
        variants.push([
            v.side.scenario.clone(),
            v.side.method.clone(),
            v.seeds.len().to_string(),
            v.mean_error.text(4),
        ]);
    }
    let mut findings = Table::new([
        "finding",
        "left",
        "right",
        "seeds",
        "left − right ± 95 % (mm)",
        "verdict",
    ]);
    for f in &report.findings {
        let side = |s: &evitrack::report::Side| format!("{} {}", s.scenario, s.method);
        findings.push([
            f.comparison.name.clone(),
            side(&f.comparison.left),
            side(&f.comparison.right),
            f.difference.n.to_string(),
            f.difference.text(4),
            f.verdict.text().to_string(),
        ]);
    }
    format!("{variants}\n{findings}")
}
