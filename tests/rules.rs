//! Fusion rules (issue 30): every variant of `scenarios/rules.toml` meets its bands on seed 1,
//! as `evitrack sweep scenarios/rules.toml --check` checks them (135 runs; about a minute on 2
//! cores since the variants share their fits), and their files hold no undocumented non-finite
//! number.

use crate::run_every_variant;

#[test]
fn the_rules_sweep_meets_its_expectations() {
    let runs = run_every_variant("rules.toml");
    assert_eq!(runs.len(), 135);
    for (name, output) in &runs {
        let missed = output.summary.regressions();
        assert!(missed.is_empty(), "{name}: {missed:#?}");
    }
    crate::cli::outputs::scan_outputs(&runs);
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
