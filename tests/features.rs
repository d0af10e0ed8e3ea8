//! Integration tests of the features room: hand-derived diagrams of drawn shapes, invariance
//! under translation, missing values, and the mesh analysis on rig-like synthetic frames.

use evitrack::features::synthetic::{add_noise, render, rig_like_frame, Shape};
use evitrack::features::{
    analyse_mesh, extract_silhouette, FeatureConfig, MeanMethod, MeshOrder, PersistenceDiagram,
    Polarity, SilhouetteConfig, Window,
};
use image::GrayImage;

const SQRT2: f64 = std::f64::consts::SQRT_2;

/// Pixels `x0..=x1`, `y0..=y1` exactly.
fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Shape {
    Shape::Rect {
        min: [x0 - 0.5, y0 - 0.5],
        max: [x1 + 0.5, y1 + 0.5],
    }
}

/// The diagram of the silhouette contour of `img` under line `angle` (unsigned distance).
fn diagram(img: &GrayImage, angle_deg: f64) -> (Vec<(f64, f64)>, [f64; 2]) {
    let s = extract_silhouette(img, Polarity::BrightOnDark, &SilhouetteConfig::default())
        .expect("a silhouette");
    let mut phi = Vec::new();
    evitrack::features::distance_from_line(
        &s.contour,
        s.centroid,
        angle_deg.to_radians(),
        false,
        &mut phi,
    );
    let mut pairs = PersistenceDiagram::of_cycle(&phi).unwrap().pairs().to_vec();
    pairs.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.total_cmp(&b.0)));
    (pairs, s.centroid)
}

fn assert_pairs(got: &[(f64, f64)], want: &[(f64, f64)], tol: f64) {
    assert_eq!(got.len(), want.len(), "got {got:?}, want {want:?}");
    for (g, w) in got.iter().zip(want) {
        let close = |a: f64, b: f64| a == b || (a - b).abs() <= tol;
        assert!(
            close(g.0, w.0) && close(g.1, w.1),
            "got {got:?}, want {want:?}"
        );
    }
}

#[test]
fn rectangle_diagrams_by_hand() {
    // Pixels x 20..=79, y 30..=49: contour pixel centres on [20, 79] × [30, 49], centroid
    // (49.5, 39.5). Horizontal line: φ = |y − 39.5| is 0.5 on both short sides and 9.5 along the
    // long sides: one essential class and one pair, both born at 0.5.
    let img = render(120, 90, &[rect(20.0, 30.0, 79.0, 49.0)], 30, 200, 1);
    let (d, c) = diagram(&img, 0.0);
    assert_eq!(c, [49.5, 39.5]);
    assert_pairs(&d, &[(0.5, 9.5), (0.5, f64::INFINITY)], 1e-12);
    let (d, _) = diagram(&img, 90.0);
    assert_pairs(&d, &[(0.5, 29.5), (0.5, f64::INFINITY)], 1e-12);
}

#[test]
fn l_shape_diagrams_by_hand() {
    // An L of two 40 × 10 pixel bars sharing the corner block; contour pixel centres trace the
    // polygon (0,0) (39,0) (39,9) (9,9) (9,39) (0,39), offset by (30, 20). The pixel centroid is
    // ((400 · 19.5 + 300 · 4.5) / 700) = 9150 / 700 on both axes.
    let (ox, oy) = (30.0, 20.0);
    let img = render(
        120,
        90,
        &[
            rect(ox, oy, ox + 39.0, oy + 9.0),
            rect(ox, oy, ox + 9.0, oy + 39.0),
        ],
        30,
        200,
        1,
    );
    let c = 9150.0 / 700.0;
    let (d, centroid) = diagram(&img, 0.0);
    assert!((centroid[0] - ox - c).abs() < 1e-12 && (centroid[1] - oy - c).abs() < 1e-12);
    // φ = |y − c|: zero crossings on the inner and the outer long edge (nearest pixel row 13,
    // φ = c − 13); they merge across the outer corner at φ(y = 0) = c, not over the far end (39 − c).
    let b = c - 13.0;
    assert_pairs(&d, &[(b, c), (b, f64::INFINITY)], 1e-9);
    // The L is symmetric under x ↔ y: the vertical line gives the same diagram.
    let (d90, _) = diagram(&img, 90.0);
    assert_pairs(&d90, &[(b, c), (b, f64::INFINITY)], 1e-9);
    // 45°: φ = |y − x| / √2, minimum 0 at the outer corner, 1/√2 at the inner corner (the tracer
    // cuts the concave corner pixel), maxima 39/√2 at both far ends.
    let (d45, _) = diagram(&img, 45.0);
    assert_pairs(
        &d45,
        &[(1.0 / SQRT2, 39.0 / SQRT2), (0.0, f64::INFINITY)],
        1e-9,
    );
    // 135°: φ = |x + y − 2c| / √2 crosses zero on four edges (nearest x + y = 26); the crossings
    // merge over the inner corner (x + y = 19), the two far outer corners (x + y = 48), and the
    // last gap over the outer corner (x + y = 0) closes the cycle.
    let (d135, _) = diagram(&img, 135.0);
    let b = (2.0 * c - 26.0) / SQRT2;
    assert_pairs(
        &d135,
        &[
            (b, (2.0 * c - 19.0) / SQRT2),
            (b, (48.0 - 2.0 * c) / SQRT2),
            (b, (48.0 - 2.0 * c) / SQRT2),
            (b, f64::INFINITY),
        ],
        1e-9,
    );
}

