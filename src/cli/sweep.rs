//! `sweep`: every variant of scenario files, each run's files written as soon as it finishes, a
//! killed sweep resumed; `merge` (in [`super::merge`]) puts its shards back together.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::Args;

use super::ensure_writable;
use super::producer::Producer;
use super::progress::StageBars;
use super::tables::{evidential_of, print_tables, seed_tables, states_text};
use evitrack::experiment::{self, Workbench};
use evitrack::report::{self, finite, write_run, RunSummary};
use evitrack::report::{Comparison, SeedReport};
use evitrack::scenario::{CheckedScenario, ScenarioSet, SeedList};

fn parse_seeds(text: &str) -> Result<SeedList, String> {
    SeedList::parse(text)
}

/// `--jobs`: at least one thread.
fn parse_jobs(text: &str) -> Result<usize, String> {
    match text.trim().parse::<usize>() {
        Ok(0) => Err("0 jobs would run nothing: give at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(format!("`{text}`: {e}")),
    }
}

/// What `sweep.json` holds: every finished run (in the sweep's order), the comparisons asked
/// for, and the report across seeds. While a sweep runs, and after it was killed or a run failed,
/// `complete` is false and `pending` names the runs without results.
#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct SweepFile {
    #[serde(default = "finished")]
    pub(super) complete: bool,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub(super) pending: Vec<String>,
    /// The slice this file holds, `[i, n]` zero-based, when `--shard` ran: run `k` of shard `i`
    /// is run `k·n + i` of the sweep, which `merge` puts back in order.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) shard: Option<[usize; 2]>,
    /// Which sweep a shard belongs to ([`sweep_identity`]), so that `merge` refuses shards of
    /// different sweeps; only in shard files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) sweep: Option<String>,
    pub(super) runs: Vec<RunSummary>,
    pub(super) comparisons: Vec<Comparison>,
    pub(super) across_seeds: SeedReport,
}

fn finished() -> bool {
    true
}

impl SweepFile {
    pub(super) fn new(
        runs: Vec<RunSummary>,
        pending: Vec<String>,
        comparisons: &[Comparison],
    ) -> Self {
        Self {
            complete: pending.is_empty(),
            across_seeds: SeedReport::new(&runs, comparisons),
            pending,
            shard: None,
            sweep: None,
            runs,
            comparisons: comparisons.to_vec(),
        }
    }

    fn write(&self, path: &Path) -> Result<()> {
        report::check_json_numbers(&path.display().to_string(), self)?;
        let json = serde_json::to_string_pretty(self)? + "\n";
        evitrack::atomic::write(path, json.as_bytes())
            .with_context(|| format!("writing {}", path.display()))
    }
}

/// What a sweep has so far, run by run in the sweep's order.
struct SweepState {
    summaries: Vec<Option<RunSummary>>,
    /// Why a run failed or its files could not be written.
    failures: Vec<Option<String>>,
}

/// What a run's folder holds of an earlier sweep.
enum Earlier {
    /// Nothing finished of this scenario and seed.
    Absent,
    /// Its finished results, written by this program: kept.
    Kept(Box<RunSummary>),
    /// Finished results that another program wrote (why): run again.
    Stale(String),
}

/// Whether `dir` holds the finished results of `run` (`results.json` of its name and seed beside
/// the same `scenario.toml`), and whether `producer` wrote them.
fn earlier_run(dir: &Path, run: &CheckedScenario, producer: &Producer) -> Earlier {
    let finished = || {
        let scenario = std::fs::read_to_string(dir.join(report::SCENARIO_FILE)).ok()?;
        if scenario != run.to_toml().ok()? {
            return None;
        }
        let text = std::fs::read_to_string(dir.join(report::RESULTS_FILE)).ok()?;
        let summary: RunSummary = serde_json::from_str(&text).ok()?;
        (summary.scenario == run.name() && summary.seed == run.seed).then_some(summary)
    };
    let Some(summary) = finished() else {
        return Earlier::Absent;
    };
    let earlier = std::fs::read_to_string(dir.join(report::PRODUCER_FILE))
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok());
    match producer.differs_from(earlier.as_ref()) {
        None => Earlier::Kept(Box::new(summary)),
        Some(why) => Earlier::Stale(why),
    }
}

