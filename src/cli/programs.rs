//! `--feature-program FILE.toml` of `features`, `train` and `track`: one external feature
//! program per file, with the keys of a scenario's `[[features.external]]`.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};

use evitrack::features::{ExternalFeatureConfig, FeatureConfig};

/// The programs of the files, in order.
pub(crate) fn read_programs(paths: &[PathBuf]) -> Result<Vec<ExternalFeatureConfig>> {
    paths
        .iter()
        .map(|path| {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            toml::from_str(&text).with_context(|| {
                format!(
                    "{} is not a feature program: give `command` and `values` (and optionally \
                     `missing`, `timeout_seconds`)",
                    path.display()
                )
            })
        })
        .collect()
}

/// `config` (a model's) with its external programs replaced by the ones given, which must give
/// the same values. A model file runs no program by itself: its programs are given again.
pub(crate) fn for_model(
    mut config: FeatureConfig,
    given: Vec<ExternalFeatureConfig>,
    model: &str,
) -> Result<FeatureConfig> {
    let values = |programs: &[ExternalFeatureConfig]| -> Vec<String> {
        programs.iter().flat_map(|p| p.values.clone()).collect()
    };
    let (wanted, got) = (values(&config.external), values(&given));
    if let (Some(first), true) = (config.external.first(), given.is_empty()) {
        bail!(
            "{model} reads the values {wanted:?} from feature programs (the first `{}`): a model \
             file runs no program by itself, so pass each with --feature-program FILE.toml",
            first.label()
        );
    }
    if wanted != got {
        bail!(
            "{model} reads the values {wanted:?} from feature programs, but the programs given \
             with --feature-program write {got:?}: give the programs it was trained with"
        );
    }
    config.external = given;
    Ok(config)
}
