//! Unit tests of the `scenario` room.
use super::*;

const BASE: &str = r#"
name = "t"
seed = 3
[model]
states = [2, 2, 2, 3, 3, 2]
"#;

#[test]
fn a_file_without_sweep_is_one_variant_with_defaults_elsewhere() {
    let set = ScenarioSet::parse(BASE, "t.toml").unwrap();
    assert_eq!(set.variants.len(), 1);
    assert_eq!(set.base.seed, 3);
    assert_eq!(set.base.tests, Scenario::default().tests);
    assert_eq!(set.variants[0], set.base);
}

#[test]
fn a_partial_table_keeps_the_defaults_it_leaves_out() {
    let set =
        ScenarioSet::parse("[model]\nseed = 7\n[sim.noise]\nsigma = 5.0\n", "p.toml").unwrap();
    let base = &set.base;
    assert_eq!(base.name, "p");
    assert_eq!(base.model.seed, 7);
    assert_eq!(base.model.states, Scenario::default().model.states);
    assert_eq!(base.sim.noise.sigma, 5.0);
    assert_eq!(base.sim.camera, Scenario::default().sim.camera);
    // A motion table replaces the default motion instead of merging into it.
    let set = ScenarioSet::parse(
        "[sample]\nmotion = { kind = \"points\", points = [[0.0, 40.0], [1.0, 41.0]] }\n",
        "q.toml",
    )
    .unwrap();
    assert!(matches!(set.base.sample.motion, Motion::Points { .. }));
}

#[test]
fn unknown_fields_are_reported_with_line_and_column() {
    let text = format!("{BASE}\n[track]\nconstructr = \"bayesian\"\n");
    let error = ScenarioSet::parse(&text, "t.toml").unwrap_err().to_string();
    assert!(error.contains("line 8"), "{error}");
    assert!(error.contains("column 1"), "{error}");
    assert!(error.contains("constructr"), "{error}");
    let error = ScenarioSet::parse("nmae = \"x\"\n", "t.toml")
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("line 1") && error.contains("nmae"),
        "{error}"
    );
}

#[test]
fn listed_variants_replace_dotted_paths() {
    let text = format!(
        "{BASE}\n[[sweep.variant]]\nname = \"a\"\n[[sweep.variant]]\nname = \"b\"\n\
         set = {{ \"model.states\" = [2, 3, 3, 3, 3, 2], \"track.constructor\" = \"consonant\" }}\n"
    );
    let set = ScenarioSet::parse(&text, "t.toml").unwrap();
    assert_eq!(set.variants.len(), 2);
    assert_eq!(set.variants[0].name, "t-a");
    assert_eq!(set.variants[1].name, "t-b");
    assert_eq!(
        set.variants[1].model.states,
        StateCounts::PerFeature(vec![2, 3, 3, 3, 3, 2])
    );
    assert_eq!(
        set.variants[1].track.constructor,
        crate::evidence::Constructor::Consonant
    );
    assert_eq!(set.variants[0].model, set.base.model);
    assert!(set.variants.iter().all(|v| v.sweep == Sweep::default()));
}

#[test]
fn a_grid_spans_the_cartesian_product() {
    let text = format!(
        "{BASE}\n[sweep.grid]\n\"model.states\" = [2, 3]\n\"sim.noise.sigma\" = [0.0, 2.0, 4.0]\n"
    );
    let set = ScenarioSet::parse(&text, "t.toml").unwrap();
    assert_eq!(set.variants.len(), 6);
    let names: Vec<&str> = set.variants.iter().map(|v| v.name.as_str()).collect();
    assert!(names.contains(&"t-states=3,noise.sigma=4.0"), "{names:?}");

    let sigmas: Vec<f64> = set.variants.iter().map(|v| v.sim.noise.sigma).collect();
    assert_eq!(sigmas, [0.0, 2.0, 4.0, 0.0, 2.0, 4.0]);
    let tables = format!(
        "{BASE}\n[sweep.grid]\n\"sample.motion\" = [{{ kind = \"mesh\", spacing = 1.0 }}, \
         {{ kind = \"mesh\", spacing = 0.5 }}]\n"
    );
    let set = ScenarioSet::parse(&tables, "t.toml").unwrap();
    let names: Vec<&str> = set.variants.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(names, ["t-motion=mesh_1.0", "t-motion=mesh_0.5"]);
}

