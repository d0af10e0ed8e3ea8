use super::*;
use crate::features::FeatureConfig;

fn spec(toml_text: &str) -> FaultSpec {
    toml::from_str(toml_text).unwrap()
}

fn names() -> Vec<String> {
    ["a", "b", "c"].iter().map(|s| s.to_string()).collect()
}

fn check(toml_text: &str) -> Result<FaultPlan, FaultError> {
    FaultPlan::check(&[spec(toml_text)], &names(), [170, 120])
}

#[test]
fn the_struck_share_and_bursts_are_as_asked() {
    for (share, burst) in [(0.3, 1), (0.3, 5), (0.1, 3)] {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let active = active_frames(20_000, share, None, burst, &mut rng);
        let struck = active.iter().filter(|&&a| a).count() as f64 / 20_000.0;
        assert!((struck - share).abs() < 0.015, "{share} {burst}: {struck}");
        // Every run of struck frames is a whole number of bursts.
        let mut run = 0;
        for &a in active.iter().chain([false].iter()) {
            if a {
                run += 1;
            } else {
                assert_eq!(run % burst, 0, "a run of {run} with bursts of {burst}");
                run = 0;
            }
        }
    }
}

#[test]
fn windows_bound_the_struck_frames() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let all = active_frames(50, 1.0, Some([10, 19]), 1, &mut rng);
    let struck: Vec<usize> = (0..50).filter(|&i| all[i]).collect();
    assert_eq!(struck, (10..20).collect::<Vec<_>>());
    let none = active_frames(50, 0.0, None, 1, &mut rng);
    assert!(none.iter().all(|&a| !a));
    // A burst is cut at the window's end; a window past the motion is cut at its end.
    let cut = active_frames(12, 1.0, Some([8, 100]), 5, &mut rng);
    assert_eq!(cut.iter().filter(|&&a| a).count(), 4);
}

#[test]
fn bad_settings_are_refused_with_the_field_named() {
    let message = |t: &str| check(t).unwrap_err().to_string();
    assert!(message("kind = \"stuck\"\nfeatures = [\"z\"]\nvalue = 1").contains("no feature `z`"));
    assert!(message("kind = \"stuck\"\nfeatures = [\"a\"]").contains("`value`"));
    assert!(
        message("kind = \"stuck\"\nfeatures = [\"a\"]\nvalue = 1\nrect = [0, 0, 1, 1]")
            .contains("`rect` does not apply")
    );
    assert!(message("kind = \"dropped\"\nshare = 1.5").contains("`share`"));
    assert!(message("kind = \"dropped\"\nburst = 0").contains("`burst`"));
    assert!(message("kind = \"dropped\"\nwindow = [5, 2]").contains("`window`"));
    assert!(message("kind = \"occluder\"").contains("`rect"));
    assert!(message("kind = \"occluder\"\nrect = [200, 0, 5, 5]").contains("outside"));
    assert!(check("kind = \"occluder\"\nrect = [-9, 0, 5, 5]\nvelocity = [1, 0]").is_ok());
    assert!(
        message("kind = \"occluder\"\nrect = [0, 0, 5, 5]\nintensity = 300")
            .contains("`intensity`")
    );
    assert!(message("kind = \"salt_pepper\"\ndensity = 0").contains("`density`"));
    assert!(message("kind = \"noise\"\nfeatures = [\"a\"]\nsigma = -1").contains("`sigma`"));
    assert!(message("kind = \"gain\"\nfeatures = [\"a\", \"a\"]\nfactor = 2").contains("twice"));
    assert!(message("kind = \"glare\"\ncentre = [1, 1]\nradius = 0").contains("`radius`"));
    assert!(toml::from_str::<FaultSpec>("kind = \"stuck\"\nvalu = 1").is_err());
    assert!(toml::from_str::<FaultSpec>("kind = \"sticky\"").is_err());
}

