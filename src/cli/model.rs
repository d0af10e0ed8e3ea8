//! Commands on models: `train` and `track`, through the estimator seam.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::Args;

use super::{
    check_polarity, ensure_output_writable, extract_with_progress, feature_config_for,
    progress_bar, read_dataset, spinner, write_output,
};
use evitrack::estimator::{self, DatasetFeatures, Evidential, Method, PoseEstimator, TrainingSet};
use evitrack::evidence::{ConflictLevel, Constructor};
use evitrack::model::StateCounts;
use evitrack::model_file::Provenance;
use evitrack::report::{write_frames_csv, ErrorStats, FrameRecord, Table};
use evitrack::track::{PoseRule, SelectionPolicy, ThresholdRule, TrackSettings};

/// Tracker settings given on the command line; what is left out keeps its value.
#[derive(Debug, Args)]
pub(super) struct TrackOptions {
    /// Belief-function constructor [default at training: bayesian].
    #[arg(long, value_enum)]
    pub(super) constructor: Option<ConstructorArg>,
    /// Conflict threshold, one spelling for every method that has one: a number ≥ 0, `inf`
    /// (combine everything), `learned` (on the validation dataset, by the method's rule) or
    /// `quantile:Q` (learned as the Q-quantile of the validation levels) [default at training:
    /// the evidential tracker learns it with --validation, inf without; at tracking: the model's].
    #[arg(long)]
    pub(super) threshold: Option<String>,
    /// Which compatible group to combine: `largest`, `lowest:N` (lowest conflict among groups of
    /// at least N features) or `split:N` (every group of at least N; the first is reported)
    /// [default at training: largest].
    #[arg(long)]
    pub(super) selection: Option<String>,
    /// Pointwise estimate from the combined belief function [default at training:
    /// weighted-mean].
    #[arg(long, value_enum)]
    pub(super) estimator: Option<EstimatorArg>,
}

impl TrackOptions {
    /// Whether any option was given.
    fn given(&self) -> bool {
        self.constructor.is_some()
            || self.threshold.is_some()
            || self.selection.is_some()
            || self.estimator.is_some()
    }

    /// `base` with the options given replacing its values.
    fn apply(&self, base: &TrackSettings) -> Result<TrackSettings> {
        let mut settings = base.clone();
        if let Some(c) = self.constructor {
            settings.constructor = match c {
                ConstructorArg::Bayesian => Constructor::Bayesian,
                ConstructorArg::Consonant => Constructor::Consonant,
            };
        }
        if let Some(text) = &self.selection {
            settings.selection = parse_selection(text)?;
        }
        if let Some(e) = self.estimator {
            settings.estimator = e.rule();
        }
        if let Some(text) = &self.threshold {
            settings.conflict_threshold = fixed_threshold(text)?;
        }
        Ok(settings)
    }
}

/// What `--threshold` says.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum ThresholdArg {
    /// A threshold used as given.
    Fixed(ConflictLevel),
    /// Learned on the validation motion, by this rule or the settings' own.
    Learned(Option<ThresholdRule>),
}

/// `--threshold`: a number ≥ 0, `inf`, `learned` or `quantile:Q`.
pub(super) fn parse_threshold(text: &str) -> Result<ThresholdArg> {
    let wrong =
        || format!("--threshold `{text}` must be a number ≥ 0, `inf`, `learned` or `quantile:Q`");
    Ok(match text.split_once(':') {
        None if text == "inf" => ThresholdArg::Fixed(ConflictLevel::Infinite),
        None if text == "learned" => ThresholdArg::Learned(None),
        Some(("quantile", q)) => ThresholdArg::Learned(Some(ThresholdRule::Quantile(
            q.parse::<f64>().ok().with_context(wrong)?,
        ))),
        _ => text
            .parse::<f64>()
            .ok()
            .filter(|t| t.is_finite() && *t >= 0.0)
            .map(|t| ThresholdArg::Fixed(ConflictLevel::Finite(t)))
            .with_context(wrong)?,
    })
}

/// `--threshold` at tracking: a trained model's threshold can be replaced, not learned again.
fn fixed_threshold(text: &str) -> Result<ConflictLevel> {
    match parse_threshold(text)? {
        ThresholdArg::Fixed(level) => Ok(level),
        ThresholdArg::Learned(_) => bail!(
            "--threshold `{text}` learns the threshold, which only `train --validation` can do: \
             give `track` a number or `inf`"
        ),
    }
}

