//! Wall time of the whole paper table: simulate, train and track all five variants of
//! `scenarios/paper.toml` from scratch on two threads (target ≤ 20 s).

use criterion::{criterion_group, criterion_main, Criterion};
use evitrack::experiment::{run_all, Workbench};
use evitrack::scenario::ScenarioSet;

fn paper_sweep(c: &mut Criterion) {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenarios/paper.toml");
    let set = ScenarioSet::load(std::path::Path::new(path)).expect("paper.toml is valid");
    let mut group = c.benchmark_group("paper_table");
    group.sample_size(10);
    group.bench_function("all_variants_2_jobs", |b| {
        b.iter(|| {
            // A fresh workbench each time: nothing is memoised across iterations.
            let results = run_all(&set.variants, 2, &Workbench::new(), &|_, _, _, _| {});
            assert!(results.iter().all(Result::is_ok));
            results
        })
    });
    group.finish();
}

criterion_group!(benches, paper_sweep);
criterion_main!(benches);
