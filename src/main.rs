//! The `evitrack` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};

use evitrack::dataset::Dataset;
use evitrack::evidence;
use evitrack::evidence::Constructor;
use evitrack::experiment::{self, FrameRecord, Part, RunSummary, Workbench};
use evitrack::features::{FeatureConfig, FeatureSet};
use evitrack::model::{EvidentialModel, ModelSettings, StateCounts, Tuning};
use evitrack::report::{self, ErrorStats, Table};
use evitrack::scenario::{SampleSettings, ScenarioSet};
use evitrack::sim::{self, Motion, NoiseSettings, SimSettings};
use evitrack::track::{Estimator, SelectionPolicy, TrackSettings};

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
    Run(RunArgs),
    /// Run every variant of one or more scenario files (in parallel), print one table, write
    /// CSV/JSON and plots; `--check` fails when a variant misses its expectations.
    Sweep(SweepArgs),
    /// Merge the JSON results of sweep shards (`sweep --shard i/n`) into one table and report.
    Merge(MergeArgs),
    /// Combine belief functions given as JSON and print the result as JSON on stdout.
    ///
    /// Input: {"frame": N, "rule": "dempster"|"conjunctive", "mass_functions":
    /// [{"focal": [[0, 5, 7], [1, 2]], "mass": [0.6, 0.4]}, ...]}. Exit status 2 on bad input;
    /// total conflict prints "conflict_level": "inf" with a warning and exits 0.
    Combine {
        /// Input JSON file (`-` reads standard input).
        file: PathBuf,
    },
    /// Simulate a motion and write a dataset folder (PNG frames, poses.csv, manifest.json).
    Simulate(SimulateArgs),
    /// Render one frame at a pose (mm, robot frame), for developing features by eye.
    Render(RenderArgs),
    /// Extract the features of every frame of a dataset into a CSV (one row per frame, one
    /// column per feature, plus the ground truth when the dataset has it).
    Features(FeaturesArgs),
    /// Train an evidential model on a dataset of the sample trajectory: one HMM per feature,
    /// its frame of discernment and its refining onto the sample poses.
    Train(TrainArgs),
    /// Track a dataset with a trained model: per-frame estimates to CSV, error summary when the
    /// dataset has ground truth.
    Track(TrackArgs),
}

#[derive(Debug, Args)]
struct SimArgs {
    /// Seed of the image noise (and of random paths).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Render without noise.
    #[arg(long)]
    noise_free: bool,
}

impl SimArgs {
    fn settings(&self) -> SimSettings {
        let mut settings = SimSettings::default();
        if self.noise_free {
            settings.noise = NoiseSettings::none();
        }
        settings
    }
}

#[derive(Debug, Args)]
struct SimulateArgs {
    /// Output folder (created; must be empty or absent).
    #[arg(long)]
    out: PathBuf,
    /// The motion as an inline TOML table, e.g.
    /// 'kind = "lissajous", freq_x = 0.3, freq_y = 0.2, duration = 10, fps = 10'.
    /// Default: the 1 mm mesh of the sample trajectory (400 nodes).
    #[arg(long, conflicts_with = "scenario")]
    motion: Option<String>,
    /// Simulate a motion of this scenario file instead, with its rig and the seed its run
    /// uses, so the dataset is the one `run` trains or tests on (`--seed`/`--noise-free` are
    /// ignored).
    #[arg(long)]
    scenario: Option<PathBuf>,
    /// Which of the scenario's motions: `sample`, `validation` or `test` (`test1`, … for later
    /// test motions).
    #[arg(long, default_value = "sample", requires = "scenario")]
    part: String,
    #[command(flatten)]
    sim: SimArgs,
}

#[derive(Debug, Args)]
struct RenderArgs {
    /// End-effector x (mm, robot frame; the workspace is x ∈ [−9.5, 9.5]).
    #[arg(long, allow_negative_numbers = true)]
    x: f64,
    /// End-effector y (mm, robot frame; the workspace is y ∈ [38, 57]).
    #[arg(long, allow_negative_numbers = true)]
    y: f64,
    /// Output PNG file.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    sim: SimArgs,
}

