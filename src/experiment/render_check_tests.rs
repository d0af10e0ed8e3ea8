use super::*;
use crate::sim::render_pose;

fn check() -> (SimSettings, RenderCheck) {
    let sim = SimSettings::default();
    let check = RenderCheck::new(&sim, &SilhouetteConfig::default()).expect("valid settings");
    (sim, check)
}

fn centre(sim: &SimSettings) -> [f64; 2] {
    sim.check().expect("valid").five_bar.workspace_centre()
}

#[test]
fn the_robot_rendered_at_the_true_pose_explains_a_clean_frame_to_a_few_pixels() {
    let (sim, check) = check();
    let w = sim.geometry.workspace;
    for (k, at) in [
        centre(&sim),
        [w.x_min + 2.0, w.y_max - 3.0],
        [w.x_max - 1.0, w.y_min + 1.0],
    ]
    .into_iter()
    .enumerate()
    {
        let image = render_pose(&sim, at[0], at[1], k as u64).expect("rendered");
        let observed = check.observe(&image);
        let pixels = observed.pixels().expect("a silhouette");
        assert!(pixels > 300, "{at:?}: {pixels} px");
        let mismatch = check.mismatch(&observed, Some(at));
        assert!(mismatch <= 10.0, "{at:?}: {mismatch} px");
    }
}

#[test]
fn the_mismatch_grows_with_the_pose_error() {
    let (sim, check) = check();
    let at = centre(&sim);
    let observed = check.observe(&render_pose(&sim, at[0], at[1], 3).expect("rendered"));
    let mismatches: Vec<f64> = [0.0, 0.1, 0.3, 1.0, 3.0]
        .iter()
        .map(|&d| check.mismatch(&observed, Some([at[0] + 0.6 * d, at[1] - 0.8 * d])))
        .collect();
    assert!(mismatches.windows(2).all(|p| p[0] < p[1]), "{mismatches:?}");
    // Near a thousand pixels a millimetre (0.2 mm pixels along the robot's outline).
    assert!(mismatches[3] > 500.0, "{mismatches:?}");
}

#[test]
fn the_limit_is_the_conformal_rank_of_the_calibration_mismatches() {
    let values: Vec<f64> = (1..=200).rev().map(f64::from).collect();
    // ⌈201 × 0.99⌉ = 199.
    assert_eq!(render_limit(&values, 0.01), Some(199.0));
    // ⌈201 × 0.5⌉ = 101.
    assert_eq!(render_limit(&values, 0.5), Some(101.0));
    // Too few frames for the rank, or the rank lands on an undefined frame: no limit.
    assert_eq!(render_limit(&values[..50], 0.01), None);
    let mut undefined = values.clone();
    undefined[..3].fill(f64::INFINITY);
    assert_eq!(render_limit(&undefined, 0.01), None);
    assert_eq!(render_limit(&[], 0.01), None);
}

#[test]
fn undefined_frames_and_estimates_have_an_infinite_mismatch() {
    let (sim, check) = check();
    let w = sim.geometry.workspace;
    let at = centre(&sim);
    let image = render_pose(&sim, at[0], at[1], 1).expect("rendered");
    let observed = check.observe(&image);
    // No silhouette: a black frame, a dropped frame, a frame of another size.
    let black = GrayImage::new(image.width(), image.height());
    let small = GrayImage::new(10, 10);
    for nothing in [
        check.observe(&black),
        Observed::dropped(),
        check.observe(&small),
    ] {
        assert_eq!(nothing.pixels(), None);
        assert_eq!(check.mismatch(&nothing, Some(at)), f64::INFINITY);
    }
    // No estimate, one out of the arms' reach, one not finite.
    for estimate in [None, Some([1e4, 1e4]), Some([f64::NAN, at[1]])] {
        assert_eq!(check.mismatch(&observed, estimate), f64::INFINITY);
    }
    // Just outside the workspace but reachable: rendered and compared like any other.
    let outside = check.mismatch(&observed, Some([w.x_max + 0.5, at[1]]));
    assert!(outside.is_finite() && outside > 100.0, "{outside}");
}

/// A run's check with `check`, and a method's limit of `limit_px` (`None`: none learned).
fn judging(check: &RenderCheck, limit_px: Option<f64>) -> (Harness, MethodLimit) {
    let harness = Harness {
        learned: Arc::new(Learned {
            check: check.clone(),
            calibration: Vec::new(),
        }),
        share: 0.01,
    };
    let limit = MethodLimit {
        limit: limit_px,
        calibration: Some(Calibration {
            coverage: 0.9,
            radius: Some(2.0),
            floor: 0.0,
            detection_limit: None,
            max_region_area: f64::INFINITY,
            workspace: SimSettings::default().geometry.workspace,
            validation_frames: 100,
            validation_abstained: 0.0,
            cell_radii: None,
            render_limit_px: None,
            stray_limit_px: None,
        }),
    };
    (harness, limit)
}

