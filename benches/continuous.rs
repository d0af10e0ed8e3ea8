//! The continuous evidential tracker, one frame with the features given: 8 synthetic smooth
//! features of the pose (`estimator::test_maps`), 400 sample poses (the 1 mm mesh), a validation
//! path of 100 poses. `clean`: a frame at a random pose with the samples' noise, every feature
//! combined. `faulty`: two features stuck far from their value and a learned threshold, so the
//! groups below the full one are searched (largest subset). Target (clean): median ≤ 100 µs.
//! `clean`/`stuck` at 64 features: the same maps, learned threshold; `stuck` has 4 features
//! stuck 0.6 off (inside their ranges, so only the group levels exclude them). Target (64
//! features, 4 stuck): median ≤ 10 ms.
//! `rule/…`: one frame per fusion rule (issue 30), 8 features, every usable feature combined
//! (`combine = "all"`), two stuck as in `faulty`: Dempster's, discounted by 0.9, learned, and the
//! cautious rule.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::estimator::test_maps::{
    feature_row, fitted_continuous, workspace_mesh, workspace_points,
};
use evitrack::estimator::{Continuous, ContinuousSettings, Labelled, PoseEstimator, TrainingSet};
use evitrack::evidence::Rule;
use evitrack::track::{Combine, Discount};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

const NOISE: f64 = 0.002;

fn fitted(features: usize, per_side: usize, learn: bool) -> Continuous {
    fitted_continuous(features, per_side, 100, NOISE, learn, 1)
}

/// A bench case: name, features, and (feature, offset) of its faulty values.
type Case<'a> = (&'a str, usize, &'a [(usize, f64)]);

/// 32 frames; `offsets`: (feature, what is added to its value).
fn frames(features: usize, offsets: &[(usize, f64)]) -> Vec<Vec<Option<f64>>> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    (workspace_points(32, &mut rng).iter())
        .map(|&q| {
            let mut row = feature_row(features, q, NOISE, &mut rng);
            for &(i, offset) in offsets {
                row[i] = row[i].map(|v| v + offset);
            }
            row
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("continuous");
    let two = [(1, 0.8), (6, -0.8)];
    let four = [(3, 0.6), (20, 0.6), (41, -0.6), (60, 0.6)];
    let cases: [Case; 4] = [
        ("clean", 8, &[]),
        ("faulty", 8, &two),
        ("clean", 64, &[]),
        ("stuck", 64, &four),
    ];
    for (name, features, offsets) in cases {
        let model = fitted(features, 20, features == 64 || !offsets.is_empty());
        let rows = frames(features, offsets);
        let mut k = 0;
        group.bench_function(BenchmarkId::new(name, format!("400x{features}")), |b| {
            b.iter(|| {
                k = (k + 1) % rows.len();
                black_box(model.estimate(black_box(&rows[k])).expect("estimates"))
            })
        });
    }
    for (name, rule, discount) in [
        ("dempster", Rule::Dempster, Discount::None),
        ("dempster-0.9", Rule::Dempster, Discount::Fixed(0.9)),
        ("dempster-learned", Rule::Dempster, Discount::Learned),
        ("cautious", Rule::Cautious, Discount::None),
    ] {
        let model = with_rule(rule, discount);
        let rows = frames(8, &two);
        let mut k = 0;
        group.bench_function(BenchmarkId::new("rule", name), |b| {
            b.iter(|| {
                k = (k + 1) % rows.len();
                black_box(model.estimate(black_box(&rows[k])).expect("estimates"))
            })
        });
    }
    group.finish();
}

/// The 8 test maps on the 1 mm mesh with 100 validation poses, every feature combined by `rule`.
fn with_rule(rule: Rule, discount: Discount) -> Continuous {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let poses = workspace_mesh(20);
    let rows: Vec<_> = (poses.iter())
        .map(|&q| feature_row(8, q, NOISE, &mut rng))
        .collect();
    let valid_poses = workspace_points(100, &mut rng);
    let valid_rows: Vec<_> = (valid_poses.iter())
        .map(|&q| feature_row(8, q, NOISE, &mut rng))
        .collect();
    let names: Vec<String> = (0..8).map(|i| format!("f{i}")).collect();
    let mut data = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows: &rows,
        },
    );
    data.validation = Some(Labelled {
        poses: &valid_poses,
        rows: &valid_rows,
    });
    let settings = ContinuousSettings {
        combine: Combine::All,
        rule,
        discount,
        ..ContinuousSettings::default()
    };
    Continuous::fit(&settings, &data).expect("the test maps fit")
}

criterion_group!(benches, bench);
criterion_main!(benches);
