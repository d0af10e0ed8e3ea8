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
mod features;
mod front_door;
mod fuzz_corpus;
mod hmm;
mod information;
mod model;
mod pipeline;
mod reference;
mod reliability;
mod scheduler;
mod sim;
mod temporal;
mod toy_method;
mod track;

/// Every variant of `scenarios/FILE`, run on two threads, with its name, in the file's order.
pub(crate) fn run_every_variant(file: &str) -> Vec<(String, evitrack::experiment::RunOutput)> {
    use evitrack::experiment::{run_all, Workbench};
    let path = format!("{}/scenarios/{file}", env!("CARGO_MANIFEST_DIR"));
    let set = evitrack::scenario::ScenarioSet::load(std::path::Path::new(&path))
        .unwrap_or_else(|e| panic!("scenarios/{file} is valid: {e}"));
    run_all(&set.variants, 2, &Workbench::new(), &|_, _, _, _| {})
        .into_iter()
        .zip(&set.variants)
        .map(|(result, variant)| {
            let output = result.unwrap_or_else(|e| panic!("variant {} failed: {e}", variant.name));
            (variant.name.clone(), output)
        })
        .collect()
}
