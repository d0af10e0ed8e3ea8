//! The `evitrack` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use evitrack::evidence;
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