/// (abstained, render_mismatch, stray_pixels) of an estimate at `pose` judged on `observed`.
fn judged(
    (harness, limit): &(Harness, MethodLimit),
    observed: &Observed,
    pose: [f64; 2],
) -> (bool, bool, bool) {
    let mut estimate = PoseEstimate {
        pose: Some(pose),
        ..PoseEstimate::default()
    };
    harness.judge(&mut estimate, observed, limit);
    let flags = &estimate.flags;
    (flags.abstained, flags.render_mismatch, flags.stray_pixels)
}

#[test]
fn a_dropped_frame_is_left_alone_and_a_frame_without_a_silhouette_abstains() {
    let (sim, check) = check();
    let at = centre(&sim);
    let image = render_pose(&sim, at[0], at[1], 1).expect("rendered");
    let run = judging(&check, Some(50.0));
    let black = GrayImage::new(image.width(), image.height());
    assert_eq!(
        judged(&run, &check.observe(&image), at),
        (false, false, false)
    );
    let off = [at[0] + 3.0, at[1]];
    assert_eq!(
        judged(&run, &check.observe(&image), off),
        (true, true, false)
    );
    assert_eq!(
        judged(&run, &check.observe(&black), at),
        (true, true, false)
    );
    // Missing data, not evidence: a temporal method's prediction stands.
    assert_eq!(
        judged(&run, &Observed::dropped(), at),
        (false, false, false)
    );
}

#[test]
fn a_frame_with_more_stray_pixels_than_the_calibration_frames_abstains() {
    let (sim, check) = check();
    let at = centre(&sim);
    // Clean frames show no stray pixels: the limit is 0.
    let calibration: Vec<Observed> = (0..5u32)
        .map(|k| {
            let image = render_pose(&sim, at[0], at[1] + 0.5 * f64::from(k), u64::from(k));
            check.observe(&image.expect("rendered"))
        })
        .collect();
    assert_eq!(RenderCheck::learn_stray_limit(&calibration), Some(0.0));
    assert_eq!(RenderCheck::learn_stray_limit(&[Observed::dropped()]), None);
    let clean = render_pose(&sim, at[0], at[1], 7).expect("rendered");
    let mut salted = clean.clone();
    for k in 0..12 {
        // White specks along the top row, far from the robot.
        salted.put_pixel(5 + 7 * k, 0, image::Luma([255]));
    }
    let (clean, salted) = (check.observe(&clean), check.observe(&salted));
    assert_eq!((clean.stray(), salted.stray()), (Some(0), Some(12)));
    // At the true pose the silhouettes agree; the specks alone make it abstain, also for a
    // method without a mismatch limit of its own.
    let limited = check.clone().with_stray_limit(Some(0.0));
    for limit_px in [Some(50.0), None] {
        let run = judging(&limited, limit_px);
        assert_eq!(judged(&run, &salted, at), (true, false, true));
        assert_eq!(judged(&run, &clean, at), (false, false, false));
    }
    // Unchecked, or below a looser limit, the specks pass.
    for unchecked in [check.clone(), check.with_stray_limit(Some(12.0))] {
        let run = judging(&unchecked, Some(50.0));
        assert_eq!(judged(&run, &salted, at), (false, false, false));
    }
}

#[test]
fn silhouettes_predicted_from_the_sample_frames_explain_a_frame_and_tell_pose_errors() {
    let (sim, renderer) = check();
    // Sample frames on a 1 mm grid about the centre, as the default mesh has them.
    let c = centre(&sim);
    let points = (-2..=2)
        .flat_map(|j| (-2..=2).map(move |i| [c[0] + f64::from(i), c[1] + f64::from(j)]))
        .collect();
    let motion = crate::sim::Motion::Points { points };
    let sample = crate::sim::simulate(&sim, &motion, 5, &mut |_, _| {}).expect("simulated");
    let check = renderer
        .clone()
        .with_samples(&sample, 2)
        .expect("25 silhouettes");
    let at = [c[0] + 0.37, c[1] - 0.42];
    let observed = check.observe(&render_pose(&sim, at[0], at[1], 9).expect("rendered"));
    let mismatches: Vec<f64> = [0.0, 0.1, 0.3, 1.0]
        .iter()
        .map(|&d| check.mismatch(&observed, Some([at[0] + 0.6 * d, at[1] - 0.8 * d])))
        .collect();
    assert!(mismatches.windows(2).all(|p| p[0] < p[1]), "{mismatches:?}");
    // Not a renderer: the samples' noise and the interpolation add a few tens of pixels at the
    // truth, where the rendered robot misses a few.
    let rendered = renderer.mismatch(&observed, Some(at));
    assert!(
        rendered < mismatches[0] && mismatches[0] <= 80.0 && mismatches[3] > 500.0,
        "{mismatches:?}, rendered {rendered}"
    );
    // Undefined cases as with the renderer.
    assert!(check
        .mismatch(&observed, Some([f64::NAN, 0.0]))
        .is_infinite());
    assert!(check.mismatch(&Observed::dropped(), Some(at)).is_infinite());
    // Too few silhouettes to fit a plane: no check.
    let two = crate::sim::Motion::Points {
        points: vec![c, [c[0] + 1.0, c[1]]],
    };
    let two = crate::sim::simulate(&sim, &two, 5, &mut |_, _| {}).expect("simulated");
    assert!(renderer.with_samples(&two, 1).is_none());
}