#[test]
fn disc_diagrams_by_hand_up_to_digitisation() {
    // A disc of radius r about a pixel centre: for every line through the centre, φ is ~0 where
    // the line crosses the contour and ~r at right angles: one essential class and one pair
    // (≈0, ≈r). Digitisation adds only pairs of persistence below 1.5 px.
    let r = 20.0;
    let img = render(
        120,
        100,
        &[Shape::Disc {
            centre: [60.0, 50.0],
            radius: r,
        }],
        30,
        200,
        1,
    );
    for k in 0..6 {
        let (d, c) = diagram(&img, k as f64 * 30.0);
        assert_eq!(c, [60.0, 50.0]);
        let big: Vec<_> = d.iter().filter(|p| p.1 - p.0 > 1.5).collect();
        assert_eq!(big.len(), 2, "line {k}: {d:?}");
        assert!(big.iter().all(|p| p.0 < 0.75), "line {k}: {d:?}");
        assert!(big[0].1 > r - 1.5 && big[0].1 <= r, "line {k}: {d:?}");
        assert!(big[1].1.is_infinite());
    }
    let v = FeatureConfig::default()
        .check()
        .unwrap()
        .extract(&img)
        .into_iter()
        .map(|v| v.unwrap())
        .collect::<Vec<_>>();
    // Hence all six features ≈ 1 + (r / 128)² and nearly equal (rotation symmetry).
    for x in &v {
        assert!((x - (1.0 + (r / 128.0).powi(2))).abs() < 0.01, "{v:?}");
    }
}

#[test]
fn hexagon_example_through_the_public_api() {
    let d = PersistenceDiagram::of_cycle(&[0.0, 3.0, 1.0, 4.0, 2.0, 5.0]).unwrap();
    assert_eq!(
        (
            d.size_function(1.5, 2.5),
            d.size_function(1.5, 3.5),
            d.size_function(-1.0, 2.0)
        ),
        (2, 1, 0)
    );
    let w = Window::new(0.0, 5.0).unwrap();
    assert_eq!(d.mean_closed_form(w), 1.32);
}

/// The L-shape plus a bar, drawn at offset `(ox, oy)`.
fn shape_at(ox: f64, oy: f64, supersample: u32) -> GrayImage {
    render(
        170,
        120,
        &[
            rect(ox, oy, ox + 39.0, oy + 9.0),
            rect(ox, oy, ox + 9.0, oy + 39.0),
            Shape::Disc {
                centre: [ox + 30.0, oy + 25.0],
                radius: 8.0,
            },
        ],
        40,
        200,
        supersample,
    )
}

#[test]
fn translation_moves_barycentre_but_not_size_features() {
    let set = FeatureConfig::with_barycentre().check().unwrap();
    let base = set.extract(&shape_at(20.0, 15.0, 4));
    for (dx, dy) in [(37.0, 11.0), (90.0, 60.0), (5.0, 0.0)] {
        let moved = set.extract(&shape_at(20.0 + dx, 15.0 + dy, 4));
        // Integer shifts reproduce the same pixels: size features agree to rounding.
        for i in 0..6 {
            let (a, b) = (base[i].unwrap(), moved[i].unwrap());
            assert!((a - b).abs() <= 1e-12, "size_line{i}: {a} vs {b}");
        }
        let (bx, by) = (base[6].unwrap(), base[7].unwrap());
        let (mx, my) = (moved[6].unwrap(), moved[7].unwrap());
        assert!((mx - bx - dx).abs() < 1e-9 && (my - by - dy).abs() < 1e-9);
    }
    // Sub-pixel shifts with noise σ = 2: size features move by under 1 % of their value (a
    // feature's whole range over the rig mesh is tens of %, see the mesh test), the barycentre by
    // the shift to within 0.15 px (edge pixels: 4 × 4 coverage steps, and the background margin
    // weighs partly covered pixels non-linearly).
    let mut noisy_base = shape_at(20.0, 15.0, 4);
    add_noise(&mut noisy_base, 2.0, 1).unwrap();
    let nb = set.extract(&noisy_base);
    for (k, (dx, dy)) in [(0.25, 0.5), (40.4, 20.7), (61.5, 33.25)]
        .into_iter()
        .enumerate()
    {
        let mut img = shape_at(20.0 + dx, 15.0 + dy, 4);
        add_noise(&mut img, 2.0, 2 + k as u64).unwrap();
        let v = set.extract(&img);
        for i in 0..6 {
            let (a, b) = (nb[i].unwrap(), v[i].unwrap());
            assert!((a - b).abs() / a < 0.01, "size_line{i}: {a} vs {b}");
        }
        assert!((v[6].unwrap() - nb[6].unwrap() - dx).abs() < 0.15);
        assert!((v[7].unwrap() - nb[7].unwrap() - dy).abs() < 0.15);
    }
}

