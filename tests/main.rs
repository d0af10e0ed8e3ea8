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
mod toy_method;
mod track;

/// Every variant of `scenarios/FILE`, run on two threads, with its name, in the file's order.
pub(crate) fn run_every_variant(file: &str) -> Vec<(String, evitrack::experiment::RunOutput)> {
    run_variants(file, None)
}

/// The variants of `scenarios/FILE` named in `only` (each name after the file's prefix; every
/// variant when `None`), run on two threads, with their names, in the file's order.
pub(crate) fn run_variants(
    file: &str,
    only: Option<&[&str]>,
) -> Vec<(String, evitrack::experiment::RunOutput)> {
    use evitrack::experiment::{run_all, Workbench};
    let path = format!("{}/scenarios/{file}", env!("CARGO_MANIFEST_DIR"));
    let set = evitrack::scenario::ScenarioSet::load(std::path::Path::new(&path))
        .unwrap_or_else(|e| panic!("scenarios/{file} is valid: {e}"));
    let prefix = format!("{}-", set.base.name());
    let chosen: Vec<_> = set
        .variants
        .iter()
        .filter(|v| {
            only.is_none_or(|names| {
                names.contains(&v.name().strip_prefix(&prefix).unwrap_or(v.name()))
            })
        })
        .cloned()
        .collect();
    if let Some(names) = only {
        assert_eq!(chosen.len(), names.len(), "{names:?} in scenarios/{file}");
    }
    run_all(&chosen, 2, &Workbench::new(), &|_, _, _, _| {})
        .into_iter()
        .zip(&chosen)
        .map(|(result, variant)| {
            let output = result.unwrap_or_else(|e| panic!("variant {} failed: {e}", variant.name));
            (variant.name.clone(), output)
        })
        .collect()
}
