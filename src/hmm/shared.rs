//! Fits kept for the next training that asks for the same one (issue 32): a run's evidential and
//! evidential_temporal trackers train the same HMMs on the same sample, and a sweep's variants
//! that differ only in how they track (fusion rules, thresholds) train them again. A fit is a
//! pure function of its observations, state count, settings and seed, so it is kept under a key
//! of all of them bit for bit; results do not depend on which caller asked first.
//!
//! Kept strongly (a trained model holds its own copy, not the fit), up to [`CAPACITY_BYTES`]
//! of keys and fits in the process; past that the store is emptied and fills again.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use super::{GaussianHmm, HmmError, HmmFit, HmmSettings};

/// Bytes of keys and fits kept at most (an entry of 10,000 samples is counted as ~165 kB, its
/// key's 80 kB of observations and the fit's count below).
const CAPACITY_BYTES: usize = 32 << 20;

/// A fit being made or made; `None` when it failed (each caller then fits for its own error).
type Slot = Arc<OnceLock<Option<HmmFit>>>;

#[derive(Default)]
struct Store {
    slots: HashMap<Vec<u8>, Slot>,
    bytes: usize,
}

fn store() -> &'static Mutex<Store> {
    static STORE: OnceLock<Mutex<Store>> = OnceLock::new();
    STORE.get_or_init(Mutex::default)
}

impl GaussianHmm {
    /// [`GaussianHmm::fit`], taken from the fits kept in this process when the same one was
    /// made before (the same bits: see the module's notes).
    ///
    /// # Errors
    /// As [`GaussianHmm::fit`].
    pub fn fit_shared(
        observations: &[f64],
        n_states: usize,
        settings: &HmmSettings,
        seed: u64,
    ) -> Result<HmmFit, HmmError> {
        let fit = || Self::fit(observations, n_states, settings, seed);
        let Some(key) = key(observations, n_states, settings, seed) else {
            return fit();
        };
        let slot = slot(store(), key, CAPACITY_BYTES, n_states, observations.len());
        let mut failure = None;
        let kept = slot.get_or_init(|| match fit() {
            Ok(made) => Some(made),
            Err(error) => {
                failure = Some(error);
                None
            }
        });
        match (failure, kept) {
            (Some(error), _) => Err(error),
            (None, Some(made)) => Ok(made.clone()),
            (None, None) => fit(),
        }
    }
}

/// Everything a fit depends on, as bytes; `None` if the settings do not serialise.
fn key(
    observations: &[f64],
    n_states: usize,
    settings: &HmmSettings,
    seed: u64,
) -> Option<Vec<u8>> {
    let mut key = serde_json::to_vec(settings).ok()?;
    key.extend(seed.to_le_bytes());
    key.extend((n_states as u64).to_le_bytes());
    key.extend(observations.iter().flat_map(|v| v.to_bits().to_le_bytes()));
    Some(key)
}

/// The slot of `key` in `store`, new if absent; the store is emptied first when the new entry
/// would take it past `capacity` bytes (a fit of `n_states` on `samples` counted generously).
fn slot(
    store: &Mutex<Store>,
    key: Vec<u8>,
    capacity: usize,
    n_states: usize,
    samples: usize,
) -> Slot {
    // A poisoned lock only means another thread panicked while inserting; the map is intact.
    let mut store = store.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(slot) = store.slots.get(&key) {
        return slot.clone();
    }
    // Key, the model (means, variances, initial and transition probabilities) and EM's trace
    // (at most one value per iteration; counted as one per sample, which bounds it in practice).
    let cost = key.len() + 8 * (n_states * (n_states + 3) + samples) + 256;
    if store.bytes + cost > capacity {
        store.slots.clear();
        store.bytes = 0;
    }
    store.bytes += cost;
    store.slots.entry(key).or_default().clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn observations(offset: f64) -> Vec<f64> {
        (0..120)
            .map(|i| offset + (i as f64 * 0.37).sin() + if i % 3 == 0 { 2.0 } else { 0.0 })
            .collect()
    }

    #[test]
    fn a_kept_fit_is_the_fit_and_is_made_once() {
        let settings = HmmSettings::default();
        // An offset no other test uses, so this key is this test's own.
        let ys = observations(7123.25);
        let direct = GaussianHmm::fit(&ys, 3, &settings, 11).unwrap();
        let first = GaussianHmm::fit_shared(&ys, 3, &settings, 11).unwrap();
        assert_eq!(first, direct);
        assert_eq!(
            first.log_likelihood.to_bits(),
            direct.log_likelihood.to_bits()
        );
        let key = key(&ys, 3, &settings, 11).unwrap();
        let kept = store().lock().unwrap().slots.get(&key).cloned();
        assert!(
            kept.as_ref().and_then(|s| s.get()).is_some(),
            "kept after the first call"
        );
        // A second call is served from the slot: it returns the kept fit, and nothing is added.
        let again = GaussianHmm::fit_shared(&ys, 3, &settings, 11).unwrap();
        assert_eq!(again, direct);
        let after = store().lock().unwrap().slots.get(&key).cloned();
        assert!(Arc::ptr_eq(&kept.unwrap(), &after.unwrap()));
        // Another seed, state count or setting is another fit.
        let other = HmmSettings {
            restarts: 3,
            ..settings.clone()
        };
        for (n, s, seed) in [(3, &settings, 12), (2, &settings, 11), (3, &other, 11)] {
            assert_ne!(key, super::key(&ys, n, s, seed).unwrap());
            assert_eq!(
                GaussianHmm::fit_shared(&ys, n, s, seed).unwrap(),
                GaussianHmm::fit(&ys, n, s, seed).unwrap()
            );
        }
    }

    #[test]
    fn errors_are_not_kept_and_the_store_stays_under_its_capacity() {
        let settings = HmmSettings::default();
        let bad = [1.0, 2.0, 3.0];
        for _ in 0..2 {
            let shared = GaussianHmm::fit_shared(&bad, 0, &settings, 1).unwrap_err();
            assert_eq!(shared, GaussianHmm::fit(&bad, 0, &settings, 1).unwrap_err());
        }
        let key = key(&bad, 0, &settings, 1).unwrap();
        let failed = store().lock().unwrap().slots.get(&key).cloned();
        assert!(matches!(failed.as_ref().and_then(|s| s.get()), Some(None)));
        // A store of its own with room for two small entries (516 bytes each): the third empties it first.
        let own = Mutex::new(Store::default());
        let entry = |tag: u8| slot(&own, vec![tag; 100], 1_100, 2, 10);
        entry(1);
        entry(2);
        assert_eq!(own.lock().unwrap().slots.len(), 2);
        entry(3);
        let held = own.lock().unwrap();
        assert_eq!(held.slots.len(), 1);
        assert!(held.bytes <= 1_100);
    }
}