#[test]
fn bad_variants_name_the_variant_and_the_problem() {
    let typo =
        format!("{BASE}\n[[sweep.variant]]\nname = \"x\"\nset = {{ \"model.stats\" = 3 }}\n");
    let error = ScenarioSet::parse(&typo, "t.toml").unwrap_err().to_string();
    assert!(error.contains("`x`") && error.contains("stats"), "{error}");
    let twice =
        format!("{BASE}\n[[sweep.variant]]\nname = \"x\"\n[[sweep.variant]]\nname = \"x\"\n");
    let error = ScenarioSet::parse(&twice, "t.toml")
        .unwrap_err()
        .to_string();
    assert!(error.contains("two variants"), "{error}");
    let through_value =
        format!("{BASE}\n[[sweep.variant]]\nname = \"y\"\nset = {{ \"seed.x\" = 1 }}\n");
    let error = ScenarioSet::parse(&through_value, "t.toml")
        .unwrap_err()
        .to_string();
    assert!(error.contains("not a table"), "{error}");
}

#[test]
fn values_deserialisation_cannot_check_are_checked() {
    for (text, needle) in [
        ("name = \"a b\"\n", "may only hold"),
        ("[sample]\nkeep_every = 0\n", "keep_every"),
        ("tests = []\n", "no test motion"),
        (
            "[features.barycentre]\nenabled = true\n",
            "6 counts for 8 features",
        ),
        ("name = \"..\"\n", "may not start with"),
        ("paper_error = nan\n", "paper_error"),
        ("[track]\nconflict_threshold = -1.0\n", "[track]"),
        ("[sweep.grid]\n\"model.states\" = []\n", "empty"),
        ("[expect]\nmax_mean_error = -1.0\n", "max_mean_error"),
    ] {
        let error = ScenarioSet::parse(text, "t.toml")
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(error.contains(needle), "{text:?}: {error}");
    }
}

#[test]
fn learning_the_threshold_needs_a_validation_motion() {
    let scenario = Scenario {
        name: "v".into(),
        learn_threshold: true,
        validation: None,
        ..Scenario::default()
    };
    let error = scenario.check().unwrap_err().to_string();
    assert!(error.contains("needs a [validation] motion"), "{error}");
}

#[test]
fn every_shipped_scenario_file_is_valid() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios");
    let mut count = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let set =
                ScenarioSet::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(!set.variants.is_empty());
            count += 1;
        }
    }
    assert!(count >= 1);
}

#[test]
fn seeds_and_findings_of_a_sweep() {
    let text = r#"
name = "s"
[sweep]
seeds = 3
[[sweep.variant]]
name = "x"
[[sweep.variant]]
name = "y"
set = { seed = 7 }
[[sweep.finding]]
name = "x < y"
left = "x"
right = "s-y"
"#;
    let set = ScenarioSet::parse(text, "s.toml").unwrap();
    let runs = set.seeded(None).unwrap();
    let seeds: Vec<(String, u64)> = runs
        .iter()
        .map(|r| (r.name().to_string(), r.seed))
        .collect();
    assert_eq!(
        seeds,
        [
            ("s-x", 1),
            ("s-x", 2),
            ("s-x", 3),
            ("s-y", 7),
            ("s-y", 8),
            ("s-y", 9)
        ]
        .map(|(n, s)| (n.to_string(), s))
    );
    let list = SeedList::parse("4,2").unwrap();
    assert_eq!(set.seeded(Some(&list)).unwrap().len(), 4);
    assert_eq!(set.comparisons[0].left.scenario, "s-x");
    assert_eq!(set.comparisons[0].right.scenario, "s-y");
    assert_eq!(set.comparisons[0].left.method, "evidential");
    // Seeds are checked, and a finding must name a variant and a method it runs.
    assert!(SeedList::parse("0").is_err() && SeedList::parse("1,1").is_err());
    assert!(SeedList::parse("x").is_err());
    let bad = text.replace("right = \"s-y\"", "right = \"z\"");
    assert!(ScenarioSet::parse(&bad, "s.toml")
        .unwrap_err()
        .to_string()
        .contains("no variant `z`"));
    let bad = text.replace("right = \"s-y\"", "right = \"y\"\nmethod = \"svm\"");
    assert!(ScenarioSet::parse(&bad, "s.toml").is_err());
    let bad = text.replace("seeds = 3", "seeds = []");
    assert!(ScenarioSet::parse(&bad, "s.toml")
        .unwrap_err()
        .to_string()
        .contains("empty"));
}

#[test]
fn a_checked_scenario_written_as_toml_reads_back_as_the_same_run() {
    let text = format!(
        "{BASE}[sweep.grid]\n\"sim.noise.sigma\" = [1.0, 3.0]\n[[faults]]\nkind = \"stuck\"\nfeatures = [\"size_line1\"]\nshare = 0.2\nvalue = 3.0\n"
    );
    let set = ScenarioSet::parse(&text, "t.toml").unwrap();
    for variant in &set.variants {
        let toml = variant.to_toml().unwrap();
        let again = ScenarioSet::parse(&toml, "again.toml").unwrap();
        assert_eq!(&again.base, variant);
        assert_eq!(again.base.to_toml().unwrap(), toml);
    }
}

