//! The scenario checks of the methods on the continuous feature maps, for their registry entries.

use super::MAX_CONTINUOUS_FEATURES;
use crate::track::SelectionPolicy;

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
    settings
        .temporal
        .check()
        .map_err(|e| format!("[temporal]: {e}"))?;
    if matches!(
        settings.continuous.selection,
        SelectionPolicy::Splitting { .. }
    ) {
        return Err(
            "[continuous]: the continuous tracker over time takes `selection` largest_subset \
             or lowest_conflict, not splitting: list the methods without \
             \"continuous_temporal\" in `estimators`"
                .into(),
        );
    }
    check_settings(settings, context)
}
