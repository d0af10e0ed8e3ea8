//! Commands on models: `train` and `track`, through the estimator seam.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::Args;

use super::{
    check_polarity, ensure_output_writable, extract_with_progress, feature_config_for,
    progress_bar, read_dataset, spinner, write_output,
};
use evitrack::estimator::{
    self, ContinuousSettings, DatasetFeatures, EstimatorSettings, Evidential, EvidentialSettings,
    KnnSettings, KnnWeights, Method, PoseEstimator, TrainingSet,
};
use evitrack::evidence::{ConflictLevel, Constructor};
use evitrack::model::{ModelSettings, Provenance, StateCounts, Tuning};
use evitrack::report::{write_frames_csv, ErrorStats, FrameRecord, Table};
use evitrack::track::{PoseRule, SelectionPolicy, ThresholdRule, TrackSettings};

/// Tracker settings given on the command line; what is left out keeps its value.
#[derive(Debug, Args)]
struct TrackOptions {
    /// Belief-function constructor [default at training: bayesian].
    #[arg(long, value_enum)]
    constructor: Option<ConstructorArg>,
    /// Conflict threshold: a number ≥ 0 or `inf` (combine everything) [default at training:
    /// inf, or learned with --validation; at tracking: the model's].
    #[arg(long)]
    threshold: Option<String>,
    /// Which compatible group to combine: `largest`, `lowest:N` (lowest conflict among groups of
    /// at least N features) or `split:N` (every group of at least N; the first is reported)
    /// [default at training: largest].
    #[arg(long)]
    selection: Option<String>,
    /// Pointwise estimate from the combined belief function [default at training:
    /// weighted-mean].
    #[arg(long, value_enum)]
    estimator: Option<EstimatorArg>,
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
            settings.estimator = match e {
                EstimatorArg::WeightedMean => PoseRule::WeightedMean,
                EstimatorArg::Map => PoseRule::Map,
                EstimatorArg::Pignistic => PoseRule::Pignistic,
            };
        }
        if let Some(text) = &self.threshold {
            settings.conflict_threshold = parse_threshold(text)?;
        }
        Ok(settings)
    }
}

/// `--threshold`: a number ≥ 0 or `inf`.
fn parse_threshold(text: &str) -> Result<ConflictLevel> {
    Ok(match text {
        "inf" => ConflictLevel::Infinite,
        text => text
            .parse::<f64>()
            .ok()
            .filter(|t| t.is_finite() && *t >= 0.0)
            .map(ConflictLevel::Finite)
            .with_context(|| format!("--threshold `{text}` must be a number ≥ 0 or `inf`"))?,
    })
}

/// Arguments of `train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Dataset folder of the sample trajectory (it must have ground-truth poses).
    dataset: PathBuf,
    /// Output model file (JSON): self-contained, `track --model` needs nothing else.
    #[arg(long)]
    out: PathBuf,
    /// A dataset of a validation motion (with ground truth): measures each feature's own error
    /// (the fallback's ranking) and learns the conflict threshold on it (§4.3).
    #[arg(long)]
    validation: Option<PathBuf>,
    /// With --validation, keep the --threshold given instead of learning it.
    #[arg(long, requires = "validation")]
    keep_threshold: bool,
    /// With --validation, learn the threshold as this quantile of the validation motion's levels
    /// of conflict (e.g. 0.99) instead of the paper's error-weighted mean.
    #[arg(long, requires = "validation", conflicts_with = "keep_threshold")]
    threshold_quantile: Option<f64>,
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
    /// The estimation method. --states, --tune-bic, --keep-threshold and the tracker options
    /// are the evidential tracker's (the continuous one takes --threshold, --selection and
    /// --threshold-quantile); --k and --weights are k-NN's.
    #[arg(long, value_enum, default_value = "evidential")]
    method: MethodArg,
    /// k-NN: the number of neighbours.
    #[arg(long, default_value_t = KnnSettings::default().k)]
    k: usize,
    /// k-NN: how the neighbours' poses are weighted.
    #[arg(long, value_enum, default_value = "distance")]
    weights: WeightsArg,
    #[command(flatten)]
    track: TrackOptions,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum MethodArg {
    /// The paper's evidential tracker.
    Evidential,
    /// k-nearest neighbours on standardised features.
    Knn,
    /// Gaussian-process regression (ARD kernel, marginal-likelihood hyperparameters).
    Gp,
    /// The workspace centre: the error of knowing nothing.
    Centre,
    /// The continuous evidential tracker (feature maps learned as smooth functions of the pose).
    Continuous,
}