#[test]
fn the_temporal_trackers_refuse_splitting_through_their_registry_checks() {
    for (method, section, expected) in [
        (
            "evidential_temporal",
            "track",
            "[track]: the temporal evidential tracker takes `selection` largest_subset or \
             lowest_conflict, not splitting: list the methods without \"evidential_temporal\"",
        ),
        (
            "continuous_temporal",
            "continuous",
            "[continuous]: the continuous tracker over time takes `selection` largest_subset or \
             lowest_conflict, not splitting: list the methods without \"continuous_temporal\"",
        ),
    ] {
        let text = format!(
            "name = \"s\"\nestimators = [\"{method}\"]\n[{section}]\n\
             selection = {{ policy = \"splitting\", min_size = 2 }}\n"
        );
        let error = ScenarioSet::parse(&text, "s.toml").unwrap_err().to_string();
        assert!(error.contains(expected), "{error}");
        let fine = text.replace("splitting", "lowest_conflict");
        assert!(ScenarioSet::parse(&fine, "s.toml").is_ok(), "{fine}");
    }
}

#[test]
fn a_variant_cannot_set_the_sweep_or_its_name() {
    for (set, needle) in [
        ("\"sweep.seeds\" = 5", "[sweep] section"),
        (
            "\"sweep.grid\" = { \"model.states\" = [2, 3] }",
            "[sweep] section",
        ),
        ("name = \"other\"", "`name` cannot be set"),
    ] {
        let text = format!("{BASE}\n[[sweep.variant]]\nname = \"v\"\nset = {{ {set} }}\n");
        let error = ScenarioSet::parse(&text, "t.toml").unwrap_err().to_string();
        assert!(
            error.contains("`v`") && error.contains(needle),
            "{set}: {error}"
        );
    }
    // Through a grid too.
    let text = format!("{BASE}\n[sweep.grid]\n\"sweep.seeds\" = [2, 3]\n");
    let error = ScenarioSet::parse(&text, "t.toml").unwrap_err().to_string();
    assert!(error.contains("[sweep] section"), "{error}");
}

#[test]
fn seeds_a_scenario_file_cannot_hold_are_refused() {
    let set = ScenarioSet::parse(BASE, "t.toml").unwrap();
    let largest = set.base.with_seed(MAX_SEED).unwrap();
    // The largest seed reads back from the TOML a run writes.
    let again = ScenarioSet::parse(&largest.to_toml().unwrap(), "again.toml").unwrap();
    assert_eq!(again.base.seed, MAX_SEED);
    let error = set.base.with_seed(MAX_SEED + 1).unwrap_err().to_string();
    assert!(
        error.contains("9223372036854775808") && error.contains("2^63"),
        "{error}"
    );
    let error = SeedList::parse(&format!("1,{}", u64::MAX)).unwrap_err();
    assert!(error.contains("2^63"), "{error}");
    // A count running past the largest seed is refused when the runs are made.
    let near = ScenarioSet::parse(
        &BASE.replace("seed = 3", &format!("seed = {MAX_SEED}")),
        "t",
    )
    .unwrap();
    let error = near
        .seeded(Some(&SeedList::Count(2)))
        .unwrap_err()
        .to_string();
    assert!(error.contains("2^63"), "{error}");
}

#[test]
fn ten_thousand_samples_with_the_default_estimators_are_refused_at_once() {
    // scale.toml's 100 × 100 sample mesh without its list of estimators: the defaults include
    // the GP and the continuous tracker, whose exact kernels would factor 10,000 samples.
    let text = r#"
name = "s"

[sample]
motion = { kind = "mesh", spacing = 0.19191919191919 }
"#;
    // Parsing checks every variant.
    let started = std::time::Instant::now();
    let error = ScenarioSet::parse(text, "s.toml").unwrap_err().to_string();
    assert!(
        started.elapsed().as_secs_f64() < 5.0,
        "{:?}",
        started.elapsed()
    );
    for part in [
        "10000 sample poses",
        "2500",
        "gp",
        "continuous",
        "estimators = [",
    ] {
        assert!(error.contains(part), "`{part}` missing from: {error}");
    }
    // Listing the estimators without them passes (as scale.toml does), and so does a mesh
    // within the limit with the defaults.
    let listed = format!("estimators = [\"evidential\", \"knn\", \"centre\"]\n{text}");
    ScenarioSet::parse(&listed, "s.toml").unwrap().variants[0]
        .check()
        .unwrap();
    let at_limit = text.replace("0.19191919191919", "0.39583333333333"); // 49 × 49 = 2,401
    ScenarioSet::parse(&at_limit, "s.toml").unwrap().variants[0]
        .check()
        .unwrap();
}
