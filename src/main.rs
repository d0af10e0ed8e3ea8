//! The `evitrack` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use evitrack::dataset::Dataset;
use evitrack::evidence;
use evitrack::features::FeatureConfig;
use evitrack::sim::{self, Motion, NoiseSettings, SimSettings};

/// Evidential (Dempster–Shafer) pose tracking on a simulated five-bar robot.
#[derive(Debug, Parser)]
#[command(name = "evitrack", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
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
    #[arg(long)]
    motion: Option<String>,
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
        Command::Simulate(args) => simulate(&args),
        Command::Render(args) => render(&args),
        Command::Features(args) => features(&args),
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

fn simulate(args: &SimulateArgs) -> Result<ExitCode> {
    let motion = match &args.motion {
        Some(text) => parse_motion(text)?,
        None => Motion::Mesh { spacing: 1.0 },
    };
    fresh_dir(&args.out)?;
    let settings = args.sim.settings();
    let bar = progress_bar("simulate");
    let dataset = sim::simulate(&settings, &motion, args.sim.seed, &mut |done, total| {
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

fn features(args: &FeaturesArgs) -> Result<ExitCode> {
    let dataset = read_dataset(&args.dataset)?;
    let set = feature_config(args.config.as_deref(), args.barycentre)?.check()?;
    let bar = progress_bar("features");
    bar.set_length(dataset.len() as u64);
    let rows: Vec<Vec<Option<f64>>> = dataset
        .frames
        .iter()
        .map(|frame| {
            bar.inc(1);
            set.extract(&frame.image)
        })
        .collect();
    bar.finish_and_clear();
    let sink: Box<dyn std::io::Write> = match &args.out {
        Some(path) => Box::new(
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
        ),
        None => Box::new(std::io::stdout().lock()),
    };
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