/// How many runs a sweep has, how many ran now and how many it kept from an earlier sweep.
fn runs_text(total: usize, ran: usize, kept: usize) -> String {
    let runs = |n: usize| format!("{n} run{}", if n == 1 { "" } else { "s" });
    match (ran, kept) {
        (_, 0) => format!("{}, all run now,", runs(total)),
        (0, _) => format!("{}, all kept from the earlier sweep,", runs(total)),
        _ => format!(
            "{} ({ran} run now, {kept} kept from the earlier sweep)",
            runs(total)
        ),
    }
}

#[derive(Debug, Args)]
pub struct SweepArgs {
    /// Scenario files (TOML) whose [sweep] variants to run.
    #[arg(required = true)]
    scenarios: Vec<PathBuf>,
    /// Threads: variants run at once (the longest first); with 2 or more, each run also
    /// simulates its motions side by side, rendering beside the physics (default: the number of
    /// cores). Results are the same whatever the count.
    #[arg(long, value_parser = parse_jobs)]
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
    /// Output folder. Runs whose folder already holds their finished results (same scenario and
    /// seed, written by this very build with the same feature programs) are kept, not run
    /// again: a killed sweep resumes where it stopped, a rebuilt program runs them again.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Also write each run's wall times to `timings.json` (without it, two sweeps of the same
    /// files and seeds write byte-identical folders).
    #[arg(long)]
    timings: bool,
    /// Refuse (exit 2) before running when the estimated peak memory is above this (`4GiB`,
    /// `1500MB`, bytes). Default: 3/4 of the smaller of the machine's memory and `ulimit -v`.
    #[arg(long, value_name = "SIZE", value_parser = super::parse_memory_limit)]
    memory_limit: Option<u64>,
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
    let identity = super::merge::sweep_identity(&runs)?;
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
    let jobs = args.jobs.unwrap_or_else(super::cores);
    ensure_writable(&args.out)?;
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
    let file_name = match shard {
        Some((i, n)) => format!("sweep-shard-{}-of-{n}.json", i + 1),
        None => "sweep.json".to_string(),
    };
    let json_path = args.out.join(&file_name);
    let producers = runs.iter().map(Producer::of).collect::<Result<Vec<_>>>()?;
    let mut stale = Vec::new();
    let summaries: Vec<Option<RunSummary>> = runs
        .iter()
        .zip(&producers)
        .map(
            |(run, producer)| match earlier_run(&folder(run), run, producer) {
                Earlier::Absent => None,
                Earlier::Kept(summary) => Some(*summary),
                Earlier::Stale(why) => {
                    stale.push(why);
                    None
                }
            },
        )
        .collect();
    let todo: Vec<usize> = (0..runs.len())
        .filter(|&k| summaries[k].is_none())
        .collect();
    let kept = runs.len() - todo.len();
    if kept > 0 {
        eprintln!(
            "resuming: {kept} of {} runs finished earlier in {} by this build are kept (remove a \
             run's folder to run it again)",
            runs.len(),
            args.out.display()
        );
    }
    if !stale.is_empty() {
        let count = stale.len();
        stale.sort();
        stale.dedup();
        eprintln!(
            "running again {count} runs finished earlier in {}: {}",
            args.out.display(),
            stale.join("; ")
        );
    }
    // The sweep file says what is finished after every run, so a kill loses nothing finished.
    let sweep_file = |state: &SweepState| {
        let pending = (0..labels.len())
            .filter(|&k| state.summaries[k].is_none() || state.failures[k].is_some())
            .map(|k| labels[k].clone())
            .collect();
        let runs = state.summaries.iter().flatten().cloned().collect();
        let mut file = SweepFile::new(runs, pending, &comparisons);
        file.shard = shard.map(|(i, n)| [i, n]);
        file.sweep = shard.map(|_| identity.clone());
        file
    };
    let state = SweepState {
        failures: vec![None; summaries.len()],
        summaries,
    };
    sweep_file(&state).write(&json_path)?;
    let state = std::sync::Mutex::new(state);
    let todo_runs: Vec<CheckedScenario> = todo.iter().map(|&k| runs[k].clone()).collect();
    super::check_memory(&todo_runs, jobs, args.memory_limit)?;
    let todo_labels: Vec<String> = todo.iter().map(|&k| labels[k].clone()).collect();
    let bench = Workbench::with_threads(jobs);
    let bars = StageBars::new(&todo_labels);
    let clock = std::time::Instant::now();
    experiment::run_each(
        &todo_runs,
        jobs,
        &bench,
        &|i, stage, done, total| bars.update(i, stage, done, total),
        &|i, result| {
            bars.done(i, result.is_err());
            let k = todo[i];
            // A run whose files cannot be written keeps its numbers but stays pending.
            let (summary, failure) = match result {
                Ok(mut output) => {
                    output.producer = Some(producers[k].to_json());
                    let written = write_run(&folder(&runs[k]), &output, args.timings);
                    (Some(output.summary), written.err().map(|e| e.to_string()))
                }
                Err(error) => (None, Some(error.to_string())),
            };
            let mut state = state.lock().unwrap_or_else(|e| e.into_inner());
            state.summaries[k] = summary;
            state.failures[k] = failure.map(|message| format!("{}: {message}", labels[k]));
            if let Err(error) = sweep_file(&state).write(&json_path) {
                state.failures[k].get_or_insert(format!("{error:#}"));
            }
        },
    );
    bars.finish();
    let elapsed = clock.elapsed().as_secs_f64();
    let state = state.into_inner().unwrap_or_else(|e| e.into_inner());
    let file = sweep_file(&state);
    let mut failures: Vec<String> = state.failures.into_iter().flatten().collect();
    let settings = (variants.iter())
        .map(|v| Ok((v.name().to_string(), v.to_toml()?)))
        .collect::<Result<Vec<_>>>()?;
    if let Err(error) = write_sweep_report(&args.out, &file_name, &file, &settings) {
        failures.push(format!("{error:#}"));
    }
    eprintln!(
        "{} in {elapsed:.1} s on {jobs} jobs; per-run outputs in {}/<variant>/{}",
        runs_text(labels.len(), todo.len(), kept),
        args.out.display(),
        if seeded { "seed-<seed>/" } else { "" }
    );
    let checked: Vec<RunSummary> = file
        .runs
        .into_iter()
        .filter(|s| own.contains(&(s.scenario.clone(), s.seed)))
        .collect();
    finish_sweep(&checked, &failures, args.check)
}

