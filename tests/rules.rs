//! Fusion rules (issue 30): every variant of `scenarios/rules.toml` meets its bands on seed 1,
//! as `evitrack sweep scenarios/rules.toml --check` checks them (135 runs), and their files hold
//! no undocumented non-finite number. CI checks the variants in five groups, one test each, so
//! they run side by side; the groups share their simulations and fits through the process's
//! workbench (`crate::bench`), as one sweep shares them between its variants.

use crate::run_variants_where;

/// The groups, by setup prefix and conditions (`None`: every condition of the setup).
const GROUPS: [(&str, Option<&[&str]>); 5] = [
    ("e-", Some(&["clean", "stuck", "noise-burst"])),
    ("e-", Some(&["occluder-dark", "glare", "salt-pepper"])),
    ("n24-", None),
    ("cont-", None),
    ("ctemp-", None),
];

fn in_group(name: &str, (setup, conditions): (&str, Option<&[&str]>)) -> bool {
    let Some(rest) = name.strip_prefix(setup) else {
        return false;
    };
    conditions.is_none_or(|c| c.iter().any(|c| rest.starts_with(&format!("{c}-"))))
}

/// Runs group `index` of [`GROUPS`]: each variant meets its bands, its files are scanned.
fn check_group(index: usize, expected: usize) {
    let runs = run_variants_where("rules.toml", |name| in_group(name, GROUPS[index]));
    assert_eq!(runs.len(), expected, "group {:?}", GROUPS[index]);
    for (name, output) in &runs {
        let missed = output.summary.regressions();
        assert!(missed.is_empty(), "{name}: {missed:#?}");
    }
    crate::cli::outputs::scan_outputs(&runs);
}

#[test]
fn the_groups_hold_every_rules_variant_once() {
    let set = crate::load_scenario("rules.toml");
    assert_eq!(set.variants.len(), 135);
    for variant in &set.variants {
        let name = variant.name().strip_prefix("rules-").unwrap();
        let groups = GROUPS.iter().filter(|g| in_group(name, **g)).count();
        assert_eq!(groups, 1, "{name}");
    }
}

#[test]
fn the_rules_sweep_meets_its_expectations_on_e_under_feature_faults() {
    check_group(0, 30);
}

#[test]
fn the_rules_sweep_meets_its_expectations_on_e_under_image_faults() {
    check_group(1, 30);
}

#[test]
fn the_rules_sweep_meets_its_expectations_on_n24() {
    check_group(2, 15);
}

#[test]
fn the_rules_sweep_meets_its_expectations_with_the_continuous_tracker() {
    check_group(3, 36);
}

#[test]
fn the_rules_sweep_meets_its_expectations_with_the_continuous_tracker_over_time() {
    check_group(4, 24);
}

/// Loads a scenario whose `[track]` ends with `track`; the error's text.
fn scenario_error(track: &str) -> String {
    section_error("evidential", "track", track)
}

/// Loads a scenario of `method` whose `[section]` ends with `body`; the error's text.
fn section_error(method: &str, section: &str, body: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.toml");
    let text = format!(
        "name = \"s\"\nestimators = [\"{method}\"]\n[sample]\nmotion = {{ kind = \"mesh\", spacing = 1.0 }}\n\
         [[tests]]\nkind = \"lissajous\"\nfreq_x = 0.3\nfreq_y = 0.2\nduration = 1.0\nfps = 10.0\n\
         [model]\nstates = 24\n[features.barycentre]\nenabled = true\n[{section}]\n{body}\n"
    );
    std::fs::write(&path, text).unwrap();
    match evitrack::scenario::ScenarioSet::load(&path) {
        Ok(_) => String::new(),
        Err(e) => e.to_string(),
    }
}

#[test]
fn the_scenario_check_names_the_valid_rules_and_the_method_that_cannot_take_one() {
    let unknown = scenario_error("rule = \"dempstr\"");
    for name in [
        "dempster",
        "yager",
        "dubois_prade",
        "pcr6",
        "cautious",
        "murphy",
    ] {
        assert!(unknown.contains(name), "{unknown}");
    }
    let costly = scenario_error("combine = \"all\"\nrule = \"pcr6\"");
    assert!(
        costly.contains("evidential") && costly.contains("pcr6"),
        "{costly}"
    );
    assert!(scenario_error("combine = \"all\"\nrule = \"murphy\"").is_empty());
    let dogmatic = scenario_error("rule = \"cautious\"");
    assert!(dogmatic.contains("dogmatic"), "{dogmatic}");
}

#[test]
fn the_continuous_trackers_take_the_rules_for_consonant_contours_and_name_them() {
    for method in ["continuous", "continuous_temporal"] {
        for rule in [
            "yager",
            "pcr6",
            "dubois_prade",
            "disjunctive",
            "murphy",
            "conjunctive",
        ] {
            let refused = section_error(method, "continuous", &format!("rule = \"{rule}\""));
            assert!(
                refused.contains(rule)
                    && refused.contains("dempster")
                    && refused.contains("cautious"),
                "{method}: {refused}"
            );
        }
        for ok in [
            "rule = \"cautious\"",
            "combine = \"all\"\ndiscount = \"learned\"",
            "discount = 0.5",
        ] {
            assert!(
                section_error(method, "continuous", ok).is_empty(),
                "{method} {ok}"
            );
        }
        let vacuous = section_error(method, "continuous", "discount = 0.0");
        assert!(vacuous.contains("continuous.discount"), "{vacuous}");
    }
}