/// Arguments of `train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Dataset folder of the sample trajectory (it must have ground-truth poses).
    pub(super) dataset: PathBuf,
    /// Output model file (JSON): self-contained, `track --model` needs nothing else.
    #[arg(long)]
    pub(super) out: PathBuf,
    /// A dataset of a validation motion (with ground truth), for what the method learns on
    /// held-out frames (the evidential tracker: each feature's own error and the conflict
    /// threshold, §4.3).
    #[arg(long)]
    pub(super) validation: Option<PathBuf>,
    /// The estimation method: any registered one (`evidential`, `evidential_temporal`,
    /// `continuous`, `continuous_temporal`, `knn`, `gp`, `particle_filter`, `centre`).
    #[arg(long, default_value = "evidential", value_parser = parse_method)]
    pub(super) method: Method,
    /// Take the method's settings from this scenario file's sections (its `[knn]`, `[track]`,
    /// …); the options below and --set then replace values in them. Default: the built-in
    /// scenario's settings.
    #[arg(long)]
    pub(super) scenario: Option<PathBuf>,
    /// Replace a setting by its dotted scenario path, as a sweep variant does (`--set knn.k=8`,
    /// `--set 'continuous.selection={ policy = "lowest_conflict", min_size = 5 }'`); repeatable.
    /// The value is TOML (a bare word is a string).
    #[arg(long = "set", value_name = "PATH=VALUE", value_parser = parse_setting)]
    pub(super) set: Vec<(String, toml::Value)>,
    /// HMM state counts (`model.states`): one for every feature (`3`) or one per feature
    /// (`2,2,2,3,3,2`). Default without --scenario: the paper's, 2,2,2,3,3,2 for the size
    /// functions then 3,2 for the barycentre.
    #[arg(long)]
    pub(super) states: Option<String>,
    /// Tune each feature's state count by BIC between these bounds (`2..5`, `model.tuning`).
    #[arg(long)]
    pub(super) tune_bic: Option<String>,
    /// Feature configuration (TOML); default: the paper's 6 size functions.
    #[arg(long)]
    pub(super) config: Option<PathBuf>,
    /// Add the barycentre features to the default configuration.
    #[arg(long, conflicts_with = "config")]
    pub(super) barycentre: bool,
    /// An external feature program's settings (TOML: `command`, `values`, `missing`,
    /// `timeout_seconds`); its values follow the configuration's. Repeatable.
    #[arg(long = "feature-program", value_name = "FILE.toml")]
    pub(super) feature_program: Vec<PathBuf>,
    /// Seed of the EM initialisations (`model.seed`).
    #[arg(long, default_value_t = 1)]
    pub(super) seed: u64,
    /// k-NN: the number of neighbours (`knn.k`).
    #[arg(long)]
    pub(super) k: Option<usize>,
    /// k-NN: how the neighbours' poses are weighted (`knn.weights`).
    #[arg(long, value_enum)]
    pub(super) weights: Option<WeightsArg>,
    #[command(flatten)]
    pub(super) track: TrackOptions,
    /// Refuse (exit 2) before fitting when the estimated peak memory is above this (`4GiB`,
    /// `1500MB`, bytes). Default: 3/4 of the smaller of the machine's memory and `ulimit -v`.
    #[arg(long, value_name = "SIZE", value_parser = super::parse_memory_limit)]
    pub(super) memory_limit: Option<u64>,
}

/// `--method`: a registered method's name.
fn parse_method(text: &str) -> Result<Method, String> {
    text.parse()
}