#[test]
fn empty_and_full_images_give_missing_values() {
    let set = FeatureConfig::with_barycentre().check().unwrap();
    for img in [
        GrayImage::new(170, 120),
        GrayImage::from_pixel(170, 120, image::Luma([255])),
        GrayImage::from_pixel(170, 120, image::Luma([90])),
        GrayImage::new(0, 0),
        GrayImage::new(1, 1),
    ] {
        let v = set.extract(&img);
        assert_eq!(v, vec![None; 8], "{:?}", img.dimensions());
    }
    // Pure noise: no silhouette (contrast guard); the barycentre of the noise itself is defined.
    let mut noise = GrayImage::from_pixel(170, 120, image::Luma([40]));
    add_noise(&mut noise, 2.0, 3).unwrap();
    let v = set.extract(&noise);
    assert_eq!(&v[..6], &[None; 6]);
    assert!(v[6].is_some_and(|x| x.is_finite()));
}

#[test]
fn rig_frames_give_finite_values_and_table_agrees_with_closed_form() {
    let set = FeatureConfig::with_barycentre().check().unwrap();
    let mut table_cfg = FeatureConfig::with_barycentre();
    table_cfg.size_functions.mean = MeanMethod::Table;
    table_cfg.size_functions.table_grid = 256;
    let table = table_cfg.check().unwrap();
    let frames: Vec<GrayImage> = [
        [-9.5, 38.0],
        [0.0, 47.5],
        [9.5, 57.0],
        [-9.5, 57.0],
        [4.2, 41.3],
    ]
    .iter()
    .enumerate()
    .map(|(k, &p)| rig_like_frame(p, 2.0, k as u64).unwrap())
    .collect();
    let exact = set.extract_batch(&frames);
    let approx = table.extract_batch(frames.iter());
    assert_eq!(exact.len(), 5);
    for (e, a) in exact.iter().zip(&approx) {
        assert!(e.iter().all(|v| v.is_some_and(f64::is_finite)), "{e:?}");
        for i in 0..6 {
            let (e, a) = (e[i].unwrap(), a[i].unwrap());
            // O(1/G) agreement: a few pairs, each off by at most ~2 cells.
            assert!((e - a).abs() < 0.05, "size_line{i}: closed {e} table {a}");
        }
        assert_eq!(e[6], a[6]);
    }
}

/// Feature vectors on the paper's 1 mm mesh over the 19 × 19 mm workspace (row-major, x
/// fastest), from rig-like synthetic frames with noise σ = 2, one seed per node.
fn rig_mesh_values(cfg: &FeatureConfig) -> Vec<Vec<Option<f64>>> {
    let set = cfg.check().unwrap();
    let mut values = Vec::with_capacity(400);
    for iy in 0..20 {
        for ix in 0..20 {
            let p = [-9.5 + ix as f64, 38.0 + iy as f64];
            let img = rig_like_frame(p, 2.0, (iy * 20 + ix) as u64).unwrap();
            values.push(set.extract(&img));
        }
    }
    values
}

