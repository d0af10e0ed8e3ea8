//! The k-d tree search against the brute force, bit for bit: ties, duplicated samples, every
//! dimension the tree serves directly or through principal components, and the switch back to
//! the brute force where the tree does not pay.

use super::*;
use crate::estimator::Labelled;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Features of a pose on a 2-D manifold of `dim` dimensions, rounded to 1/16 so that distances
/// tie often.
fn manifold(p: [f64; 2], dim: usize) -> Vec<Option<f64>> {
    let (x, y) = (p[0] / 9.5, (p[1] - 47.5) / 9.5);
    (0..dim)
        .map(|d| {
            let a = 0.3 + d as f64 * 0.17;
            let v = (a * x + (1.0 - a) * y).sin() + (0.5 * a * x * y).cos() + 0.2 * a * y;
            Some((v * 16.0).round() / 16.0)
        })
        .collect()
}

fn random_pose(rng: &mut ChaCha8Rng) -> [f64; 2] {
    [rng.random_range(-9.5..9.5), rng.random_range(38.0..57.0)]
}

/// A k-NN fitted on `rows` (poses drawn at random), with `k` neighbours.
fn fit(rows: &[Vec<Option<f64>>], k: usize, rng: &mut ChaCha8Rng) -> Knn {
    let dim = rows[0].len();
    let names: Vec<String> = (0..dim).map(|d| format!("f{d}")).collect();
    let poses: Vec<[f64; 2]> = rows.iter().map(|_| random_pose(rng)).collect();
    let settings = KnnSettings {
        k,
        weights: KnnWeights::Distance,
    };
    let data = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows,
        },
    );
    Knn::fit(&settings, &data).expect("k-NN fits")
}

/// Every query's neighbours equal the brute force's: same samples, order and distance bits.
fn assert_like_brute_force(knn: &Knn, queries: &[Vec<Option<f64>>]) {
    for (q, features) in queries.iter().enumerate() {
        let found = knn.neighbours(features).expect("a query");
        let (query, mask, _) = knn.query(features).expect("valid").expect("present");
        let brute = knn.brute_force(&query, &mask);
        let bits = |v: &[(usize, f64)]| -> Vec<(usize, u64)> {
            v.iter().map(|(i, d)| (*i, d.to_bits())).collect()
        };
        assert_eq!(bits(&found), bits(&brute), "query {q}");
    }
}

type Rows = Vec<Vec<Option<f64>>>;

/// Samples on the manifold with every 10th row repeated further on, and queries: fresh poses,
/// sample rows themselves, and rows with a feature missing (the brute force's case).
fn manifold_case(dim: usize, seed: u64) -> (Rows, Rows) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut rows: Vec<Vec<Option<f64>>> = (0..1800)
        .map(|_| manifold(random_pose(&mut rng), dim))
        .collect();
    let copies: Vec<_> = rows.iter().step_by(10).cloned().collect();
    rows.extend(copies);
    let mut queries: Vec<Vec<Option<f64>>> = (0..150)
        .map(|_| manifold(random_pose(&mut rng), dim))
        .collect();
    queries.extend(rows.iter().step_by(37).cloned());
    let mut gap = rows[5].clone();
    gap[0] = None;
    queries.push(gap);
    (rows, queries)
}

#[test]
fn the_tree_finds_what_the_brute_force_finds_in_every_dimension() {
    let mut rng = ChaCha8Rng::seed_from_u64(40);
    for (dim, k) in [(2, 6), (3, 1), (4, 6), (8, 6), (17, 3), (33, 6), (64, 10)] {
        let (rows, queries) = manifold_case(dim, dim as u64);
        let knn = fit(&rows, k, &mut rng);
        assert!(
            knn.index.is_some(),
            "{dim} features on a surface: the tree pays"
        );
        assert_like_brute_force(&knn, &queries);
    }
}

#[test]
fn ties_and_duplicates_go_to_the_lower_sample_as_in_the_brute_force() {
    // Integer features on a small lattice: many samples at equal distances, many duplicates.
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    let rows: Vec<Vec<Option<f64>>> = (0..3000)
        .map(|_| {
            (0..3)
                .map(|_| Some(rng.random_range(0..12) as f64))
                .collect()
        })
        .collect();
    let queries: Vec<Vec<Option<f64>>> = (0..200)
        .map(|_| {
            (0..3)
                .map(|_| Some(rng.random_range(0..24) as f64 * 0.5))
                .collect()
        })
        .collect();
    let knn = fit(&rows, 8, &mut rng);
    assert!(knn.index.is_some());
    assert_like_brute_force(&knn, &queries);
    // A duplicated sample's neighbours start with the equal rows, lowest index first.
    let first = knn.neighbours(&rows[0]).expect("a query");
    assert_eq!(first[0].1, 0.0);
    let zero: Vec<usize> = first.iter().filter(|n| n.1 == 0.0).map(|n| n.0).collect();
    assert!(zero.windows(2).all(|w| w[0] < w[1]), "{zero:?}");
}