#[test]
fn feature_changes_follow_their_units() {
    let scale = FeatureScale {
        mean: 10.0,
        sd: 2.0,
        range: 8.0,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut go = |c, u| change_value(Some(5.0), c, u, scale, &mut rng);
    assert_eq!(go(Change::Stuck(3.0), FaultUnits::Raw), Some(3.0));
    assert_eq!(go(Change::Stuck(3.0), FaultUnits::Sd), Some(16.0));
    assert_eq!(go(Change::Offset(1.5), FaultUnits::Sd), Some(8.0));
    assert_eq!(go(Change::Gain(2.0), FaultUnits::Raw), Some(10.0));
    assert_eq!(go(Change::Dropout, FaultUnits::Raw), None);
    assert_ne!(go(Change::Noise(1.0), FaultUnits::Raw), Some(5.0));
    assert!(changed(Some(1.0), Some(1.1), 8.0));
    assert!(!changed(Some(1.0), Some(1.05), 8.0));
    assert!(changed(None, Some(1.0), 8.0) && changed(Some(1.0), None, 8.0));
}

#[test]
fn scales_skip_missing_values() {
    let rows = vec![vec![Some(1.0), None], vec![Some(3.0), None]];
    let s = FeatureScale::of_rows(&rows, 2);
    assert_eq!((s[0].mean, s[0].sd, s[0].range), (2.0, 1.0, 2.0));
    assert_eq!((s[1].mean, s[1].sd, s[1].range), (0.0, 0.0, 0.0));
}

/// A bright bar on a dark image, moving right one pixel a frame.
fn frames(n: usize) -> Vec<GrayImage> {
    (0..n)
        .map(|i| {
            GrayImage::from_fn(170, 120, |x, y| {
                let inside = (40..100).contains(&y) && (60 + i as u32..75 + i as u32).contains(&x);
                image::Luma([if inside { 220 } else { 30 }])
            })
        })
        .collect()
}

#[test]
fn faults_are_labelled_and_drawn_the_same_from_the_same_seed() {
    let set = FeatureConfig::with_barycentre().check().unwrap();
    let images = frames(40);
    let clean = set.extract_batch(&images);
    let scales = FeatureScale::of_rows(&clean, set.len());
    let names = set.names();
    let specs: Vec<FaultSpec> = toml::from_str::<toml::Table>(&format!(
        r#"
        [[f]]
        kind = "stuck"
        features = ["{}", "{}"]
        value = 1000
        share = 0.3
        [[f]]
        kind = "dropped"
        window = [30, 39]
        share = 0.5
        [[f]]
        kind = "occluder"
        name = "bright_bar"
        rect = [0, 30, 170, 20]
        intensity = 255
        window = [0, 9]
        "#,
        names[0], names[6]
    ))
    .unwrap()["f"]
        .clone()
        .try_into()
        .unwrap();
    let plan = FaultPlan::check(&specs, &names, [170, 120]).unwrap();
    assert!(plan.touches_images());
    let a = plan.apply(5, images.iter(), &clean, &set, &scales);
    let b = plan.apply(5, images.iter(), &clean, &set, &scales);
    assert_eq!(a, b);
    let c = plan.apply(6, images.iter(), &clean, &set, &scales);
    assert_ne!(a.labels, c.labels);
    for (i, (row, label)) in a.rows.iter().zip(&a.labels).enumerate() {
        let stuck = label.faults.iter().any(|f| f == "stuck");
        if label.dropped {
            assert!(row.iter().all(Option::is_none));
            assert!(label.corrupted() && (30..40).contains(&i));
        } else if stuck {
            assert_eq!((row[0], row[6]), (Some(1000.0), Some(1000.0)));
            assert!(label.changed.contains(&0) && label.changed.contains(&6));
        }
        let occluded = label.faults.iter().any(|f| f == "bright_bar");
        assert_eq!(occluded, i < 10, "frame {i}");
        if !label.dropped && !stuck && !occluded {
            assert_eq!(row, &clean[i]);
            assert!(label.changed.is_empty() && !label.corrupted());
        }
        if occluded && !label.dropped {
            // The bright band crosses the bar: the silhouette and its features change.
            assert!(!label.changed.is_empty(), "frame {i}");
        }
    }
    let stuck_frames = a
        .labels
        .iter()
        .filter(|l| l.faults.iter().any(|f| f == "stuck"))
        .count();
    assert!((5..=20).contains(&stuck_frames), "{stuck_frames}");
}

#[test]
fn painters_change_the_right_pixels() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mut img = GrayImage::from_pixel(10, 10, image::Luma([30]));
    let occluder = Effect::Occluder {
        rect: [2.0, 3.0, 4.0, 2.0],
        intensity: 0,
        velocity: [1.0, 0.0],
    };
    image_faults::paint(&mut img, &occluder, 2.0, &mut rng);
    let dark: Vec<(u32, u32)> = img
        .enumerate_pixels()
        .filter(|p| p.2 .0[0] == 0)
        .map(|p| (p.0, p.1))
        .collect();
    let expected: Vec<(u32, u32)> = (3..5).flat_map(|y| (4..8).map(move |x| (x, y))).collect();
    assert_eq!(dark, expected);
    let mut img = GrayImage::from_pixel(20, 20, image::Luma([30]));
    let glare = Effect::Glare {
        centre: [10.0, 10.0],
        radius: 2.0,
        peak: 200.0,
    };
    image_faults::paint(&mut img, &glare, 0.0, &mut rng);
    assert!(img.get_pixel(10, 10).0[0] > 200 && img.get_pixel(0, 0).0[0] == 30);
    let mut img = GrayImage::from_pixel(100, 100, image::Luma([30]));
    image_faults::paint(
        &mut img,
        &Effect::SaltPepper { density: 0.2 },
        0.0,
        &mut rng,
    );
    let hit = img.pixels().filter(|p| p.0[0] != 30).count();
    assert!((1700..2300).contains(&hit), "{hit}");
}