/// `--set PATH=VALUE`: the value as TOML, or as a string when it is not TOML.
fn parse_setting(text: &str) -> Result<(String, toml::Value), String> {
    let (path, value) = text
        .split_once('=')
        .ok_or_else(|| format!("`{text}` must look like PATH=VALUE, e.g. knn.k=8"))?;
    let value = value.trim();
    let parsed = toml::from_str::<toml::Table>(&format!("v = {value}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(value.to_string()));
    Ok((path.trim().to_string(), parsed))
}

#[derive(Debug, Clone, Copy, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum WeightsArg {
    /// Every neighbour counts the same.
    Uniform,
    /// Neighbours count as 1 / distance.
    Distance,
}

/// Arguments of `track`.
#[derive(Debug, Args)]
pub struct TrackArgs {
    /// Dataset folder to track.
    dataset: PathBuf,
    /// Model file written by `train`, `run` or `sweep` (`<out>/<scenario>/model-<method>.json`,
    /// e.g. `model-evidential.json`).
    #[arg(long)]
    model: PathBuf,
    /// Output CSV of per-frame estimates (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
    /// The settings of each external feature program the model was trained with, in order (a
    /// model file runs no program by itself). Repeatable.
    #[arg(long = "feature-program", value_name = "FILE.toml")]
    feature_program: Vec<PathBuf>,
    /// The sample frames the model was trained on (a dataset folder): with a model file that
    /// carries the render check's limit (`confidence.render_check`, on by default), each estimate
    /// whose predicted silhouette misses the frame's by more than that limit abstains (flag
    /// `render_mismatch`), as does each frame with more stray pixels than the model's
    /// calibration frames showed (flag `stray_pixels`), as in the run.
    #[arg(long, value_name = "SAMPLE_DATASET")]
    samples: Option<PathBuf>,
    /// Options given here replace the model's tracker settings.
    #[command(flatten)]
    track: TrackOptions,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(super) enum EstimatorArg {
    /// Σ Pl(q) q over the sample poses, with relative plausibilities.
    WeightedMean,
    /// The sample pose of highest plausibility.
    Map,
    /// Σ BetP(q) q with the pignistic probability.
    Pignistic,
}

impl EstimatorArg {
    pub(super) fn rule(self) -> PoseRule {
        match self {
            EstimatorArg::WeightedMean => PoseRule::WeightedMean,
            EstimatorArg::Map => PoseRule::Map,
            EstimatorArg::Pignistic => PoseRule::Pignistic,
        }
    }
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(super) enum ConstructorArg {
    Bayesian,
    Consonant,
}

pub(super) fn parse_selection(text: &str) -> Result<SelectionPolicy> {
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

pub(super) fn parse_counts(text: &str, what: &str) -> Result<StateCounts> {
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
pub(super) fn paper_states(feature: &str) -> Result<usize> {
    Ok(match feature {
        "size_line3" | "size_line4" | "barycentre_x" => 3,
        "size_line0" | "size_line1" | "size_line2" | "size_line5" | "barycentre_y" => 2,
        other => bail!("the paper gives no state count for feature `{other}`: pass --states"),
    })
}

/// Holds the fit to `--memory-limit` (or the machine's default) before it allocates.
fn check_fit_memory(
    args: &TrainArgs,
    dataset: &evitrack::dataset::Dataset,
    settings: &evitrack::estimator::EstimatorSettings,
    features: usize,
    poses: &[[f64; 2]],
) -> Result<()> {
    use evitrack::memory::{check, fit_parts, Estimate, FitShape, Limit, Part};
    let extent = match &dataset.manifest.workspace {
        Some(w) => [w.x_max - w.x_min, w.y_max - w.y_min],
        None => {
            let (lo, hi) = evitrack::planar::bounding_box(poses);
            [hi[0] - lo[0], hi[1] - lo[1]]
        }
    };
    let shape = FitShape {
        samples: poses.len(),
        features,
        extent,
    };
    let images = Part {
        what: format!("the dataset's {} images", dataset.frames.len()),
        setting: args.dataset.display().to_string(),
        bytes: dataset.images().map(|i| i.len() as u64).sum(),
    };
    let estimate = Estimate {
        name: format!("train --method {}", args.method),
        parts: std::iter::once(images)
            .chain(fit_parts(&[args.method], settings, &shape))
            .collect(),
    };
    Ok(check(
        &[estimate],
        1,
        Limit::from_option(args.memory_limit, 1),
    )?)
}

pub fn train(args: &TrainArgs) -> Result<ExitCode> {
    ensure_output_writable(Some(&args.out))?;
    let dataset = read_dataset(&args.dataset)?;
    let what = args.dataset.display().to_string();
    let mut config = feature_config_for(args.config.as_deref(), args.barycentre, &dataset, &what)?;
    config
        .external
        .extend(super::programs::read_programs(&args.feature_program)?);
    let set = config.check()?;
    let names = set.names();
    let sample = DatasetFeatures {
        poses: dataset.truth_positions().with_context(|| {
            format!("{what} has frames without ground-truth poses: training needs the pose of every sample")
        })?,
        rows: extract_with_progress(&set, &dataset, &what)?,
    };
    let validation_data = args.validation.as_deref().map(read_dataset).transpose()?;
    let validation = match (&args.validation, &validation_data) {
        (Some(path), Some(data)) => {
            check_polarity(&config, data, &path.display().to_string())?;
            let times: Vec<f64> = data.frames.iter().map(|f| f.t).collect();
            Some((
                DatasetFeatures {
                    poses: data.truth_positions().with_context(|| {
                        format!(
                            "{} has frames without ground-truth poses: validation needs them",
                            path.display()
                        )
                    })?,
                    rows: extract_with_progress(&set, data, &path.display().to_string())?,
                },
                times,
            ))
        }
        _ => None,
    };
    let training = TrainingSet {
        feature_names: &names,
        feature_config: Some(&config),
        sample: sample.labelled(),
        validation: validation.as_ref().map(|(v, _)| v.labelled()),
        validation_times: validation.as_ref().map(|(_, t)| t.as_slice()),
        calibration: None,
        calibration_times: None,
        missing_penalty: dataset.workspace_diagonal(),
        provenance: Provenance::new(None, args.seed).with_workspace(dataset.manifest.workspace),
    };
    let settings = super::train_settings::train_settings(args, &names, validation.is_some())?;
    let method = args.method;
    check_fit_memory(args, &dataset, &settings, names.len(), &sample.poses)?;
    let bar = spinner(&format!("fit {method}"));
    let estimator = method.fit(&settings, &training);
    bar.finish_and_clear();
    let mut estimator = estimator?;
    let confidence = &settings.confidence;
    let data = (validation_data.as_ref().zip(validation.as_ref()))
        .map(|(data, (features, times))| (data, features.rows.as_slice(), times.as_slice()));
    let limit =
        super::render_check::learn_limit(estimator.as_mut(), confidence, &config, &dataset, data)?;
    if let Some(limit) = limit {
        eprintln!("render check: limit {limit} px of mismatch, learned on the validation frames");
    }
    evitrack::atomic::write(&args.out, estimator.to_json()?.as_bytes())
        .with_context(|| format!("writing {}", args.out.display()))?;
    let Some(estimator) = (estimator::underlying(estimator.as_ref()) as &dyn std::any::Any)
        .downcast_ref::<Evidential>()
    else {
        eprintln!(
            "trained `{}` on {} sample poses; model written to {}",
            estimator.method(),
            sample.poses.len(),
            args.out.display()
        );
        return Ok(ExitCode::SUCCESS);
    };
    let mut table = Table::new([
        "feature",
        "states",
        "asked",
        "log-likelihood",
        "BIC",
        "block sizes",
        "validation error",
        "notes",
    ]);
    let model = estimator.model();
    let validation_errors = model.validation_errors();
    for (i, summary) in model.frames().summary().into_iter().enumerate() {
        let mut notes = Vec::new();
        if !summary.removed_states.is_empty() {
            notes.push(format!("removed states {:?}", summary.removed_states));
        }
        if summary.imputed > 0 {
            notes.push(format!("{} missing values imputed", summary.imputed));
        }
        if summary.em_converged == Some(false) {
            notes.push(
                "EM stopped at its iteration cap before converging (raise \
                 model.hmm.max_iterations)"
                    .into(),
            );
        }
        table.push([
            summary.name.clone(),
            summary.states.to_string(),
            summary.requested_states.to_string(),
            format!("{:.3}", summary.log_likelihood),
            format!("{:.3}", summary.bic),
            format!("{:?}", summary.block_sizes),
            validation_errors.map_or("—".into(), |v| format!("{:.4}", v[i])),
            notes.join("; "),
        ]);
    }
    println!("{table}");
    let threshold = model.track_settings().conflict_threshold;
    eprintln!(
        "trained on {} sample poses; conflict threshold {}{}; model written to {}",
        sample.poses.len(),
        match threshold {
            ConflictLevel::Infinite => "inf".to_string(),
            ConflictLevel::Finite(k) => format!("{k:.4}"),
        },
        if model.threshold_learned() {
            " (learned)"
        } else {
            ""
        },
        args.out.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// A missing model file is named, with the new name when it is a run's old `model.json`.
fn check_model_path(path: &std::path::Path) -> Result<()> {
    if path.exists() {
        return Ok(());
    }
    let renamed = path.with_file_name(evitrack::report::model_file_name("evidential"));
    if path.file_name().is_some_and(|n| n == "model.json") && renamed.is_file() {
        bail!(
            "{} does not exist: runs and sweeps name the evidential model {} (model-<method>.json \
             for every method)",
            path.display(),
            renamed.display()
        );
    }
    bail!(
        "{} does not exist: give a model file written by `train`, `run` or `sweep`",
        path.display()
    )
}

pub fn track(args: &TrackArgs) -> Result<ExitCode> {
    ensure_output_writable(args.out.as_deref())?;
    check_model_path(&args.model)?;
    let loaded = estimator::load(&args.model)
        .with_context(|| format!("loading the model {}", args.model.display()))?;
    let estimator: Box<dyn PoseEstimator> = if args.track.given() {
        let evidential = (estimator::underlying(loaded.as_ref()) as &dyn std::any::Any)
            .downcast_ref::<Evidential>()
            .with_context(|| {
                format!(
                    "{} is a `{}` model: --constructor, --threshold, --selection and --estimator \
                 apply to evidential models only",
                    args.model.display(),
                    loaded.method()
                )
            })?;
        let settings = args.track.apply(evidential.model().track_settings())?;
        if (loaded.as_ref() as &dyn std::any::Any).is::<estimator::Calibrated>() {
            eprintln!(
                "note: the model's regions and abstentions were calibrated with its own tracker \
                 settings; with these they are left out"
            );
        }
        Box::new(evidential.with_track_settings(settings)?)
    } else {
        loaded
    };
    let config = estimator.feature_config().cloned().with_context(|| {
        format!(
            "{} records no feature configuration, so its features cannot be extracted here",
            args.model.display()
        )
    })?;
    let config = super::programs::for_model(
        config,
        super::programs::read_programs(&args.feature_program)?,
        &args.model.display().to_string(),
    )?;
    let set = config.check()?;
    let names = set.names();
    if names != estimator.feature_names() {
        bail!(
            "the model's features {:?} do not match its configuration's {names:?}: \
             the model file was edited or is corrupted",
            estimator.feature_names()
        );
    }
    let dataset = read_dataset(&args.dataset)?;
    check_polarity(&config, &dataset, &args.dataset.display().to_string())?;
    let what = args.dataset.display().to_string();
    let check = super::render_check::TrackCheck::new(
        estimator.as_ref(),
        &args.model,
        args.samples.as_deref(),
        &config,
        &dataset,
    )?;
    let rows = extract_with_progress(&set, &dataset, &what)?;
    let bar = progress_bar("track");
    bar.set_length(dataset.len() as u64);
    let label = args
        .dataset
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".into());
    let mut records = Vec::with_capacity(dataset.len());
    let mut motion = estimator.start_motion();
    for (i, (frame, row)) in dataset.frames.iter().zip(&rows).enumerate() {
        let mut estimate = motion.next(frame.t, row)?;
        if let Some(check) = &check {
            check.judge(&mut estimate, &frame.image);
        }
        let truth = frame.truth.map(|t| [t.x, t.y]);
        records.push(FrameRecord::new(
            estimator.method(),
            &label,
            i,
            frame.t,
            truth,
            &estimate,
            &names,
        ));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut csv = Vec::new();
    write_frames_csv(&mut csv, &records, &names)?;
    write_output(args.out.as_deref(), &csv)?;
    let errors: Vec<f64> = records.iter().filter_map(|r| r.error).collect();
    let flagged = records.iter().filter(|r| !r.flags.is_empty()).count();
    let without = records.iter().filter(|r| r.estimate.is_none()).count();
    match ErrorStats::from_errors(&errors) {
        Some(stats) => eprintln!(
            "{} frames: error mean {:.4} mm, median {:.4}, RMS {:.4}, max {:.4}; {} flagged, {} without estimate",
            dataset.len(), stats.mean, stats.median, stats.rms, stats.max, flagged, without
        ),
        None if records.iter().any(|r| r.truth.is_some()) => eprintln!(
            "{} frames tracked ({} flagged), none with an estimate, so no errors",
            dataset.len(), flagged
        ),
        None => eprintln!(
            "{} frames tracked ({} flagged, {} without estimate); no ground truth, so no errors",
            dataset.len(), flagged, without
        ),
    }
    Ok(ExitCode::SUCCESS)
}