#[test]
fn features_without_structure_keep_the_brute_force_and_far_frames_still_rank() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let rows: Vec<Vec<Option<f64>>> = (0..2000)
        .map(|_| (0..64).map(|_| Some(rng.random_range(-1.0..1.0))).collect())
        .collect();
    let knn = fit(&rows, 6, &mut rng);
    assert!(
        knn.index.is_none(),
        "64 independent features: the tree would gather all"
    );
    // Few samples: no tree either.
    let (rows, _) = manifold_case(8, 3);
    assert!(fit(&rows[..200], 6, &mut rng).index.is_none());
    // A frame far beyond the samples overflows the squares: the brute force ranks it.
    let knn = fit(&rows, 6, &mut rng);
    let mut far = rows[3].clone();
    far[1] = Some(1e200);
    assert_like_brute_force(&knn, &[far.clone()]);
    assert!(knn.neighbours(&far).expect("a query")[0].1 > 1e150);
}

/// The detection score of `features` (a frame with an estimate).
fn score(knn: &Knn, features: &[Option<f64>]) -> f64 {
    let e = knn.estimate(features).expect("a frame");
    e.detection_score.expect("a score")
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
fn the_score_sees_one_corrupted_feature_among_many_and_skips_a_missing_one() {
    // Samples on the manifold at the poses they come from (a 1 mm mesh, as the scenarios').
    let mut rng = ChaCha8Rng::seed_from_u64(43);
    let poses: Vec<[f64; 2]> = (0..400)
        .map(|i| [(i % 20) as f64 - 9.5, (i / 20) as f64 + 38.0])
        .collect();
    let rows: Rows = poses.iter().map(|p| manifold(*p, 8)).collect();
    let names: Vec<String> = (0..8).map(|d| format!("f{d}")).collect();
    let data = TrainingSet::new(
        &names,
        Labelled {
            poses: &poses,
            rows: &rows,
        },
    );
    let knn = Knn::fit(&KnnSettings::default(), &data).expect("k-NN fits");
    let frames: Vec<_> = (0..60)
        .map(|_| manifold(random_pose(&mut rng), 8))
        .collect();
    // One feature off by a standard deviation of its own: a frame no sample pose shows.
    let scale = knn.file.standardisation.scales[3];
    let struck: Vec<_> = (frames.iter().cloned())
        .map(|mut f| {
            f[3] = f[3].map(|v| v + scale);
            f
        })
        .collect();
    let clean = median(frames.iter().map(|f| score(&knn, f)).collect());
    let corrupted = median(struck.iter().map(|f| score(&knn, f)).collect());
    assert!(corrupted > 3.0 * clean, "{corrupted} against {clean}");
    // The nearest sample's distance, the score before, moved less: the neighbours shift to
    // other poses to absorb the corrupted feature.
    let nearest = |f: &Vec<Option<f64>>| knn.neighbours(f).expect("a frame")[0].1;
    let before = median(struck.iter().map(nearest).collect::<Vec<_>>())
        / median(frames.iter().map(nearest).collect::<Vec<_>>());
    assert!(
        corrupted / clean > before,
        "{} against {before}",
        corrupted / clean
    );
    // The corrupted feature missing: the score over the others is a clean frame's again.
    let gaps: Vec<f64> = (struck.iter().cloned())
        .map(|mut f| {
            f[3] = None;
            score(&knn, &f)
        })
        .collect();
    assert!(median(gaps) < 2.0 * clean);
    // Beyond the double range: finite, and as large as the frame is far.
    let mut far = frames[0].clone();
    far[1] = Some(1e200);
    let s = score(&knn, &far);
    assert!(s.is_finite() && s > 1e150, "{s}");
}

#[test]
fn a_frame_on_one_sample_states_that_samples_cell() {
    use crate::estimator::test_maps::{feature_value, MeshSamples};
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    // The 1 mm mesh: each sample pose stands for a 1 mm square, variance 1/12 mm² per axis.
    let samples = MeshSamples::new(20, 4, 0.01, &mut rng);
    let knn = Knn::fit(&KnnSettings::default(), &samples.training()).unwrap();
    // On a sample's own features every weight sits on it: no spread, only its cell.
    let on_sample = knn.estimate(&samples.rows[123]).unwrap();
    assert_eq!(on_sample.pose, Some(samples.poses[123]));
    assert_eq!(on_sample.uncertainty_radius, Some(0.0));
    let cell = 1.0 / 12.0;
    assert_eq!(on_sample.covariance, Some([[cell, 0.0], [0.0, cell]]));
    // Between samples the neighbours' spread comes on top of it.
    let between: Vec<Option<f64>> = (0..4)
        .map(|d| Some(feature_value(d, [0.3, 47.4])))
        .collect();
    let e = knn.estimate(&between).unwrap();
    let spread = e.uncertainty_radius.unwrap();
    let c = e.covariance.unwrap();
    assert!(spread > 0.0);
    assert!((c[0][0] + c[1][1] - 2.0 * cell - spread * spread).abs() < 1e-12);
}