#[test]
fn rig_mesh_condition_two_report() {
    // The simulated rig itself is the lead's run once the simulator lands; this is the same
    // analysis on rig-like synthetic frames.
    let cfg = FeatureConfig::with_barycentre();
    let set = cfg.check().unwrap();
    let values = rig_mesh_values(&cfg);
    let a = analyse_mesh(&values, 20, 20, MeshOrder::RowMajor, 0.01).unwrap();
    eprintln!(
        "rig-like mesh: {} of {} nodes told apart from all 4-neighbours (tolerance 1 % of range)",
        a.distinguished, a.nodes
    );
    // Noise jitter: the spread of each feature over 8 noise seeds at fixed poses.
    let poses = [[0.0, 47.5], [-7.0, 40.0], [6.0, 55.0]];
    let mut jitter = vec![0.0f64; set.len()];
    for p in poses {
        let frames: Vec<GrayImage> = (0..8)
            .map(|k| rig_like_frame(p, 2.0, 1000 + k).unwrap())
            .collect();
        let runs = set.extract_batch(&frames);
        for (f, j) in jitter.iter_mut().enumerate() {
            let xs: Vec<f64> = runs.iter().map(|v| v[f].unwrap()).collect();
            let m = xs.iter().sum::<f64>() / xs.len() as f64;
            let sd = (xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / 7.0).sqrt();
            *j = j.max(sd);
        }
    }
    for ((name, f), j) in set.names().iter().zip(&a.features).zip(&jitter) {
        eprintln!(
            "  {name:>13}: range {:.4}, |Δ|/range max {:.3} mean {:.3}, noise sd/range {:.4}",
            f.range,
            f.max_step,
            f.mean_step,
            j / f.range
        );
    }
    assert!(a.features.iter().all(|f| f.missing == 0 && f.range > 0.0));
    // The barycentre follows the end-effector (1 mm = 5 px): every node is told apart.
    assert_eq!(a.distinguished, 400);
    for f in &a.features[6..] {
        assert!(f.max_step < 0.15, "{f:?}");
    }
    // Condition 2: no size feature jumps by more than a fifth of its range between neighbours,
    // and noise moves each feature by well under the typical neighbour step.
    for (f, j) in a.features.iter().zip(&jitter) {
        assert!(f.max_step < 0.2, "{f:?}");
        assert!(j / f.range < 0.5 * f.mean_step, "{f:?}, noise sd {j}");
    }
}

#[test]
fn unsigned_distance_tells_more_nodes_apart_than_signed() {
    // Why the default is the unsigned distance: on the rig-like mesh, the six size features alone
    // tell more nodes apart from their neighbours than with the signed distance (projection).
    let size_only = |signed: bool| {
        let mut cfg = FeatureConfig::default();
        cfg.size_functions.signed = signed;
        if signed {
            cfg.size_functions.window = [-128.0, 128.0];
        }
        let values = rig_mesh_values(&cfg);
        let a = analyse_mesh(&values, 20, 20, MeshOrder::RowMajor, 0.05).unwrap();
        eprintln!(
            "signed = {signed}: {} of 400 nodes told apart (tolerance 5 % of range)",
            a.distinguished
        );
        a.distinguished
    };
    let (unsigned, signed) = (size_only(false), size_only(true));
    assert!(
        unsigned > 2 * signed,
        "unsigned {unsigned}, signed {signed}"
    );
}

/// Issue 4's report on the simulated rig itself: over the 1 mm mesh, how many nodes the 8-feature
/// vector tells apart from their 4-neighbours, and how smooth each feature is (§3.1, condition 2).
#[test]
fn simulated_rig_mesh_condition_two() {
    use evitrack::sim::{simulate, Motion, SimSettings};
    let dataset = simulate(
        &SimSettings::default(),
        &Motion::Mesh { spacing: 1.0 },
        7,
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(dataset.len(), 400);
    let set = FeatureConfig::with_barycentre().check().unwrap();
    let values = set.extract_batch(dataset.images());
    let analysis = analyse_mesh(&values, 20, 20, MeshOrder::Serpentine, 0.01).unwrap();
    let six: Vec<Vec<Option<f64>>> = values.iter().map(|v| v[..6].to_vec()).collect();
    let six_analysis = analyse_mesh(&six, 20, 20, MeshOrder::Serpentine, 0.01).unwrap();
    eprintln!(
        "simulated rig, 1 mm mesh: 8 features tell {} of {} nodes apart from all 4-neighbours, \
         the 6 size functions {} (tolerance 1 % of range)",
        analysis.distinguished, analysis.nodes, six_analysis.distinguished
    );
    for (name, f) in set.names().iter().zip(&analysis.features) {
        eprintln!(
            "  {name:>13}: range {:.4}, |Δ|/range max {:.3} mean {:.3}, missing {}",
            f.range, f.max_step, f.mean_step, f.missing
        );
    }
    // Every frame shows a silhouette, and every feature varies with the pose.
    assert!(analysis
        .features
        .iter()
        .all(|f| f.missing == 0 && f.range > 0.0));
    // The barycentre follows the end-effector, so with it the vector tells (almost) every node
    // apart; the size functions alone tell fewer.
    assert!(analysis.distinguished >= 390, "{}", analysis.distinguished);
    assert!(six_analysis.distinguished <= analysis.distinguished);
    // Condition 2: no feature jumps by more than a third of its range between neighbours.
    for (name, f) in set.names().iter().zip(&analysis.features) {
        assert!(
            f.max_step < 0.34,
            "{name}: max step {:.3} of range",
            f.max_step
        );
    }
}