#[derive(Debug, Args)]
struct FeaturesArgs {
    /// Dataset folder (frames + poses.csv + manifest.json).
    dataset: PathBuf,
    /// Feature configuration (TOML, the `[features]` table of a scenario without its header).
    /// Default: the paper's 6 size functions.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Add the barycentre features (x, y) to the default configuration.
    #[arg(long, conflicts_with = "config")]
    barycentre: bool,
    /// Output CSV file (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct TrainArgs {
    /// Dataset folder of the sample trajectory (it must have ground-truth poses).
    dataset: PathBuf,
    /// Output model file (JSON).
    #[arg(long)]
    out: PathBuf,
    /// HMM state counts: one for every feature (`3`) or one per feature (`2,2,2,3,3,2`).
    /// Default: the paper's, 2,2,2,3,3,2 for the size functions then 3,2 for the barycentre.
    #[arg(long)]
    states: Option<String>,
    /// Tune each feature's state count by BIC between these bounds (`2..5`) instead.
    #[arg(long)]
    tune_bic: Option<String>,
    /// Feature configuration (TOML); default: the paper's 6 size functions.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Add the barycentre features to the default configuration.
    #[arg(long, conflicts_with = "config")]
    barycentre: bool,
    /// Seed of the EM initialisations.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(Debug, Args)]
struct RunArgs {
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
struct TrackArgs {
    /// Dataset folder to track.
    dataset: PathBuf,
    /// Model file written by `train` (or by `run`).
    #[arg(long)]
    model: PathBuf,
    /// Output CSV of per-frame estimates (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Belief-function constructor.
    #[arg(long, value_enum, default_value = "bayesian")]
    constructor: ConstructorArg,
    /// Conflict threshold: a number, `inf` (combine everything), or `model` (the threshold
    /// learned into the model; `inf` when it has none).
    #[arg(long, default_value = "model")]
    threshold: String,
    /// Which compatible group to combine: `largest`, `lowest:N` (lowest conflict among groups of
    /// at least N features) or `split:N` (every group of at least N; the first is reported).
    #[arg(long, default_value = "largest")]
    selection: String,
    /// Pointwise estimate from the combined belief function.
    #[arg(long, value_enum, default_value = "weighted-mean")]
    estimator: EstimatorArg,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum EstimatorArg {
    /// Σ Pl(q) q over the sample poses, with relative plausibilities.
    WeightedMean,
    /// The sample pose of highest plausibility.
    Map,
    /// Σ BetP(q) q with the pignistic probability.
    Pignistic,
}

fn parse_selection(text: &str) -> Result<SelectionPolicy> {
    let min_size = |n: &str| {
        n.parse::<usize>()
            .ok()
            .filter(|&n| n >= 1)
            .with_context(|| format!("--selection `{text}`: N must be a whole number ≥ 1"))
    };
    Ok(match text.split_once(':') {
        None if text == "largest" => SelectionPolicy::LargestSubset,
        Some(("lowest", n)) => SelectionPolicy::LowestConflict {
            min_size: min_size(n)?,
        },
        Some(("split", n)) => SelectionPolicy::Splitting {
            min_size: min_size(n)?,
        },
        _ => bail!("--selection `{text}` must be `largest`, `lowest:N` or `split:N`"),
    })
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum ConstructorArg {
    Bayesian,
    Consonant,
}

#[derive(Debug, Args)]
struct SweepArgs {
    /// Scenario files (TOML) whose [sweep] variants to run.
    #[arg(required = true)]
    scenarios: Vec<PathBuf>,
    /// Variants run at once (default: the number of cores).
    #[arg(long)]
    jobs: Option<usize>,
    /// Compare against each variant's expectations; exit 1 with a list of what regressed.
    #[arg(long)]
    check: bool,
    /// Run only slice i of n (1-based, e.g. `2/4`) of the variants, for batch schedulers; merge
    /// the shards' JSON files with `evitrack merge`.
    #[arg(long)]
    shard: Option<String>,
    /// Output folder.
    #[arg(long, default_value = "out")]
    out: PathBuf,
}

#[derive(Debug, Args)]
struct MergeArgs {
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

fn main() -> ExitCode {
    let cli = Cli::parse();
    match dispatch(cli.command) {
        Ok(code) => code,
        Err(error) => {
            eprintln!("error: {error:#}");
            ExitCode::from(2)
        }
    }
}

fn dispatch(command: Command) -> Result<ExitCode> {
    match command {
        Command::Combine { file } => combine(&file),
        Command::Run(args) => run(&args),
        Command::Sweep(args) => sweep(&args),
        Command::Merge(args) => merge(&args),
        Command::Simulate(args) => simulate(&args),
        Command::Render(args) => render(&args),
        Command::Features(args) => features(&args),
        Command::Train(args) => train(&args),
        Command::Track(args) => track_dataset(&args),
    }
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
fn progress_bar(label: &str) -> ProgressBar {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(label.to_string());
    bar
}

fn parse_motion(text: &str) -> Result<Motion> {
    let table = format!("motion = {{ {text} }}");
    #[derive(serde::Deserialize)]
    struct Wrapper {
        motion: Motion,
    }
    let wrapper: Wrapper = toml::from_str(&table)
        .with_context(|| format!("--motion '{text}' is not a valid motion table"))?;
    Ok(wrapper.motion)
}

/// Refuses to overwrite a folder that already holds files.
fn fresh_dir(dir: &Path) -> Result<()> {
    if dir.exists() && std::fs::read_dir(dir)?.next().is_some() {
        bail!(
            "{} exists and is not empty: choose another --out or remove it",
            dir.display()
        );
    }
    Ok(())
}

/// The rig, motion and seed of one part of a scenario, as `run` simulates it.
fn scenario_part(path: &Path, part: &str) -> Result<(SimSettings, Motion, u64)> {
    let scenario = ScenarioSet::load(path)?.base;
    let (motion, part) = match part {
        "sample" => (scenario.sample.motion.clone(), Part::Sample),
        "validation" => (
            scenario
                .validation
                .clone()
                .with_context(|| format!("{} has no validation motion", path.display()))?,
            Part::Validation,
        ),
        test if test.starts_with("test") => {
            let index: usize = match &test[4..] {
                "" => 0,
                digits => digits
                    .parse()
                    .with_context(|| format!("--part `{test}`: expected test, test1, test2, …"))?,
            };
            let motion = scenario.tests.get(index).cloned().with_context(|| {
                format!(
                    "{} has {} test motion(s): use --part test … test{}",
                    path.display(),
                    scenario.tests.len(),
                    scenario.tests.len().saturating_sub(1)
                )
            })?;
            (motion, Part::Test(index))
        }
        other => bail!("--part `{other}` must be sample, validation or test[N]"),
    };
    let seed = experiment::part_seed(scenario.seed, part);
    Ok((scenario.sim, motion, seed))
}

fn simulate(args: &SimulateArgs) -> Result<ExitCode> {
    let (settings, motion, seed) = match (&args.scenario, &args.motion) {
        (Some(path), _) => scenario_part(path, &args.part)?,
        (None, Some(text)) => (args.sim.settings(), parse_motion(text)?, args.sim.seed),
        (None, None) => (
            args.sim.settings(),
            SampleSettings::default().motion,
            args.sim.seed,
        ),
    };
    fresh_dir(&args.out)?;
    let bar = progress_bar("simulate");
    let dataset = sim::simulate(&settings, &motion, seed, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    dataset
        .write(&args.out)
        .with_context(|| format!("writing the dataset to {}", args.out.display()))?;
    eprintln!(
        "wrote {} frames of `{}` to {}",
        dataset.len(),
        motion.name(),
        args.out.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn render(args: &RenderArgs) -> Result<ExitCode> {
    let image = sim::render_pose(&args.sim.settings(), args.x, args.y, args.sim.seed)?;
    image
        .save(&args.out)
        .with_context(|| format!("writing {}", args.out.display()))?;
    eprintln!(
        "rendered ({}, {}) mm to {} ({}×{} px)",
        args.x,
        args.y,
        args.out.display(),
        image.width(),
        image.height()
    );
    Ok(ExitCode::SUCCESS)
}

fn combine(file: &Path) -> Result<ExitCode> {
    let (text, name) = if file == Path::new("-") {
        let text = std::io::read_to_string(std::io::stdin()).context("reading standard input")?;
        (text, "standard input".to_string())
    } else {
        let text =
            std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
        (text, file.display().to_string())
    };
    let report = evidence::exchange::combine_json(&text)
        .with_context(|| format!("{name} is not a valid combine input"))?;
    if report.is_total_conflict() {
        eprintln!(
            "warning: the mass functions are in total conflict (κ = 1): no combination exists"
        );
    }
    println!("{}", serde_json::to_string(&report)?);
    Ok(ExitCode::SUCCESS)
}

fn read_dataset(dir: &Path) -> Result<Dataset> {
    Dataset::read(dir).with_context(|| format!("reading the dataset {}", dir.display()))
}

fn feature_config(path: Option<&Path>, barycentre: bool) -> Result<FeatureConfig> {
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

/// The features of every frame, with a progress bar.
fn extract_with_progress(set: &FeatureSet, dataset: &Dataset) -> Vec<Vec<Option<f64>>> {
    let bar = progress_bar("features");
    bar.set_length(dataset.len() as u64);
    let rows = dataset
        .frames
        .iter()
        .map(|frame| {
            bar.inc(1);
            set.extract(&frame.image)
        })
        .collect();
    bar.finish_and_clear();
    rows
}

/// A buffered writer to the file, or to standard output when there is none.
fn output_sink(path: Option<&Path>) -> Result<Box<dyn std::io::Write>> {
    Ok(match path {
        Some(path) => Box::new(std::io::BufWriter::new(
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
        )),
        None => Box::new(std::io::stdout().lock()),
    })
}

fn features(args: &FeaturesArgs) -> Result<ExitCode> {
    let dataset = read_dataset(&args.dataset)?;
    let set = feature_config(args.config.as_deref(), args.barycentre)?.check()?;
    let rows = extract_with_progress(&set, &dataset);
    let sink = output_sink(args.out.as_deref())?;
    let mut csv = csv::Writer::from_writer(sink);
    let with_truth = dataset.frames.iter().all(|f| f.truth.is_some());
    let mut header = vec!["file".to_string(), "t".to_string()];
    header.extend(set.names());
    if with_truth {
        header.extend(["x", "y", "theta1", "theta2"].map(String::from));
    }
    csv.write_record(&header)?;
    for (frame, values) in dataset.frames.iter().zip(&rows) {
        let mut record = vec![frame.file.clone(), frame.t.to_string()];
        record.extend(
            values
                .iter()
                .map(|v| v.map(|v| v.to_string()).unwrap_or_default()),
        );
        if let (true, Some(truth)) = (with_truth, frame.truth) {
            record.extend([truth.x, truth.y, truth.theta1, truth.theta2].map(|v| v.to_string()));
        }
        csv.write_record(&record)?;
    }
    csv.flush()?;
    let missing = rows.iter().flatten().filter(|v| v.is_none()).count();
    eprintln!(
        "{} frames × {} features{}",
        rows.len(),
        set.len(),
        if missing > 0 {
            format!(", {missing} missing values (empty cells)")
        } else {
            String::new()
        }
    );
    Ok(ExitCode::SUCCESS)
}

fn parse_counts(text: &str, what: &str) -> Result<StateCounts> {
    let counts: Vec<usize> = text
        .split(',')
        .map(|c| c.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .with_context(|| {
            format!("{what} `{text}` must be a count (`3`) or a list of counts (`2,2,2,3,3,2`)")
        })?;
    Ok(match counts.as_slice() {
        [one] => StateCounts::All(*one),
        _ => StateCounts::PerFeature(counts),
    })
}

/// The paper's state count for one of its features (§6.2).
fn paper_states(feature: &str) -> Result<usize> {
    Ok(match feature {
        "size_line3" | "size_line4" | "barycentre_x" => 3,
        "size_line0" | "size_line1" | "size_line2" | "size_line5" | "barycentre_y" => 2,
        other => bail!("the paper gives no state count for feature `{other}`: pass --states"),
    })
}

fn train(args: &TrainArgs) -> Result<ExitCode> {
    let dataset = read_dataset(&args.dataset)?;
    let poses = dataset.truth_positions().with_context(|| {
        format!(
            "{} has frames without ground-truth poses: training needs the pose of every sample",
            args.dataset.display()
        )
    })?;
    let config = feature_config(args.config.as_deref(), args.barycentre)?;
    let set = config.check()?;
    let rows = extract_with_progress(&set, &dataset);
    let states = match &args.states {
        Some(text) => parse_counts(text, "--states")?,
        None => StateCounts::PerFeature(
            set.names()
                .iter()
                .map(|name| paper_states(name))
                .collect::<Result<_>>()?,
        ),
    };
    let mut settings = ModelSettings {
        states,
        seed: args.seed,
        ..ModelSettings::default()
    };
    if let Some(bounds) = &args.tune_bic {
        let (low, high) = bounds
            .split_once("..")
            .with_context(|| format!("--tune-bic `{bounds}` must look like `2..5`"))?;
        settings.tuning = Tuning::Bic {
            min_states: parse_counts(low, "--tune-bic lower bound")?,
            max_states: parse_counts(high, "--tune-bic upper bound")?,
        };
    }
    let mut model = EvidentialModel::train(&poses, &set.names(), &rows, &settings)?;
    model.set_feature_config(Some(config));
    model
        .save(&args.out)
        .with_context(|| format!("writing {}", args.out.display()))?;
    let mut table = Table::new([
        "feature",
        "states",
        "asked",
        "log-likelihood",
        "BIC",
        "block sizes",
        "notes",
    ]);
    for summary in model.summary() {
        let mut notes = Vec::new();
        if !summary.removed_states.is_empty() {
            notes.push(format!("removed states {:?}", summary.removed_states));
        }
        if summary.imputed > 0 {
            notes.push(format!("{} missing values imputed", summary.imputed));
        }
        table.push([
            summary.name.clone(),
            summary.states.to_string(),
            summary.requested_states.to_string(),
            format!("{:.3}", summary.log_likelihood),
            format!("{:.3}", summary.bic),
            format!("{:?}", summary.block_sizes),
            notes.join("; "),
        ]);
    }
    println!("{table}");
    eprintln!(
        "trained on {} sample poses; model written to {}",
        poses.len(),
        args.out.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn load_scenarios(path: Option<&Path>) -> Result<ScenarioSet> {
    match path {
        Some(path) => Ok(ScenarioSet::load(path)?),
        None => Ok(ScenarioSet::builtin_default()),
    }
}

fn fmt_mm(value: Option<f64>) -> String {
    value
        .map(|v| format!("{v:.4}"))
        .unwrap_or_else(|| "—".into())
}

fn error_table(summaries: &[&RunSummary]) -> Table {
    let mut table = Table::new([
        "scenario",
        "samples",
        "states",
        "constructor",
        "mean",
        "median",
        "RMS",
        "max",
        "paper",
        "no est.",
        "flagged",
    ]);
    for s in summaries {
        let states: Vec<String> = s.states.iter().map(usize::to_string).collect();
        table.push([
            s.scenario.clone(),
            s.samples.to_string(),
            states.join(","),
            s.constructor.clone(),
            fmt_mm(s.error.map(|e| e.mean)),
            fmt_mm(s.error.map(|e| e.median)),
            fmt_mm(s.error.map(|e| e.rms)),
            fmt_mm(s.error.map(|e| e.max)),
            fmt_mm(s.paper_error),
            format!("{}/{}", s.frames_without_estimate, s.frames),
            s.frames_flagged.to_string(),
        ]);
    }
    table
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

fn run(args: &RunArgs) -> Result<ExitCode> {
    let set = load_scenarios(args.scenario.as_deref())?;
    let mut scenario = set.base;
    if let Some(seed) = args.seed {
        scenario.seed = seed;
    }
    let bench = Workbench::new();
    let bars = StageBars::new(std::slice::from_ref(&scenario.name));
    let output = experiment::run(&scenario, &bench, &mut |stage, done, total| {
        bars.update(0, stage, done, total)
    });
    bars.finish();
    let output = output.with_context(|| format!("running scenario `{}`", scenario.name))?;
    let dir = args.out.join(&scenario.name);
    let written = experiment::write_run(&dir, &output)?;
    println!("{}", error_table(&[&output.summary]));
    for (label, stats) in &output.summary.per_motion {
        if output.summary.per_motion.len() > 1 {
            println!("  {label}: mean {}", fmt_mm(stats.map(|s| s.mean)));
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

fn track_dataset(args: &TrackArgs) -> Result<ExitCode> {
    let model = EvidentialModel::load(&args.model)
        .with_context(|| format!("loading the model {}", args.model.display()))?;
    let config = model.feature_config().cloned().with_context(|| {
        format!(
            "{} records no feature configuration, so its features cannot be extracted here",
            args.model.display()
        )
    })?;
    let set = config.check()?;
    let names = set.names();
    let model_names: Vec<String> = model
        .feature_names()
        .iter()
        .map(|n| n.to_string())
        .collect();
    if names != model_names {
        bail!(
            "the model's features {model_names:?} do not match its configuration's {names:?}: \
             the model file was edited or is corrupted"
        );
    }
    let mut settings = TrackSettings {
        constructor: match args.constructor {
            ConstructorArg::Bayesian => Constructor::Bayesian,
            ConstructorArg::Consonant => Constructor::Consonant,
        },
        selection: parse_selection(&args.selection)?,
        estimator: match args.estimator {
            EstimatorArg::WeightedMean => Estimator::WeightedMean,
            EstimatorArg::Map => Estimator::Map,
            EstimatorArg::Pignistic => Estimator::Pignistic,
        },
        ..TrackSettings::default()
    };
    settings.conflict_threshold = match args.threshold.as_str() {
        "model" => model.conflict_threshold().unwrap_or(f64::INFINITY),
        "inf" => f64::INFINITY,
        text => text
            .parse::<f64>()
            .ok()
            .filter(|t| *t >= 0.0)
            .with_context(|| {
                format!("--threshold `{text}` must be a number ≥ 0, `inf` or `model`")
            })?,
    };
    let tracker = experiment::tracker_for(&model, &settings)?;
    let dataset = read_dataset(&args.dataset)?;
    let bar = progress_bar("track");
    bar.set_length(dataset.len() as u64);
    let label = args
        .dataset
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".into());
    let mut records = Vec::with_capacity(dataset.len());
    for (i, frame) in dataset.frames.iter().enumerate() {
        let likelihoods = model.likelihoods(&set.extract(&frame.image))?;
        let estimate = tracker.track(&likelihoods)?;
        let truth = frame.truth.map(|t| [t.x, t.y]);
        records.push(FrameRecord::new(
            &label, i, frame.t, truth, &estimate, &names,
        ));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let sink = output_sink(args.out.as_deref())?;
    experiment::write_frames_csv(sink, &records, &names)?;
    let errors: Vec<f64> = records.iter().filter_map(|r| r.error).collect();
    let flagged = records.iter().filter(|r| !r.flags.is_empty()).count();
    let without = records.iter().filter(|r| r.estimate.is_none()).count();
    match ErrorStats::from_errors(&errors) {
        Some(stats) => eprintln!(
            "{} frames: error mean {:.4} mm, median {:.4}, RMS {:.4}, max {:.4}; {} flagged, {} without estimate",
            dataset.len(), stats.mean, stats.median, stats.rms, stats.max, flagged, without
        ),
        None => eprintln!(
            "{} frames tracked ({} flagged, {} without estimate); no ground truth, so no errors",
            dataset.len(), flagged, without
        ),
    }
    Ok(ExitCode::SUCCESS)
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

fn sweep(args: &SweepArgs) -> Result<ExitCode> {
    let mut variants = Vec::new();
    for path in &args.scenarios {
        let set = ScenarioSet::load(path)?;
        variants.extend(set.variants);
    }
    let names: std::collections::HashSet<&str> = variants.iter().map(|v| v.name.as_str()).collect();
    if names.len() != variants.len() {
        bail!("two variants of these scenario files have the same name: rename one scenario");
    }
    let total = variants.len();
    let shard = args.shard.as_deref().map(parse_shard).transpose()?;
    if let Some((i, n)) = shard {
        variants = variants
            .into_iter()
            .enumerate()
            .filter(|(k, _)| k % n == i)
            .map(|(_, v)| v)
            .collect();
        eprintln!(
            "shard {}/{n}: {} of {total} variants",
            i + 1,
            variants.len()
        );
    }
    let jobs = args.jobs.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let bench = Workbench::new();
    let labels: Vec<String> = variants.iter().map(|v| v.name.clone()).collect();
    let bars = StageBars::new(&labels);
    let clock = std::time::Instant::now();
    let outputs = experiment::run_all(&variants, jobs, &bench, &|i, stage, done, total| {
        bars.update(i, stage, done, total)
    });
    bars.finish();
    let elapsed = clock.elapsed().as_secs_f64();
    let mut summaries = Vec::new();
    let mut failures = Vec::new();
    for (variant, output) in variants.iter().zip(outputs) {
        match output {
            Ok(output) => {
                // A variant whose files cannot be written is reported, not the whole sweep lost.
                if let Err(error) = experiment::write_run(&args.out.join(&variant.name), &output) {
                    failures.push(format!("{}: {error}", variant.name));
                }
                summaries.push(output.summary);
            }
            Err(error) => failures.push(format!("{}: {error}", variant.name)),
        }
    }
    let file_name = match shard {
        Some((i, n)) => format!("sweep-shard-{}-of-{n}.json", i + 1),
        None => "sweep.json".to_string(),
    };
    write_sweep_report(&args.out, &file_name, &summaries)?;
    eprintln!(
        "{} variants in {elapsed:.1} s on {jobs} jobs; per-variant outputs in {}/<variant>/",
        summaries.len(),
        args.out.display()
    );
    finish_sweep(&summaries, &failures, args.check)
}

/// Prints the table, writes JSON, CSV and plots of a set of run summaries.
fn write_sweep_report(out: &Path, json_name: &str, summaries: &[RunSummary]) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let refs: Vec<&RunSummary> = summaries.iter().collect();
    println!("{}", error_table(&refs));
    let json_path = out.join(json_name);
    std::fs::write(&json_path, serde_json::to_string_pretty(summaries)? + "\n")
        .with_context(|| format!("writing {}", json_path.display()))?;
    let csv_path = out.join(json_name.replace(".json", ".csv"));
    let mut csv = csv::Writer::from_path(&csv_path)
        .with_context(|| format!("writing {}", csv_path.display()))?;
    csv.write_record([
        "scenario",
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
        "flagged",
        "expected_max_mean",
    ])?;
    let num = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
    for s in summaries {
        let states: Vec<String> = s.states.iter().map(usize::to_string).collect();
        csv.write_record([
            s.scenario.clone(),
            s.samples.to_string(),
            states.join(" "),
            s.constructor.clone(),
            s.conflict_threshold.value().to_string(),
            num(s.error.map(|e| e.mean)),
            num(s.error.map(|e| e.median)),
            num(s.error.map(|e| e.rms)),
            num(s.error.map(|e| e.max)),
            num(s.paper_error),
            s.frames.to_string(),
            s.frames_without_estimate.to_string(),
            s.frames_flagged.to_string(),
            num(s.expect.max_mean_error),
        ])?;
    }
    csv.flush()?;
    let plotted: Vec<&RunSummary> = summaries.iter().filter(|s| s.error.is_some()).collect();
    if !plotted.is_empty() {
        let labels: Vec<String> = plotted.iter().map(|s| s.scenario.clone()).collect();
        let errors: Vec<f64> = plotted
            .iter()
            .filter_map(|s| s.error.map(|e| e.mean))
            .collect();
        let paper: Vec<Option<f64>> = plotted.iter().map(|s| s.paper_error).collect();
        let has_paper = paper.iter().any(Option::is_some);
        report::plot_errors_by_variant(
            &out.join(json_name.replace(".json", "-errors.png")),
            "mean estimation error per variant",
            &labels,
            &errors,
            has_paper.then_some(paper.as_slice()),
        )?;
        // Where the variants differ in their state counts, error against the total count.
        let totals: Vec<usize> = plotted.iter().map(|s| s.states.iter().sum()).collect();
        if totals
            .iter()
            .collect::<std::collections::HashSet<_>>()
            .len()
            > 1
        {
            let mut points: Vec<(f64, f64)> = totals
                .iter()
                .zip(&errors)
                .map(|(&n, &e)| (n as f64, e))
                .collect();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            report::plot_series(
                &out.join(json_name.replace(".json", "-states.png")),
                "mean error against the total number of states",
                "Σ nᵢ (states over all features)",
                "mean error (mm)",
                &[report::PlotSeries {
                    name: "variants".into(),
                    points,
                }],
            )?;
        }
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

fn merge(args: &MergeArgs) -> Result<ExitCode> {
    let mut summaries: Vec<RunSummary> = Vec::new();
    for path in &args.shards {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let shard: Vec<RunSummary> = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a sweep result file", path.display()))?;
        summaries.extend(shard);
    }
    let mut seen = std::collections::HashSet::new();
    if let Some(dup) = summaries.iter().find(|s| !seen.insert(s.scenario.clone())) {
        bail!(
            "variant `{}` appears in two shard files: merge each shard once",
            dup.scenario
        );
    }
    write_sweep_report(&args.out, "sweep.json", &summaries)?;
    finish_sweep(&summaries, &[], args.check)
}
