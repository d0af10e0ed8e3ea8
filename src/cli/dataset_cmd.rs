//! `dataset init` and `dataset check`: bringing your own frames.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};

use evitrack::dataset::{check_folder, init_folder, InitOptions, Polarity, Rect};

/// What to do with a dataset folder.
#[derive(Debug, Args)]
pub struct DatasetArgs {
    #[command(subcommand)]
    command: DatasetCommand,
}

#[derive(Debug, Subcommand)]
enum DatasetCommand {
    /// Make a folder of PNG frames a dataset: writes its `poses.csv` and `manifest.json` (the
    /// frames are left as they are). The image size is read from the frames; the rest from the
    /// options, whose defaults are the simulated rig's camera.
    Init(InitArgs),
    /// Report every problem of a dataset folder at once (manifest fields, pose rows, missing or
    /// wrongly sized frames); exit 1 when there is any.
    Check(CheckArgs),
}

#[derive(Debug, Args)]
struct InitArgs {
    /// The folder holding the frames (`*.png` directly in it, taken in file-name order: number
    /// them with leading zeros).
    folder: PathBuf,
    /// A CSV of positions (mm) with a header: columns `x`, `y`, optionally `t` (s) and `file`
    /// (the frame's name). Without `file`, row k is the k-th frame in file-name order. An empty
    /// x, y leaves a frame without a pose. Without the CSV, no frame has one.
    #[arg(long, value_name = "CSV")]
    poses: Option<PathBuf>,
    /// Pixel size (mm per pixel).
    #[arg(long, default_value_t = 0.2)]
    mm_per_px: f64,
    /// World point (mm) at the image centre, `X,Y`.
    #[arg(
        long,
        value_name = "X,Y",
        default_value = "0,47.5",
        allow_hyphen_values = true
    )]
    centre: String,
    /// Which way round the frames are drawn.
    #[arg(long, value_enum, default_value = "bright-on-dark")]
    polarity: PolarityArg,
    /// The workspace (mm), `X_MIN,X_MAX,Y_MIN,Y_MAX`: poses outside it are refused, and missing
    /// estimates cost its diagonal. Default: none.
    #[arg(
        long,
        value_name = "X_MIN,X_MAX,Y_MIN,Y_MAX",
        allow_hyphen_values = true
    )]
    workspace: Option<String>,
    /// Frames per second: frame k is at time k / fps when the CSV has no `t` column.
    #[arg(long, default_value_t = 10.0)]
    fps: f64,
    /// A name for the recording (the manifest's `scenario`). Default: the folder's name.
    #[arg(long)]
    name: Option<String>,
    /// Replace an existing `manifest.json` and `poses.csv`.
    #[arg(long)]
    force: bool,
}

#[derive(Debug, Args)]
struct CheckArgs {
    /// The dataset folder.
    folder: PathBuf,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum PolarityArg {
    /// A bright body on a dark background (the simulator's frames).
    BrightOnDark,
    /// A dark body on a bright background.
    DarkOnBright,
}

/// Runs `dataset init` or `dataset check`.
pub fn dataset(args: &DatasetArgs) -> Result<ExitCode> {
    match &args.command {
        DatasetCommand::Init(args) => init(args),
        DatasetCommand::Check(args) => check(args),
    }
}

/// `text` as `n` comma-separated finite numbers (`what` names the option in errors).
fn numbers<const N: usize>(text: &str, what: &str) -> Result<[f64; N]> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .ok()
        .filter(|v: &Vec<f64>| v.len() == N && v.iter().all(|x| x.is_finite()))
        .with_context(|| format!("{what} `{text}` must be {N} numbers separated by commas"))?;
    let mut out = [0.0; N];
    out.copy_from_slice(&values);
    Ok(out)
}

fn init(args: &InitArgs) -> Result<ExitCode> {
    if !args.folder.is_dir() {
        bail!(
            "{} is not a folder: give the folder that holds the PNG frames",
            args.folder.display()
        );
    }
    let workspace = match &args.workspace {
        Some(text) => {
            let [x_min, x_max, y_min, y_max] = numbers::<4>(text, "--workspace")?;
            Some(Rect {
                x_min,
                x_max,
                y_min,
                y_max,
            })
        }
        None => None,
    };
    let name = args.name.clone().unwrap_or_else(|| {
        args.folder
            .canonicalize()
            .ok()
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_default()
    });
    let options = InitOptions {
        mm_per_px: args.mm_per_px,
        centre: numbers::<2>(&args.centre, "--centre")?,
        polarity: match args.polarity {
            PolarityArg::BrightOnDark => Polarity::BrightOnDark,
            PolarityArg::DarkOnBright => Polarity::DarkOnBright,
        },
        workspace,
        fps: args.fps,
        name,
        ..InitOptions::default()
    };
    let dataset = init_folder(&args.folder, &options, args.poses.as_deref(), args.force)
        .with_context(|| format!("making {} a dataset", args.folder.display()))?;
    let with_truth = dataset.frames.iter().filter(|f| f.truth.is_some()).count();
    let c = &dataset.manifest.camera;
    eprintln!(
        "{}: {} frames of {}×{} px at {} mm/px, {} with a pose; wrote manifest.json and poses.csv",
        args.folder.display(),
        dataset.len(),
        c.width,
        c.height,
        c.mm_per_px,
        with_truth
    );
    Ok(ExitCode::SUCCESS)
}

fn check(args: &CheckArgs) -> Result<ExitCode> {
    let report = check_folder(&args.folder);
    for problem in &report.problems {
        println!("{problem}");
    }
    if report.problems.is_empty() {
        eprintln!(
            "{}: a dataset of {} frames, {} with a pose; no problems",
            args.folder.display(),
            report.frames,
            report.with_truth
        );
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!(
            "{}: {} problem(s)",
            args.folder.display(),
            report.problems.len()
        );
        Ok(ExitCode::from(1))
    }
}
