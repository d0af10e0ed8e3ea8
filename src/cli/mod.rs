//! The `evitrack` command line: one room per command group, shared helpers here.

mod data;
mod dataset_cmd;
mod feature_report;
mod merge;
mod model;
mod producer;
mod programs;
mod progress;
mod render_check;
mod runs;
mod scenario_cmd;
mod sweep;
mod tables;
mod train_settings;

use std::path::Path;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use evitrack::dataset::Dataset;
use evitrack::features::{FeatureConfig, FeatureRows, FeatureSet, Polarity};
use evitrack::scenario::ScenarioSet;

/// Evidential (Dempster–Shafer) pose tracking on a simulated five-bar robot.
#[derive(Debug, Parser)]
#[command(name = "evitrack", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a scenario end to end: simulate, train, track, report. Without a file it runs the
    /// built-in default, the paper's dense Bayesian setup (Figure 2a).
    Run(runs::RunArgs),
    /// Run every variant of one or more scenario files (in parallel), print one table, write
    /// CSV/JSON and plots; `--check` fails when a variant misses its expectations.
    Sweep(sweep::SweepArgs),
    /// Merge the JSON results of sweep shards (`sweep --shard i/n`) into one table and report.
    Merge(merge::MergeArgs),
    /// Combine belief functions given as JSON and print the result as JSON on stdout.
    ///
    /// Input: {"frame": N, "rule": RULE, "reliability": A or [A, ...] (optional),
    /// "mass_functions": [{"focal": [[0, 5, 7], [1, 2]], "mass": [0.6, 0.4]}, ...]}. Every
    /// function is first discounted by its reliability A (m(X) ← A·m(X), m(Ω) += 1 − A).
    /// "conflict_mass" κ and "conflict_level" K = −ln(1 − κ) are the conjunctive conflict of the
    /// (discounted) inputs, exact whatever the order, except for cautious and murphy. RULE and
    /// where κ goes: dempster (normalised away; no result on total conflict), conjunctive (kept
    /// on ∅; masses not normalised), yager (moved to the whole frame), dubois_prade (each
    /// conflicting tuple's product to the union of its sets), pcr6 (each conflicting tuple's
    /// product back to its sets in proportion to their masses; n-ary), disjunctive (unions; the
    /// rule creates none, κ is for information), cautious (non-dogmatic inputs, frames of at most
    /// 20 elements; κ is the result's own mass on ∅, kept there), murphy (the mean combined with
    /// itself n − 1 times by Dempster's rule; κ and K of that combination). Exit status 2 on bad
    /// input; K = +∞ prints "conflict_level": "inf" with a warning and exits 0.
    Combine(data::CombineArgs),
    /// Simulate a motion and write a dataset folder (PNG frames, poses.csv, manifest.json).
    Simulate(data::SimulateArgs),
    /// Bring your own frames: `dataset init FOLDER` makes a folder of PNGs a dataset,
    /// `dataset check FOLDER` reports every problem of one.
    Dataset(dataset_cmd::DatasetArgs),
    /// Render one frame at a pose (mm, robot frame), for developing features by eye.
    Render(data::RenderArgs),
    /// Extract the features of every frame of a dataset into a CSV (one row per frame, one
    /// column per feature, plus the ground truth when the dataset has it).
    Features(data::FeaturesArgs),
    /// Train any registered method (`--method`, default `evidential`) on a dataset of the sample
    /// trajectory and write its self-contained model file.
    Train(model::TrainArgs),
    /// Print a scenario as it runs, every setting filled in with a comment above it (without a
    /// file: the built-in default, `--defaults`).
    Scenario(scenario_cmd::ScenarioArgs),
    /// Track a dataset with a trained model: per-frame estimates to CSV, error summary when the
    /// dataset has ground truth.
    Track(model::TrackArgs),
}

/// Parses the command line, runs the command, maps errors to exit status 2.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    match dispatch(cli.command) {
        Ok(code) => code,
        Err(error) => {
            eprintln!("error: {}", error_text(&error));
            ExitCode::from(2)
        }
    }
}

/// The error and its causes joined by `: `, leaving out a cause whose text the message before
/// it already holds (library errors name their cause in their own message).
fn error_text(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&cause);
        }
    }
    text
}

fn dispatch(command: Command) -> Result<ExitCode> {
    match command {
        Command::Combine(args) => data::combine(&args),
        Command::Run(args) => runs::run(&args),
        Command::Sweep(args) => sweep::sweep(&args),
        Command::Merge(args) => merge::merge(&args),
        Command::Simulate(args) => data::simulate(&args),
        Command::Render(args) => data::render(&args),
        Command::Dataset(args) => dataset_cmd::dataset(&args),
        Command::Features(args) => data::features(&args),
        Command::Train(args) => model::train(&args),
        Command::Track(args) => model::track(&args),
        Command::Scenario(args) => scenario_cmd::scenario(&args),
    }
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
pub(crate) fn progress_bar(label: &str) -> ProgressBar {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(label.to_string());
    bar
}

/// Refuses to overwrite a folder that already holds files.
pub(crate) fn fresh_dir(dir: &Path) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        bail!(
            "{} is a file, not a folder: choose another --out",
            dir.display()
        );
    }
    let listing = || std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()));
    if dir.exists() && listing()?.next().is_some() {
        bail!(
            "{} exists and is not empty: choose another --out or remove it",
            dir.display()
        );
    }
    Ok(())
}

pub(crate) fn read_dataset(dir: &Path) -> Result<Dataset> {
    Dataset::read(dir).with_context(|| format!("reading the dataset {}", dir.display()))
}

