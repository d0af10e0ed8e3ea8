//! What every EM run of a fit shares (argument checks, centred data, variance floor) and the
//! restarts' initialisations, also handed out by [`GaussianHmm::starts`].

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::em::Params;
use super::init::{init_kmeanspp, init_partition, init_quantile, init_random};
use super::{check_finite, count_distinct_up_to, GaussianHmm, HmmError, HmmSettings};

impl GaussianHmm {
    /// The starting models of [`GaussianHmm::fit`]'s EM runs with these arguments, in order,
    /// an identical start listed once (states ordered by mean): what lets another EM
    /// implementation start where this one does (`benches/peers`). Errors as `fit`'s.
    pub fn starts(
        observations: &[f64],
        n_states: usize,
        settings: &HmmSettings,
        seed: u64,
    ) -> Result<Vec<GaussianHmm>, HmmError> {
        let p = prepare(observations, n_states, settings)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut tried: Vec<Params> = Vec::with_capacity(settings.restarts);
        for restart in 0..settings.restarts {
            let init = start(restart, &p.centred, p.k, p.floor, &mut rng);
            if !tried.contains(&init) {
                tried.push(init);
            }
        }
        Ok(tried
            .into_iter()
            .map(|mut init| {
                for m in &mut init.means {
                    *m += p.mean;
                }
                init.into_sorted_hmm()
            })
            .collect())
    }
}

/// What every EM run of a fit shares: the data's mean, the variance floor, the state count
/// and the centred data.
pub(super) struct Prepared {
    pub(super) mean: f64,
    pub(super) floor: f64,
    pub(super) k: usize,
    pub(super) centred: Vec<f64>,
}

/// Checks the arguments of a fit and prepares its runs.
pub(super) fn prepare(
    observations: &[f64],
    n_states: usize,
    settings: &HmmSettings,
) -> Result<Prepared, HmmError> {
    settings.check()?;
    if n_states == 0 {
        return Err(HmmError::NoStates);
    }
    if observations.is_empty() {
        return Err(HmmError::Empty);
    }
    check_finite(observations)?;
    let n = observations.len();
    let mean = observations.iter().sum::<f64>() / n as f64;
    let var = observations
        .iter()
        .map(|y| (y - mean) * (y - mean))
        .sum::<f64>()
        / n as f64;
    if !(mean.is_finite() && var.is_finite()) {
        return Err(HmmError::DataRange);
    }
    let reference = if var > 0.0 {
        var
    } else {
        mean.abs().max(1.0).powi(2)
    };
    let floor = settings.variance_floor * reference;
    let k = n_states.min(count_distinct_up_to(observations, n_states));
    // EM runs on centred data: the second-moment variance update loses precision when the
    // mean is large against the spread.
    let centred: Vec<f64> = observations.iter().map(|y| y - mean).collect();
    Ok(Prepared {
        mean,
        floor,
        k,
        centred,
    })
}

/// The initialisation of restart `restart`: k-means++, partition, quantiles, random points, …
pub(super) fn start(
    restart: usize,
    centred: &[f64],
    k: usize,
    floor: f64,
    rng: &mut ChaCha8Rng,
) -> Params {
    match restart % 4 {
        0 => init_kmeanspp(centred, k, floor, rng),
        1 => init_partition(centred, k, floor),
        2 => init_quantile(centred, k, floor),
        _ => init_random(centred, k, floor, rng),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each start is where one of `fit`'s EM runs began: with one restart, the fit's first
    /// traced log-likelihood is the start's.
    #[test]
    fn starts_are_where_fit_begins() {
        let ys: Vec<f64> = (0..200)
            .map(|i| 5.0 + (i as f64 * 0.07).sin() + if i % 50 < 20 { 2.0 } else { 0.0 })
            .collect();
        let settings = HmmSettings::default();
        let starts = GaussianHmm::starts(&ys, 3, &settings, 4).unwrap();
        assert!(!starts.is_empty() && starts.len() <= settings.restarts);
        let one = HmmSettings {
            restarts: 1,
            ..settings.clone()
        };
        let fit = GaussianHmm::fit(&ys, 3, &one, 4).unwrap();
        let ll = starts[0].log_likelihood(&ys).unwrap();
        assert!(
            (fit.trace[0] - ll).abs() <= 1e-9 * ll.abs(),
            "{} {ll}",
            fit.trace[0]
        );
        assert!(GaussianHmm::starts(&[], 3, &settings, 4).is_err());
    }
}
