//! Seed derivation: every random draw of a run comes from one master seed, split into named,
//! independent streams here and nowhere else, so that a scenario and its seed give identical
//! results whatever the order or the number of threads that use the streams.

/// A part of a scenario that is simulated on its own seed stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScenarioPart {
    /// The sample trajectory.
    Sample,
    /// The validation motion.
    Validation,
    /// The calibration motion (`[calibration]`).
    Calibration,
    /// The test motion of this index.
    Test(usize),
}

/// An independent seed for one named stream of a run.
pub fn derive(master: u64, stream: &str) -> u64 {
    // FNV-1a of the stream name, then a splitmix64 finaliser over the mix.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in stream.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    finalise((master ^ h).wrapping_add(0x9e37_79b9_7f4a_7c15))
}

/// The seed a run simulates `part` with; `simulate --scenario` uses it too, so both produce the
/// same dataset.
pub fn for_part(master: u64, part: ScenarioPart) -> u64 {
    match part {
        ScenarioPart::Sample => derive(master, "sample"),
        ScenarioPart::Validation => derive(master, "validation"),
        ScenarioPart::Calibration => derive(master, "calibration"),
        ScenarioPart::Test(k) => derive(master, &format!("test{k}")),
    }
}

/// The seed of the faults injected into test motion `test` (each fault draws its own stream
/// from it).
pub fn for_faults(master: u64, test: usize) -> u64 {
    derive(master, &format!("faults{test}"))
}

/// The seed of the `round`-th batch of adaptive samples (§3.1).
pub fn for_adaptive_round(master: u64, round: usize) -> u64 {
    derive(master, &format!("adaptive{round}"))
}

/// The training seed of a run: `stream` picks one of several training streams of the master seed.
pub fn for_training(master: u64, stream: u64) -> u64 {
    derive(master, &format!("model{stream}"))
}

/// The shape of a random validation path whose scenario does not pin its own seed.
pub fn for_validation_path(master: u64) -> u64 {
    derive(master, "validation-path")
}

/// One seed per (feature, state count) of a training seed, so that tuning and the given-count path
/// draw the same initialisations for the same count.
pub fn for_fit(training: u64, feature: usize, n_states: usize) -> u64 {
    finalise(
        training
            ^ (feature as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (n_states as u64).wrapping_mul(0xD1B5_4A32_D192_ED03),
    )
}

/// The splitmix64 finaliser.
fn finalise(x: u64) -> u64 {
    let mut z = x;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_differ_by_name_and_master_and_are_stable() {
        let a = for_part(1, ScenarioPart::Sample);
        assert_eq!(a, for_part(1, ScenarioPart::Sample));
        assert_ne!(a, for_part(2, ScenarioPart::Sample));
        assert_ne!(a, for_part(1, ScenarioPart::Validation));
        assert_ne!(
            for_part(1, ScenarioPart::Test(0)),
            for_part(1, ScenarioPart::Test(1))
        );
        assert_eq!(for_part(7, ScenarioPart::Test(3)), derive(7, "test3"));
        assert_ne!(for_validation_path(1), for_validation_path(2));
    }

    #[test]
    fn fit_seeds_differ_by_feature_and_count() {
        let a = for_fit(1, 0, 3);
        assert_ne!(a, for_fit(1, 1, 3));
        assert_ne!(a, for_fit(1, 0, 4));
        assert_ne!(a, for_fit(2, 0, 3));
        assert_eq!(a, for_fit(1, 0, 3));
    }
}
