//! `train`'s settings, built as a scenario's are: a scenario's sections, the options as
//! shorthands for scenario paths, `--set`, then the method's registry checks.

use anyhow::{bail, Context, Result};

use super::model::{
    paper_states, parse_counts, parse_selection, parse_threshold, ConstructorArg, ThresholdArg,
    TrainArgs,
};
use evitrack::estimator::{EstimatorSettings, SettingsContext};
use evitrack::evidence::Constructor;
use evitrack::model::{StateCounts, Tuning};
use evitrack::scenario::{Scenario, ScenarioSet};

/// A setting's value as TOML.
fn toml_of<T: serde::Serialize>(value: &T) -> Result<toml::Value> {
    toml::Value::try_from(value).context("a setting has no TOML form")
}

/// The settings `train` fits with, built as a scenario's are: the `--scenario` file's (or the
/// built-in scenario's) sections, the options and `--set` laid over them, then the method's
/// registry checks. Every option must name a section the method reads.
pub(super) fn train_settings(
    args: &TrainArgs,
    names: &[String],
    has_validation: bool,
) -> Result<EstimatorSettings> {
    let method = args.method;
    let reads = |section: &str| method.entry().sections.contains(&section);
    let base = match &args.scenario {
        Some(path) => {
            // As written (random paths' seeds not yet derived: they need not fit TOML's i64).
            let set = ScenarioSet::load(path)?;
            let first = set
                .variants
                .first()
                .with_context(|| format!("{} has no scenario", path.display()))?;
            toml::from_str::<Scenario>(&first.to_toml()?)
                .with_context(|| format!("reading back the settings of {}", path.display()))?
        }
        None => Scenario {
            name: "train".into(),
            ..Scenario::default()
        },
    };
    let mut values: Vec<(String, toml::Value)> = Vec::new();
    let mut put = |option: &str, path: &str, value: toml::Value| -> Result<()> {
        // A section may be dotted (`methods.NAME` of a registered method); the evidential
        // threshold learning is spelled at the top level but belongs with `[track]`.
        let in_section = |s: &&str| path == *s || path.starts_with(&format!("{s}."));
        // Every method is calibrated by `[confidence]` (the centre has nothing to calibrate).
        let known = match path {
            "learn_threshold" | "threshold_rule" => reads("track"),
            _ if in_section(&"confidence") => !method.entry().sections.is_empty(),
            _ => method.entry().sections.iter().any(in_section),
        };
        if !known {
            bail!(
                "{option} sets `{path}`, which `{method}` does not read (it reads {}): leave it \
                 out or pick a method that has it",
                match method.entry().sections {
                    [] => "no settings".to_string(),
                    sections => sections
                        .iter()
                        .map(|s| format!("[{s}]"))
                        .collect::<Vec<_>>()
                        .join(", "),
                }
            );
        }
        values.push((path.to_string(), value));
        Ok(())
    };
    if args.scenario.is_none() && reads("model") && args.states.is_none() {
        let states: Vec<usize> = names
            .iter()
            .map(|n| paper_states(n))
            .collect::<Result<_>>()?;
        put(
            "the paper's state counts",
            "model.states",
            toml_of(&StateCounts::PerFeature(states))?,
        )?;
    }
    if reads("model") {
        put("--seed", "model.seed", toml_of(&args.seed)?)?;
    }
    if let Some(text) = &args.states {
        put(
            "--states",
            "model.states",
            toml_of(&parse_counts(text, "--states")?)?,
        )?;
    }
    if let Some(bounds) = &args.tune_bic {
        let (low, high) = bounds
            .split_once("..")
            .with_context(|| format!("--tune-bic `{bounds}` must look like `2..5`"))?;
        let tuning = Tuning::Bic {
            min_states: parse_counts(low, "--tune-bic lower bound")?,
            max_states: parse_counts(high, "--tune-bic upper bound")?,
        };
        put("--tune-bic", "model.tuning", toml_of(&tuning)?)?;
    }
    if let Some(k) = args.k {
        put("--k", "knn.k", toml_of(&k)?)?;
    }
    if let Some(weights) = args.weights {
        put("--weights", "knn.weights", toml_of(&weights)?)?;
    }
    let track = &args.track;
    if let Some(c) = track.constructor {
        let constructor = match c {
            ConstructorArg::Bayesian => Constructor::Bayesian,
            ConstructorArg::Consonant => Constructor::Consonant,
        };
        put("--constructor", "track.constructor", toml_of(&constructor)?)?;
    }
    if let Some(e) = track.estimator {
        put("--estimator", "track.estimator", toml_of(&e.rule())?)?;
    }
    // The conflict threshold and the selection live in [track] for the trackers on HMM
    // frames and in [continuous] for those on feature maps: one option for both.
    let (threshold, learn, rule, selection) = if reads("track") {
        (
            "track.conflict_threshold",
            "learn_threshold",
            "threshold_rule",
            "track.selection",
        )
    } else {
        (
            "continuous.conflict_threshold",
            "continuous.learn_threshold",
            "continuous.threshold_rule",
            "continuous.selection",
        )
    };
    if let Some(text) = &track.selection {
        put("--selection", selection, toml_of(&parse_selection(text)?)?)?;
    }
    match track
        .threshold
        .as_deref()
        .map(parse_threshold)
        .transpose()?
    {
        Some(ThresholdArg::Fixed(level)) => {
            put("--threshold", threshold, toml_of(&level)?)?;
            put("--threshold", learn, toml::Value::Boolean(false))?;
        }
        Some(ThresholdArg::Learned(chosen)) => {
            put("--threshold", learn, toml::Value::Boolean(true))?;
            if let Some(r) = chosen {
                put("--threshold", rule, toml_of(&r)?)?;
            }
        }
        // Without a scenario, a validation dataset teaches the evidential trackers their
        // threshold, as `train` always did.
        None if args.scenario.is_none() && has_validation && reads("track") => {
            put("--validation", learn, toml::Value::Boolean(true))?;
        }
        None => {}
    }
    for (path, value) in &args.set {
        put("--set", path, value.clone())?;
    }
    let scenario = Scenario {
        estimators: vec![method],
        ..base.with_values(&values)?
    };
    Ok(scenario.check_estimators(&SettingsContext {
        feature_names: names.to_vec(),
        has_validation,
    })?)
}
