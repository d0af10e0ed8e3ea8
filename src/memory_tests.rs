use super::*;

#[test]
fn sizes_read_with_their_units_and_refuse_the_rest() {
    assert_eq!(parse_size("4GiB").unwrap(), 4 << 30);
    assert_eq!(parse_size("1500 MB").unwrap(), 1_500_000_000);
    assert_eq!(parse_size("2.5g").unwrap(), 2_500_000_000);
    assert_eq!(parse_size("123").unwrap(), 123);
    for bad in [
        "",
        "GiB",
        "-1G",
        "0",
        "4 parsecs",
        "1e400",
        "99999999999999999999TiB",
    ] {
        assert!(parse_size(bad).is_err(), "{bad}");
    }
}

fn shape(features: usize) -> FitShape {
    FitShape {
        samples: 400,
        features,
        extent: [40.0, 20.0],
    }
}

#[test]
fn the_grid_is_counted_once_and_grows_with_the_features() {
    let mut settings = EstimatorSettings::default();
    settings.continuous.grid_spacing = 0.02;
    let grid = |methods: &[Method], features| -> u64 {
        let parts = fit_parts(methods, &settings, &shape(features));
        parts
            .iter()
            .filter(|p| p.what.contains("grid"))
            .map(|p| p.bytes)
            .sum()
    };
    let one = grid(&[Method::CONTINUOUS], 4);
    // 1000 × 1000 nodes (capped) × 4 features × 32 bytes.
    assert_eq!(one, 1000 * 1000 * 4 * 32);
    let all = [
        Method::CONTINUOUS,
        Method::CONTINUOUS_TEMPORAL,
        Method::PARTICLE_FILTER,
    ];
    assert_eq!(grid(&all, 4), one, "one grid shared by the three");
    assert_eq!(grid(&all, 64), 16 * one, "64 features: 16 times 4");
    assert_eq!(grid(&[Method::KNN], 4), 0);
    let regrouped = |features| -> u64 {
        fit_parts(&[Method::PARTICLE_FILTER], &settings, &shape(features))
            .iter()
            .filter(|p| p.what.contains("regrouped"))
            .map(|p| p.bytes)
            .sum()
    };
    assert_eq!(
        regrouped(4),
        one,
        "the particle filter's copy of four features"
    );
    assert_eq!(regrouped(7), one, "only whole groups of four are copied");
    assert_eq!(grid(&[Method::CONTINUOUS], 8), regrouped(8));
}

#[test]
fn the_render_check_from_the_samples_holds_a_field_per_sample() {
    let part = |scenario: &crate::scenario::Scenario, what: &str| -> Option<u64> {
        let estimate = of_run(&scenario.check().expect("valid")).expect("planned");
        (estimate.parts.iter())
            .find(|p| p.what.contains(what))
            .map(|p| p.bytes)
    };
    let fields = |scenario: &crate::scenario::Scenario| part(scenario, "distance fields");
    let mut scenario = crate::scenario::Scenario {
        name: "fields".into(),
        ..Default::default()
    };
    // The default validation motion's 100 frames are too few for a limit at share 0.005,
    // so the check is off unless asked for.
    assert_eq!(
        fields(&scenario),
        None,
        "too few frames to learn its limit on"
    );
    scenario.confidence.render_check = Some(true);
    // The default 1 mm mesh: 400 samples of 170 × 120 px, 2 bytes each.
    let all = Some(400 * 170 * 120 * 2);
    assert_eq!(fields(&scenario), all, "asked for");
    scenario.confidence.render_check = None;
    scenario.validation = Some(crate::sim::Motion::RandomPath {
        seed: None,
        speed: 8.0,
        duration: 20.0,
        fps: 10.0,
        components: 4,
    });
    assert_eq!(fields(&scenario), all, "on by default on 200 frames");
    scenario.confidence.render_check = Some(false);
    assert_eq!(fields(&scenario), None, "turned off");
    scenario.confidence.render_check = Some(true);
    scenario.confidence.render_from = RenderSource::Simulator;
    assert_eq!(fields(&scenario), None, "the renderer keeps none");
    // Either source keeps the calibration and test frames' silhouettes, 319 words of 64 px
    // each: the 200 calibration frames and the default test motion's (10 s at 20 frames/s).
    let silhouettes = |scenario: &crate::scenario::Scenario| part(scenario, "check's silhouettes");
    assert_eq!(silhouettes(&scenario), Some((200 + 200) * 319 * 8));
    scenario.confidence.render_check = Some(false);
    assert_eq!(silhouettes(&scenario), None, "turned off");
}

#[test]
fn over_the_limit_names_the_costliest_setting_and_jobs_add_up() {
    let mut settings = EstimatorSettings::default();
    settings.continuous.grid_spacing = 0.02;
    let run = |name: &str| Estimate {
        name: name.into(),
        parts: fit_parts(&[Method::CONTINUOUS], &settings, &shape(4)),
    };
    let runs = [run("a"), run("b")];
    let total = runs[0].total();
    let limit = |bytes| Limit {
        bytes,
        source: LimitSource::Option,
    };
    assert!(check(&runs, 1, limit(total)).is_ok());
    let message = check(&runs, 2, limit(total)).unwrap_err().to_string();
    assert!(message.contains("2 runs at once"), "{message}");
    assert!(
        message.contains("`continuous.grid_spacing = 0.02`"),
        "{message}"
    );
    assert!(message.contains("`--memory-limit`"), "{message}");
    assert!(check(&runs, 2, limit(2 * total - BASE_BYTES)).is_ok());
}