pub(crate) fn feature_config(path: Option<&Path>, barycentre: bool) -> Result<FeatureConfig> {
    match path {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            toml::from_str(&text)
                .with_context(|| format!("{} is not a valid feature configuration", path.display()))
        }
        None if barycentre => Ok(FeatureConfig::with_barycentre()),
        None => Ok(FeatureConfig::default()),
    }
}

/// The feature configuration for `dataset` (`what` names it in errors): the file's, whose
/// polarity must be the one the dataset's manifest declares, or the default one with the
/// manifest's polarity.
pub(crate) fn feature_config_for(
    path: Option<&Path>,
    barycentre: bool,
    dataset: &Dataset,
    what: &str,
) -> Result<FeatureConfig> {
    let mut config = feature_config(path, barycentre)?;
    if path.is_none() {
        config.polarity = dataset.manifest.camera.polarity;
    }
    check_polarity(&config, dataset, what)?;
    Ok(config)
}

/// Fails when the features would read `dataset`'s frames the wrong way round: its manifest's
/// `camera.polarity` is not the configuration's.
pub(crate) fn check_polarity(config: &FeatureConfig, dataset: &Dataset, what: &str) -> Result<()> {
    let declared = dataset.manifest.camera.polarity;
    if config.polarity != declared {
        bail!(
            "{what} declares `camera.polarity = {}` in its manifest, but the feature configuration \
             reads frames as `{}`: set `polarity = \"{}\"` in the feature configuration (for a \
             model, train it again on frames of that polarity)",
            polarity_name(declared),
            polarity_name(config.polarity),
            polarity_name(declared)
        );
    }
    Ok(())
}

fn polarity_name(p: Polarity) -> &'static str {
    match p {
        Polarity::BrightOnDark => "bright_on_dark",
        Polarity::DarkOnBright => "dark_on_bright",
    }
}

/// The features of every frame, on every core, with a progress bar; then the external
/// programs' (`what` names the dataset in their errors).
pub(crate) fn extract_with_progress(
    set: &FeatureSet,
    dataset: &Dataset,
    what: &str,
) -> Result<FeatureRows> {
    let bar = progress_bar("features");
    bar.set_length(dataset.len() as u64);
    let rows = evitrack::external::extract(set, dataset, cores(), &mut |done, _| {
        bar.set_position(done as u64)
    });
    bar.finish_and_clear();
    rows.with_context(|| format!("the features of {what}"))
}

/// A spinner with the elapsed time, for a stage that reports no progress of its own (a fit).
pub(crate) fn spinner(label: &str) -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} {spinner} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.set_message(label.to_string());
    // The ticker is a thread: only for a bar that is drawn (stderr is a terminal).
    if !bar.is_hidden() {
        bar.enable_steady_tick(std::time::Duration::from_millis(120));
    }
    bar
}

/// `--memory-limit`: a size with its unit.
pub(crate) fn parse_memory_limit(text: &str) -> Result<u64, String> {
    evitrack::memory::parse_size(text).map_err(|e| e.to_string())
}

/// Holds `runs`, `jobs` at once, to `--memory-limit` (or the machine's default) before anything
/// large is allocated.
pub(crate) fn check_memory(
    runs: &[evitrack::scenario::CheckedScenario],
    jobs: usize,
    limit: Option<u64>,
) -> Result<()> {
    let estimates = runs
        .iter()
        .map(evitrack::memory::of_run)
        .collect::<Result<Vec<_>, _>>()?;
    let limit = evitrack::memory::Limit::from_option(limit, jobs);
    Ok(evitrack::memory::check(&estimates, jobs, limit)?)
}

/// The cores this process may use, the default thread count of every command.
pub(crate) fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// A buffered writer to the file, or to standard output when there is none.
/// Writes a command's output to `path` atomically, or to standard output without one.
pub(crate) fn write_output(path: Option<&Path>, bytes: &[u8]) -> Result<()> {
    match path {
        Some(path) => evitrack::atomic::write(path, bytes)
            .with_context(|| format!("writing {}", path.display())),
        None => {
            use std::io::Write;
            let mut out = std::io::stdout().lock();
            out.write_all(bytes)
                .and_then(|()| out.flush())
                .context("writing standard output")
        }
    }
}

/// Proves before any work that the folder of the output file `path` (when given) is writable.
pub(crate) fn ensure_output_writable(path: Option<&Path>) -> Result<()> {
    match path.map(|p| p.parent().unwrap_or(Path::new(""))) {
        Some(parent) if parent.as_os_str().is_empty() => ensure_writable(Path::new(".")),
        Some(parent) => ensure_writable(parent),
        None => Ok(()),
    }
}

pub(crate) fn load_scenarios(path: Option<&Path>) -> Result<ScenarioSet> {
    match path {
        Some(path) => Ok(ScenarioSet::load(path)?),
        None => Ok(ScenarioSet::builtin_default()?),
    }
}

pub(crate) use evitrack::report::tables::fmt_mm;

/// Creates `dir` and proves it writable before any work, so that a run does not compute for
/// minutes and then find `--out` read-only.
pub(crate) fn ensure_writable(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| {
        format!(
            "cannot create the output folder {}: choose another --out",
            dir.display()
        )
    })?;
    let probe = dir.join(".evitrack-write-probe");
    evitrack::atomic::write(&probe, b"").with_context(|| {
        format!(
            "cannot write to the output folder {}: choose another --out",
            dir.display()
        )
    })?;
    std::fs::remove_file(&probe).with_context(|| format!("removing {}", probe.display()))?;
    Ok(())
}
