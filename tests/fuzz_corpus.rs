//! The fuzz targets' bounded run: every stored input of `tests/fuzz/corpus/<target>/`, then
//! seeded mutations of each (byte flips, insertions of awkward tokens, cuts and repeats) through
//! the same checks the `cargo fuzz` targets run (`tests/fuzz/checks.rs`). Long, coverage-guided
//! runs: `cargo +nightly fuzz run --fuzz-dir tests/fuzz TARGET tests/fuzz/corpus/TARGET`.

#[path = "fuzz/checks.rs"]
mod checks;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Tokens that broke parsers before: huge, tiny, negative, non-finite, empty.
const TOKENS: [&str; 12] = [
    "1e308",
    "1e-310",
    "-1",
    "0",
    "NaN",
    "null",
    "[]",
    "{}",
    "\"inf\"",
    "18446744073709551615",
    "1e300",
    "\"",
];

fn corpus(target: &str) -> Vec<Vec<u8>> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz/corpus")
        .join(target);
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| entry.unwrap().path())
        .collect();
    paths.sort();
    paths.iter().map(|p| std::fs::read(p).unwrap()).collect()
}

fn mutate(input: &[u8], rng: &mut ChaCha8Rng) -> Vec<u8> {
    let mut out = input.to_vec();
    for _ in 0..rng.random_range(1..4) {
        let at = rng.random_range(0..=out.len());
        match rng.random_range(0..5) {
            0 if !out.is_empty() => {
                let i = at.min(out.len() - 1);
                out[i] ^= 1 << rng.random_range(0..8);
            }
            1 => {
                let token = TOKENS[rng.random_range(0..TOKENS.len())];
                out.splice(at..at, token.bytes());
            }
            2 => {
                let end = (at + rng.random_range(1..16)).min(out.len());
                out.drain(at..end);
            }
            3 => {
                let end = (at + rng.random_range(1..32)).min(out.len());
                let piece = out[at..end].to_vec();
                out.splice(at..at, piece);
            }
            _ => {
                // Replace a number with a token, where the text has one.
                let start = (at..out.len()).find(|&i| out[i].is_ascii_digit());
                if let Some(start) = start {
                    let end = (start..out.len())
                        .find(|&i| !(out[i].is_ascii_digit() || b".e-".contains(&out[i])))
                        .unwrap_or(out.len());
                    let token = TOKENS[rng.random_range(0..TOKENS.len())];
                    out.splice(start..end, token.bytes());
                }
            }
        }
    }
    out
}

/// The corpus and `mutations` mutants of each input through `check`; a panic names the input.
/// Returns how many inputs and mutants were accepted, for the test to show the checks reach past
/// the parser.
fn run(target: &str, check: fn(&[u8]) -> bool, mutations: usize) -> (usize, usize) {
    let inputs = corpus(target);
    assert!(!inputs.is_empty(), "no corpus for {target}");
    let mut rng = ChaCha8Rng::seed_from_u64(15);
    let (mut inputs_accepted, mut mutants_accepted) = (0, 0);
    for (k, input) in inputs.iter().enumerate() {
        inputs_accepted += usize::from(check(input));
        for m in 0..mutations {
            let mutant = mutate(input, &mut rng);
            match std::panic::catch_unwind(|| check(&mutant)) {
                Ok(accepted) => mutants_accepted += usize::from(accepted),
                Err(_) => panic!(
                    "{target}: input {k}, mutant {m} panicked: {:?}",
                    String::from_utf8_lossy(&mutant)
                ),
            }
        }
    }
    (inputs_accepted, mutants_accepted)
}

#[test]
fn combine_inputs_and_their_mutants() {
    let (inputs, mutants) = run("combine", checks::combine, 20_000);
    // Every stored input is valid; some mutants still are (a changed element or rule).
    assert_eq!(inputs, 7);
    assert!(mutants > 1000, "{mutants} mutants accepted");
}

#[test]
fn scenario_files_and_their_mutants() {
    let (inputs, mutants) = run("scenario", checks::scenario, 1000);
    // The two bombs are refused; the file with every section is read.
    assert_eq!(inputs, 3);
    assert!(mutants > 20, "{mutants} mutants accepted");
}

#[test]
fn model_files_and_their_mutants() {
    let (inputs, mutants) = run("model", checks::model, 1000);
    // Five older files and a run's file of every method (calibration included) load.
    assert_eq!(inputs, 13);
    assert!(mutants > 100, "{mutants} mutants accepted");
}

#[test]
fn datasets_and_their_mutants() {
    let (inputs, mutants) = run("dataset", checks::dataset, 1000);
    // The pose of 1e300 mm is refused.
    assert_eq!(inputs, 1);
    assert!(mutants > 10, "{mutants} mutants accepted");
}
