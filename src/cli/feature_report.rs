//! `evitrack features DATASET --report`: the feature author's report
//! (`evitrack::feature_report`) as a table, and with `--out DIR` as JSON and a plot.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Args;

use super::{cores, ensure_writable, extract_with_progress, fresh_dir};
use super::{progress_bar, read_dataset, spinner};
use evitrack::dataset::Dataset;
use evitrack::estimator::{Labelled, Method};
use evitrack::faults::FaultSpec;
use evitrack::feature_report::{self, FeatureReport, Inputs, Options};
use evitrack::features::{FeatureRows, FeatureSet};

/// The report's options of `features`.
#[derive(Debug, Args)]
pub struct ReportArgs {
    /// Print a report for the features' author instead of the CSV: per feature its spread,
    /// missing share, correlation, how often each fault changes it and, with ground truth, its
    /// noise σ, share of the Fisher information, neighbour separation (§3.1) and ablation. With
    /// --out, a folder (created, must be empty) for feature-report.json and
    /// feature-information.png.
    #[arg(long)]
    pub report: bool,
    /// With --report: a dataset with ground truth for σ and the ablation's errors (default:
    /// the odd frames of DATASET; the even ones are fitted on).
    #[arg(long, value_name = "DATASET", requires = "report")]
    validation: Option<PathBuf>,
    /// With --report: per-frame methods of the ablation, comma-separated; `none` for none. Each
    /// is fitted (features + 1) times.
    #[arg(long, value_delimiter = ',', default_value = "knn")]
    methods: Vec<String>,
    /// With --report: a TOML file of `[[faults]]` tables (a scenario's) applied instead of the
    /// default image faults (dark and bright 15 × 15 px boxes and a glare at the frame's
    /// centre, 1 % salt-and-pepper, a black frame).
    #[arg(long, value_name = "FILE.toml", requires = "report")]
    faults: Option<PathBuf>,
    /// With --report: frames (evenly spaced) each fault is applied to.
    #[arg(long, value_name = "N", default_value_t = 100)]
    fault_frames: usize,
    /// With --report: seed of the faults' draws.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// With --report: points per axis of the information's grid over the workspace.
    #[arg(long, value_name = "N", default_value_t = 20)]
    grid: usize,
}

impl ReportArgs {
    fn methods(&self) -> Result<Vec<Method>> {
        if self.methods.iter().any(|m| m == "none") {
            return Ok(Vec::new());
        }
        self.methods
            .iter()
            .map(|name| name.parse::<Method>().map_err(anyhow::Error::msg))
            .collect::<Result<_>>()
            .context("--methods")
    }

    fn faults(&self, dataset: &Dataset) -> Result<Vec<FaultSpec>> {
        let Some(path) = &self.faults else {
            let camera = dataset.manifest.camera;
            return Ok(feature_report::default_faults(camera.width, camera.height));
        };
        #[derive(serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Faults {
            faults: Vec<FaultSpec>,
        }
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let faults: Faults = toml::from_str(&text)
            .with_context(|| format!("{} is not a list of [[faults]] tables", path.display()))?;
        Ok(faults.faults)
    }
}

/// The report on `dataset`'s features `rows` (extracted with `set`), printed, and written into
/// `out` when given.
pub fn report(
    args: &ReportArgs,
    dataset: &Dataset,
    set: &FeatureSet,
    rows: &FeatureRows,
    out: Option<&Path>,
) -> Result<ExitCode> {
    let clock = Instant::now();
    let methods = args.methods()?;
    let faults = args.faults(dataset)?;
    if !(2..=200).contains(&args.grid) {
        bail!("--grid {} must lie in 2..=200", args.grid);
    }
    if rows.is_empty() {
        bail!("the dataset has no frames: nothing to report on");
    }
    if let Some(dir) = out {
        fresh_dir(dir)?;
        ensure_writable(dir)?;
    }
    let validation = match &args.validation {
        Some(path) => Some(validation_features(path, set)?),
        None => None,
    };
    let names = set.names();
    let poses = dataset.truth_positions();
    if poses.is_none() && dataset.frames.iter().any(|f| f.truth.is_some()) {
        eprintln!("note: some frames lack ground truth: reporting what needs none");
    }
    let bar = spinner("faults");
    let changes = feature_report::fault_changes(
        &faults,
        set,
        dataset,
        rows,
        args.fault_frames,
        args.seed,
        cores(),
    )?;
    bar.finish_and_clear();
    let inputs = Inputs {
        names: &names,
        rows,
        poses: poses.as_deref(),
        validation: validation
            .as_ref()
            .map(|(poses, rows)| Labelled { poses, rows }),
        workspace: dataset.manifest.workspace,
    };
    let options = Options {
        methods,
        grid: args.grid,
    };
    let bar = progress_bar("report");
    let report = feature_report::build(&inputs, &options, &changes, &mut |stage, done, total| {
        if bar.message() != stage {
            bar.set_message(stage.to_string());
        }
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    print_report(&report);
    if let Some(dir) = out {
        for path in feature_report::write_outputs(&report, dir)? {
            eprintln!("wrote {}", path.display());
        }
    }
    eprintln!("report in {:.1} s", clock.elapsed().as_secs_f64());
    Ok(ExitCode::SUCCESS)
}

/// The validation dataset's poses and features.
fn validation_features(path: &Path, set: &FeatureSet) -> Result<(Vec<[f64; 2]>, FeatureRows)> {
    let dataset = read_dataset(path)?;
    let what = path.display().to_string();
    let Some(poses) = dataset.truth_positions() else {
        bail!("--validation {what} has no ground truth: it is where σ is measured");
    };
    if set
        .polarity()
        .is_some_and(|p| p != dataset.manifest.camera.polarity)
    {
        bail!("--validation {what} declares the other camera polarity from DATASET's");
    }
    let rows = extract_with_progress(set, &dataset, &what)?;
    Ok((poses, rows))
}

fn print_report(report: &FeatureReport) {
    println!(
        "{} frames, {}; faults on {} frames",
        report.frames, report.split, report.fault_frames
    );
    for (method, error) in &report.method_errors {
        println!("{method}: mean error {error:.4} mm with every feature");
    }
    if let Some(limit) = report.limit_rms {
        println!("Cramér–Rao limit (RMS over the grid): {limit:.4} mm");
    }
    println!("{}", feature_report::table(report));
    for note in &report.notes {
        eprintln!("note: {note}");
    }
}
