//! Integration tests: one binary, one module per room.

mod adaptive;
mod baselines;
mod cli;
mod confidence;
mod conformance;
mod continuous;
mod dataset;
mod evidence;
mod external_features;
mod faults;
mod feature_report;
mod features;
mod front_door;
mod fuzz_corpus;
mod hmm;
mod information;
mod memory;
mod model;
mod pipeline;
mod reference;
mod reliability;
mod rules;
mod scheduler;
mod sim;
mod temporal;
mod tiles;
mod time;
mod toy_method;
mod track;

/// One workbench for the whole test process. Datasets, feature rows and shared fits are pure
/// functions of their settings, so tests that run the same setup (paper.toml's (e) and
/// rules.toml's; faults.toml's and occlusion.toml's global features; best.toml's n24 and
/// rules.toml's) simulate, extract and fit it once, whichever test asks first.
pub(crate) fn bench() -> &'static evitrack::experiment::Workbench {
    static BENCH: std::sync::LazyLock<evitrack::experiment::Workbench> =
        std::sync::LazyLock::new(evitrack::experiment::Workbench::new);
    &BENCH
}

/// Every variant of `scenarios/FILE`, run on two threads, with its name, in the file's order.
pub(crate) fn run_every_variant(file: &str) -> Vec<(String, evitrack::experiment::RunOutput)> {
    run_variants_where(file, |_| true)
}

/// The variants of `scenarios/FILE` named in `only` (each name after the file's prefix; every
/// variant when `None`), run on two threads, with their names, in the file's order.
pub(crate) fn run_variants(
    file: &str,
    only: Option<&[&str]>,
) -> Vec<(String, evitrack::experiment::RunOutput)> {
    let runs = run_variants_where(file, |name| only.is_none_or(|names| names.contains(&name)));
    if let Some(names) = only {
        assert_eq!(runs.len(), names.len(), "{names:?} in scenarios/{file}");
    }
    runs
}

/// The variants of `scenarios/FILE` whose name after the file's prefix passes `keep`, run on
/// two threads with the process's [`bench`], with their names, in the file's order.
pub(crate) fn run_variants_where(
    file: &str,
    keep: impl Fn(&str) -> bool,
) -> Vec<(String, evitrack::experiment::RunOutput)> {
    use evitrack::experiment::run_all;
    let set = load_scenario(file);
    let prefix = format!("{}-", set.base.name());
    let chosen: Vec<_> = set
        .variants
        .iter()
        .filter(|v| keep(v.name().strip_prefix(&prefix).unwrap_or(v.name())))
        .cloned()
        .collect();
    assert!(!chosen.is_empty(), "no variant of scenarios/{file} chosen");
    run_all(&chosen, 2, bench(), &|_, _, _, _| {})
        .into_iter()
        .zip(&chosen)
        .map(|(result, variant)| {
            let output = result.unwrap_or_else(|e| panic!("variant {} failed: {e}", variant.name));
            (variant.name.clone(), output)
        })
        .collect()
}

/// `scenarios/FILE`, loaded and checked.
pub(crate) fn load_scenario(file: &str) -> evitrack::scenario::ScenarioSet {
    let path = format!("{}/scenarios/{file}", env!("CARGO_MANIFEST_DIR"));
    evitrack::scenario::ScenarioSet::load(std::path::Path::new(&path))
        .unwrap_or_else(|e| panic!("scenarios/{file} is valid: {e}"))
}