impl MethodArg {
    fn method(self) -> Method {
        match self {
            MethodArg::Evidential => Method::Evidential,
            MethodArg::Knn => Method::Knn,
            MethodArg::Gp => Method::Gp,
            MethodArg::Centre => Method::Centre,
            MethodArg::Continuous => Method::Continuous,
        }
    }
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum WeightsArg {
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
    /// Model file written by `train`, `run` or `sweep` (`<out>/<scenario>/model.json`).
    #[arg(long)]
    model: PathBuf,
    /// Output CSV of per-frame estimates (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Options given here replace the model's tracker settings.
    #[command(flatten)]
    track: TrackOptions,
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

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum ConstructorArg {
    Bayesian,
    Consonant,
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

pub fn train(args: &TrainArgs) -> Result<ExitCode> {
    ensure_output_writable(Some(&args.out))?;
    let dataset = read_dataset(&args.dataset)?;
    let what = args.dataset.display().to_string();
    let config = feature_config_for(args.config.as_deref(), args.barycentre, &dataset, &what)?;
    let set = config.check()?;
    let names = set.names();
    let sample = DatasetFeatures {
        poses: dataset.truth_positions().with_context(|| {
            format!("{what} has frames without ground-truth poses: training needs the pose of every sample")
        })?,
        rows: extract_with_progress(&set, &dataset),
    };
    let validation = match &args.validation {
        Some(path) => {
            let data = read_dataset(path)?;
            check_polarity(&config, &data, &path.display().to_string())?;
            let times: Vec<f64> = data.frames.iter().map(|f| f.t).collect();
            Some((
                DatasetFeatures {
                    poses: data.truth_positions().with_context(|| {
                        format!(
                            "{} has frames without ground-truth poses: validation needs them",
                            path.display()
                        )
                    })?,
                    rows: extract_with_progress(&set, &data),
                },
                times,
            ))
        }
        None => None,
    };
    let training = TrainingSet {
        feature_names: &names,
        feature_config: Some(&config),
        sample: sample.labelled(),
        validation: validation.as_ref().map(|(v, _)| v.labelled()),
        validation_times: validation.as_ref().map(|(_, t)| t.as_slice()),
        missing_penalty: dataset.workspace_diagonal(),
        provenance: Provenance::new(None, args.seed).with_workspace(dataset.manifest.workspace),
    };
    if args.method != MethodArg::Evidential {
        let continuous = args.method == MethodArg::Continuous;
        let track = &args.track;
        if args.states.is_some()
            || args.tune_bic.is_some()
            || args.keep_threshold
            || track.constructor.is_some()
            || track.estimator.is_some()
        {
            bail!(
                "--states, --tune-bic, --keep-threshold, --constructor and --estimator apply to \
                 --method evidential only"
            );
        }
        if !continuous && (args.threshold_quantile.is_some() || track.given()) {
            bail!(
                "--threshold-quantile and the tracker options apply to --method evidential and \
                 continuous only"
            );
        }
        let mut continuous_settings = ContinuousSettings::default();
        if let Some(text) = &track.selection {
            continuous_settings.selection = parse_selection(text)?;
        }
        if let Some(text) = &track.threshold {
            continuous_settings.conflict_threshold = parse_threshold(text)?;
        }
        if let Some(q) = args.threshold_quantile {
            continuous_settings.learn_threshold = true;
            continuous_settings.threshold_rule = ThresholdRule::Quantile(q);
        }
        let settings = EstimatorSettings {
            continuous: continuous_settings,
            knn: KnnSettings {
                k: args.k,
                weights: match args.weights {
                    WeightsArg::Uniform => KnnWeights::Uniform,
                    WeightsArg::Distance => KnnWeights::Distance,
                },
            },
            ..EstimatorSettings::default()
        };
        let method = args.method.method();
        let bar = spinner(&format!("fit {method}"));
        let estimator = method.fit(&settings, &training);
        bar.finish_and_clear();
        let estimator = estimator?;
        evitrack::atomic::write(&args.out, estimator.to_json()?.as_bytes())
            .with_context(|| format!("writing {}", args.out.display()))?;
        eprintln!(
            "trained `{}` on {} sample poses; model written to {}",
            estimator.method(),
            sample.poses.len(),
            args.out.display()
        );
        return Ok(ExitCode::SUCCESS);
    }
    let states = match &args.states {
        Some(text) => parse_counts(text, "--states")?,
        None => StateCounts::PerFeature(
            names
                .iter()
                .map(|name| paper_states(name))
                .collect::<Result<_>>()?,
        ),
    };
    let mut model = ModelSettings {
        states,
        seed: args.seed,
        ..ModelSettings::default()
    };
    if let Some(bounds) = &args.tune_bic {
        let (low, high) = bounds
            .split_once("..")
            .with_context(|| format!("--tune-bic `{bounds}` must look like `2..5`"))?;
        model.tuning = Tuning::Bic {
            min_states: parse_counts(low, "--tune-bic lower bound")?,
            max_states: parse_counts(high, "--tune-bic upper bound")?,
        };
    }
    let settings = EvidentialSettings {
        model,
        track: args.track.apply(&TrackSettings::default())?,
        learn_threshold: validation.is_some() && !args.keep_threshold,
        threshold_rule: args
            .threshold_quantile
            .map_or(ThresholdRule::ErrorWeighted, ThresholdRule::Quantile),
    };
    let bar = spinner("fit evidential");
    let estimator = Evidential::fit(&settings, &training);
    bar.finish_and_clear();
    let estimator = estimator?;
    evitrack::atomic::write(&args.out, estimator.to_json()?.as_bytes())
        .with_context(|| format!("writing {}", args.out.display()))?;
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

pub fn track(args: &TrackArgs) -> Result<ExitCode> {
    ensure_output_writable(args.out.as_deref())?;
    let loaded = estimator::load(&args.model)
        .with_context(|| format!("loading the model {}", args.model.display()))?;
    let estimator: Box<dyn PoseEstimator> = if args.track.given() {
        let evidential = loaded.as_evidential().with_context(|| {
            format!(
                "{} is a `{}` model: --constructor, --threshold, --selection and --estimator \
                 apply to evidential models only",
                args.model.display(),
                loaded.method()
            )
        })?;
        let settings = args.track.apply(evidential.model().track_settings())?;
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
    let bar = progress_bar("track");
    bar.set_length(dataset.len() as u64);
    let label = args
        .dataset
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".into());
    let mut records = Vec::with_capacity(dataset.len());
    let mut motion = estimator.start_motion();
    for (i, frame) in dataset.frames.iter().enumerate() {
        let estimate = motion.next(frame.t, &set.extract(&frame.image))?;
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
