//! The scenario checks of the methods on the continuous feature maps, for their registry entries.

use super::MAX_CONTINUOUS_FEATURES;

/// The scenario checks of the continuous tracker (and of every method on its feature maps): the
/// `[continuous]` section, at most [`MAX_CONTINUOUS_FEATURES`] features, groups no larger than
/// the features.
pub(crate) fn check_settings(
    settings: &crate::estimator::EstimatorSettings,
    context: &crate::estimator::SettingsContext,
) -> Result<(), String> {
    let continuous = &settings.continuous;
    continuous
        .check()
        .map_err(|e| format!("[continuous]: {e}"))?;
    let n = context.feature_names.len();
    if n > MAX_CONTINUOUS_FEATURES {
        return Err(format!(
            "[features]: {n} features, but the continuous tracker takes at most \
             {MAX_CONTINUOUS_FEATURES}: use fewer size-function lines, or list the methods \
             without \"continuous\" and \"particle_filter\" in `estimators`"
        ));
    }
    let min_size = continuous.selection.min_size();
    if min_size > n {
        return Err(format!(
            "[continuous]: selection `min_size = {min_size}` is more than the {n} features: no \
             group could ever be chosen"
        ));
    }
    Ok(())
}

/// The scenario checks of the continuous tracker over time: the `[temporal]` section, no
/// splitting, and the continuous tracker's own.
pub(crate) fn check_temporal_settings(
    settings: &crate::estimator::EstimatorSettings,
    context: &crate::estimator::SettingsContext,
) -> Result<(), String> {
    if let Some(why) = super::temporal::too_many_features(context.feature_names.len()) {
        return Err(format!("[features]: {why}"));
    }
    crate::estimator::motion::check_temporal(
        &settings.temporal,
        Some((
            &settings.continuous.selection,
            "continuous",
            "the continuous tracker over time",
            super::ContinuousTemporal::METHOD,
        )),
    )?;
    check_settings(settings, context)
}
