//! Features of one 170 × 120 frame: a rig-like synthetic frame (end-effector disc plus the two
//! distal links reaching the image border, noise σ = 2). Target: all 8 features ≤ 200 µs median.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use evitrack::features::synthetic::rig_like_frame;
use evitrack::features::{
    extract_silhouette, FeatureConfig, MeanMethod, Polarity, SilhouetteConfig, TileConfig,
};
use std::hint::black_box;

fn features(c: &mut Criterion) {
    let frame = rig_like_frame([2.3, 44.1], 2.0, 42).expect("a reachable pose");
    let mut group = c.benchmark_group("features");
    let eight = FeatureConfig::with_barycentre()
        .check()
        .expect("valid preset");
    group.bench_function("all_8_closed_form", |b| {
        b.iter(|| eight.extract(black_box(&frame)))
    });
    let six = FeatureConfig::default().check().expect("valid default");
    group.bench_function("size_functions_6", |b| {
        b.iter(|| six.extract(black_box(&frame)))
    });
    let cfg = SilhouetteConfig::default();
    group.bench_function("silhouette_only", |b| {
        b.iter(|| extract_silhouette(black_box(&frame), Polarity::BrightOnDark, &cfg))
    });
    group.bench_function("barycentre_only", |b| {
        b.iter(|| {
            evitrack::features::barycentre(
                black_box(&frame),
                Polarity::BrightOnDark,
                evitrack::features::Background::MedianPlusNoise,
            )
        })
    });
    // The local family alone, as in scenarios/occlusion.toml, and at the trackers' 64.
    for (columns, rows) in [(4usize, 4usize), (8, 8)] {
        let mut config = FeatureConfig::default();
        config.size_functions.enabled = false;
        config.tiles = TileConfig {
            enabled: true,
            columns,
            rows,
            ..TileConfig::default()
        };
        let set = config.check().expect("valid tiles");
        let id = BenchmarkId::new("tiles", format!("{columns}x{rows}"));
        group.bench_with_input(id, &set, |b, set| b.iter(|| set.extract(black_box(&frame))));
    }
    for grid in [16usize, 64] {
        let mut table = FeatureConfig::with_barycentre();
        table.size_functions.mean = MeanMethod::Table;
        table.size_functions.table_grid = grid;
        let set = table.check().expect("valid table config");
        group.bench_with_input(BenchmarkId::new("all_8_table", grid), &set, |b, set| {
            b.iter(|| set.extract(black_box(&frame)))
        });
    }
    group.finish();
}

criterion_group!(benches, features);
criterion_main!(benches);
