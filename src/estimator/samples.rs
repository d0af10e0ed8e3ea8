//! The sample rows a method keeps and the checks of loaded samples, shared by the methods that
//! store their samples (k-NN, the GP, the continuous tracker).

use super::inputs::complete_samples;
use super::{EstimatorError, TrainingSet};
use crate::model_file::{self, check_finite};

/// A corrupted-file error, as the loaders of these methods return it.
fn corrupted(what: impl Into<String>) -> EstimatorError {
    model_file::corrupted(what).into()
}

/// Sample poses (mm) and their feature rows.
pub(super) type Samples = (Vec<[f64; 2]>, Vec<Vec<f64>>);

/// The sample rows a baseline keeps (every value present and finite) and their poses.
pub(super) fn kept_samples(data: &TrainingSet, method: &str) -> Result<Samples, EstimatorError> {
    let kept = complete_samples(data, method)?;
    let poses = kept.iter().map(|&i| data.sample.poses[i]).collect();
    let rows = kept
        .iter()
        .map(|&i| {
            data.sample.rows[i]
                .iter()
                .map(|v| v.unwrap_or(0.0))
                .collect()
        })
        .collect();
    Ok((poses, rows))
}

/// Checks loaded sample poses and feature rows: as many rows as poses (at least one), `dim`
/// values per row, everything finite.
pub(super) fn check_samples(
    poses: &[[f64; 2]],
    rows: &[Vec<f64>],
    dim: usize,
) -> Result<(), EstimatorError> {
    if poses.is_empty() {
        return Err(corrupted("`sample_poses` is empty"));
    }
    if rows.len() != poses.len() {
        return Err(corrupted(format!(
            "`sample_features` has {} rows for {} sample poses",
            rows.len(),
            poses.len()
        )));
    }
    for (i, p) in poses.iter().enumerate() {
        check_finite(&format!("sample_poses[{i}]"), p)?;
    }
    for (i, r) in rows.iter().enumerate() {
        if r.len() != dim {
            return Err(corrupted(format!(
                "`sample_features[{i}]` has {} values for {dim} features",
                r.len()
            )));
        }
        check_finite(&format!("sample_features[{i}]"), r)?;
    }
    Ok(())
}

/// The methods that factor an exact Gaussian-process kernel matrix on every sample pose: the GP
/// baseline, and the continuous tracker's feature maps (which the continuous temporal tracker and
/// the particle filter fit too).
pub(crate) const EXACT_GP_METHODS: [super::Method; 4] = [
    super::Method::GP,
    super::Method::CONTINUOUS,
    super::Method::CONTINUOUS_TEMPORAL,
    super::Method::PARTICLE_FILTER,
];

/// Refuses `samples` sample poses for `methods` when an exact Gaussian process would factor more
/// than [`MAX_EXACT_GP_SAMPLES`] of them: its n³/3 work (a 10,000-sample kernel ran past ten
/// minutes) is refused up front, naming the limit and the way out.
///
/// # Errors
/// A sentence naming the sample count, the limit, the methods concerned and what to change.
pub(crate) fn check_exact_gp_samples(
    methods: &[super::Method],
    samples: usize,
) -> Result<(), String> {
    let exact: Vec<&str> = (methods.iter())
        .filter(|m| EXACT_GP_METHODS.contains(m))
        .map(|m| m.name())
        .collect();
    if samples <= MAX_EXACT_GP_SAMPLES || exact.is_empty() {
        return Ok(());
    }
    let kept: Vec<&str> = (methods.iter())
        .filter(|m| !EXACT_GP_METHODS.contains(m))
        .map(|m| m.name())
        .collect();
    let ratio = (samples as f64 / MAX_EXACT_GP_SAMPLES as f64).powi(3);
    Err(format!(
        "{samples} sample poses are more than the {MAX_EXACT_GP_SAMPLES} the exact Gaussian \
         processes of {} factor (n³/3 work per kernel matrix: {ratio:.0}× the cost at the \
         limit); list the estimators without them (`estimators = {kept:?}`; the methods are \
         {}) or sample fewer poses (a coarser `sample.motion`, a larger `sample.keep_every`)",
        exact.join(", "),
        super::Method::names_sentence()
    ))
}

/// Most sample poses an exact Gaussian process factors (the GP baseline's kernel, each of the
/// continuous tracker's feature maps): at this size one factorisation takes a few seconds.
pub const MAX_EXACT_GP_SAMPLES: usize = 2_500;

/// The fit-time guard of [`MAX_EXACT_GP_SAMPLES`], for fits that no scenario checked (`train`
/// on a dataset folder).
pub(super) fn check_exact_gp_count(samples: usize, method: &str) -> Result<(), EstimatorError> {
    if samples > MAX_EXACT_GP_SAMPLES {
        return Err(EstimatorError::Training(format!(
            "{method}: {samples} complete samples are more than the {MAX_EXACT_GP_SAMPLES} an \
             exact Gaussian process factors (n³/3 work); train on fewer samples or another method"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::{Gp, GpSettings, Labelled, Method};

    #[test]
    fn a_gp_fit_beyond_the_limit_is_refused_before_any_work() {
        let n = MAX_EXACT_GP_SAMPLES + 1;
        let names = vec!["f".to_string()];
        let poses: Vec<[f64; 2]> = (0..n).map(|i| [0.0, 40.0 + i as f64 * 1e-3]).collect();
        let rows: Vec<Vec<Option<f64>>> = (0..n).map(|i| vec![Some(i as f64)]).collect();
        let data = TrainingSet::new(
            &names,
            Labelled {
                poses: &poses,
                rows: &rows,
            },
        );
        let started = std::time::Instant::now();
        let error = Gp::fit(&GpSettings::default(), &data)
            .unwrap_err()
            .to_string();
        assert!(
            started.elapsed().as_secs_f64() < 1.0,
            "{:?}",
            started.elapsed()
        );
        assert!(
            error.contains("2501 complete samples") && error.contains("2500"),
            "{error}"
        );
    }

    #[test]
    fn the_scenario_check_names_only_the_exact_gp_methods() {
        let methods = [Method::KNN, Method::GP, Method::PARTICLE_FILTER];
        assert!(check_exact_gp_samples(&methods, MAX_EXACT_GP_SAMPLES).is_ok());
        assert!(check_exact_gp_samples(&[Method::KNN], 1_000_000).is_ok());
        let error = check_exact_gp_samples(&methods, 10_000).unwrap_err();
        assert!(error.contains("of gp, particle_filter factor"), "{error}");
        assert!(error.contains("`estimators = [\"knn\"]`"), "{error}");
        assert!(error.contains("64× the cost"), "{error}");
    }
}