/// Prints the table, writes JSON, CSV, plots and `report.html` of a set of run summaries;
/// `settings` are the variants' scenarios as TOML by name (for the plot against a setting).
pub(super) fn write_sweep_report(
    out: &Path,
    json_name: &str,
    file: &SweepFile,
    settings: &[(String, String)],
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let all_runs = file.runs.as_slice();
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
        println!("{}", seed_tables(&file.across_seeds));
    }
    file.write(&out.join(json_name))?;
    let csv_path = out.join(json_name.replace(".json", ".csv"));
    let mut csv = csv::Writer::from_writer(Vec::new());
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
        "coverage_clean",
        "coverage_corrupted",
        "abstained_clean",
        "abstained_corrupted",
        "aurc",
        "oracle_aurc",
        "error_at_80",
        "error_at_95",
        "aurc_clean",
        "aurc_corrupted",
        "limit_rms",
        "efficiency",
        "calibration_far_frames",
        "coverage_clean_near",
        "coverage_clean_far",
        "abstained_clean_near",
        "abstained_clean_far",
    ])?;
    for s in all_runs {
        for m in &s.methods {
            let what = format!("sweep.csv, {} seed {} {}", s.scenario, s.seed, m.method);
            let num = |v: Option<f64>| finite::cell(&what, v);
            let evidential = evidential_of(s, m);
            let states = states_text(evidential, " ");
            let f = m.faults.as_ref();
            let c = m.confidence.as_ref();
            let reach = s.calibration_reach.as_ref();
            let method_reach = reach.and_then(|r| r.methods.iter().find(|r| r.method == m.method));
            let (coverage_near, coverage_far) = method_reach.map_or((None, None), |m| m.coverage());
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
                match evidential {
                    Some(e) => finite::level(&what, e.conflict_threshold.value())?,
                    None => String::new(),
                },
                num(m.error.map(|e| e.mean))?,
                num(m.error.map(|e| e.median))?,
                num(m.error.map(|e| e.rms))?,
                num(m.error.map(|e| e.max))?,
                num(s.paper_error.filter(|_| evidential.is_some()))?,
                s.frames.to_string(),
                m.frames_without_estimate.to_string(),
                m.frames_with_missing_features.to_string(),
                m.frames_with_features_left_out.to_string(),
                m.frames_fallback.to_string(),
                num(expected)?,
                f.map_or(String::new(), |f| f.corrupted_frames.to_string()),
                num(f.and_then(|f| f.error_clean).map(|e| e.mean))?,
                num(f.and_then(|f| f.error_corrupted).map(|e| e.mean))?,
                f.map_or(String::new(), |f| f.corrupted_without_estimate.to_string()),
                num(f.and_then(|f| f.detection_auc))?,
                num(f.and_then(|f| f.left_out_precision))?,
                num(f.and_then(|f| f.left_out_recall))?,
                num(m.region.as_ref().map(|r| r.coverage))?,
                num(m.region.as_ref().map(|r| r.mean_area))?,
                num(c.and_then(|c| c.coverage_clean))?,
                num(c.and_then(|c| c.coverage_corrupted))?,
                c.map_or(String::new(), |c| c.abstained_clean.to_string()),
                c.map_or(String::new(), |c| c.abstained_corrupted.to_string()),
                num(c.map(|c| c.all.aurc))?,
                num(c.map(|c| c.all.oracle_aurc))?,
                num(c.map(|c| c.all.error_at_80))?,
                num(c.map(|c| c.all.error_at_95))?,
                num(c.and_then(|c| c.clean.as_ref()).map(|r| r.aurc))?,
                num(c.and_then(|c| c.corrupted.as_ref()).map(|r| r.aurc))?,
                num(s.limit.as_ref().and_then(|l| l.rms))?,
                num(m.efficiency)?,
                reach.map_or(String::new(), |r| r.far_frames.to_string()),
                num(coverage_near)?,
                num(coverage_far)?,
                method_reach.map_or(String::new(), |m| m.abstained_near.to_string()),
                method_reach.map_or(String::new(), |m| m.abstained_far.to_string()),
            ])?;
        }
    }
    let bytes = csv.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
    evitrack::atomic::write(&csv_path, &bytes)
        .with_context(|| format!("writing {}", csv_path.display()))?;
    let prefix = json_name.trim_end_matches(".json");
    let plots = report::write_sweep_plots(
        out,
        prefix,
        &report::SweepPlots {
            first: &first,
            across: &file.across_seeds,
            settings,
        },
    )?;
    let page = report::sweep_page(
        &report::SweepPage {
            first: &first,
            runs: all_runs.len(),
            across: &file.across_seeds,
            stated: file.comparisons.len(),
            pending: &file.pending,
        },
        &plots,
    )?;
    // `report.html` beside `sweep.json`; a shard's page is named after its file.
    let html = match prefix {
        "sweep" => out.join(report::REPORT_FILE),
        shard => out.join(format!("{shard}-report.html")),
    };
    evitrack::atomic::write(&html, page.as_bytes())
        .with_context(|| format!("writing {}", html.display()))?;
    Ok(())
}

/// Reports failures and regressions. Exit status 2 when a variant failed to run or write, else
/// 1 when `check` finds a regression, else 0.
pub(super) fn finish_sweep(
    summaries: &[RunSummary],
    failures: &[String],
    check: bool,
) -> Result<ExitCode> {
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
