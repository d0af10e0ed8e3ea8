//! Confidence: `scenarios/confidence.toml` meets its expectations (coverage, abstentions and AURC
//! of every method, in both directions) and the README's statements on seed 1 hold: regions hold
//! about 90 % of clean frames, few clean frames abstain, the bright box and glare are abstained
//! on, and where the continuous tracker's AURC stands against the GP's.

use std::collections::HashMap;

use evitrack::estimator::RenderSource;
use evitrack::report::{ConfidenceSummary, RunSummary};
use evitrack::scenario::ScenarioSet;

/// The variants of `scenarios/confidence.toml` named in `variants`, each meeting its
/// expectations, their files without an undocumented non-finite number (the three tests run
/// every variant between them). Each test runs the variants it reads; their fits (shared by
/// every variant) come once from the process's workbench (`crate::bench`).
fn confidence_runs(variants: &[&str]) -> HashMap<String, RunSummary> {
    let runs = crate::run_variants("confidence.toml", Some(variants));
    crate::cli::outputs::scan_outputs(&runs);
    let runs: HashMap<_, _> = runs
        .into_iter()
        .map(|(name, output)| (name, output.summary))
        .collect();
    for (name, run) in &runs {
        let missed = run.regressions();
        assert!(missed.is_empty(), "{name}: {missed:#?}");
    }
    runs
}

fn confidence<'a>(
    runs: &'a HashMap<String, RunSummary>,
    variant: &str,
    method: &str,
) -> &'a ConfidenceSummary {
    runs[&format!("confidence-{variant}")]
        .method(method)
        .and_then(|m| m.confidence.as_ref())
        .unwrap_or_else(|| panic!("{variant}: {method} has no confidence summary"))
}

const WITH_REGIONS: [&str; 7] = [
    "evidential",
    "evidential_temporal",
    "continuous",
    "continuous_temporal",
    "knn",
    "gp",
    "particle_filter",
];

/// On 200 clean frames of a test motion of the calibration motion's kind, every method's 90 %
/// regions hold 0.83–0.96 of them (seed 1; over 5 seeds the README's 0.86–0.92), variants with
/// fewer than 100 clean frames left out (a moving occluder leaves 11).
pub(crate) fn assert_regions_calibrated<'a>(summaries: impl IntoIterator<Item = &'a RunSummary>) {
    let mut checked = 0;
    for summary in summaries {
        for method in &summary.methods {
            let clean_frames =
                summary.frames - method.faults.as_ref().map_or(0, |f| f.corrupted_frames);
            let Some(coverage) = method.confidence.as_ref().and_then(|c| c.coverage_clean) else {
                continue;
            };
            if clean_frames < 100 {
                continue;
            }
            assert!(
                (0.83..=0.96).contains(&coverage),
                "{} {}: coverage {coverage} of {clean_frames} clean frames",
                summary.scenario,
                method.method
            );
            checked += 1;
        }
    }
    assert!(checked > 0, "no method gave regions");
}

#[test]
fn the_confidence_sweep_on_clean_frames_meets_its_expectations_and_the_readme_statements() {
    let runs = confidence_runs(&["clean"]);
    let frames = runs["confidence-clean"].frames as f64;
    for method in WITH_REGIONS {
        // Calibrated on the validation motion, the regions hold about 90 % of clean frames, and
        // a method abstains on at most 2 % of them.
        let clean = confidence(&runs, "clean", method);
        let coverage = clean.coverage_clean.expect("regions");
        assert!((0.85..=0.95).contains(&coverage), "{method}: {coverage}");
        assert!(
            clean.abstained_clean as f64 <= 0.02 * frames,
            "{method}: {clean:?}"
        );
        // Ranked by its own doubt, its surest frames are its better ones.
        assert!(
            clean.all.aurc < clean.all.curve[19],
            "{method}: {:?}",
            clean.all
        );
        assert!(clean.all.oracle_aurc <= clean.all.aurc);
    }
    // The centre says nothing: a flat curve and no region.
    let centre = confidence(&runs, "clean", "centre");
    assert!(centre
        .all
        .curve
        .iter()
        .all(|&r| (r - centre.all.aurc).abs() < 1e-9 * r));
    assert_eq!(centre.coverage_clean, None);
}

#[test]
fn the_confidence_sweep_under_a_bright_box_and_glare_meets_the_readme_statements() {
    let runs = confidence_runs(&["bright-box", "glare"]);
    // Every method with regions abstains on (nearly) every bright-box and glare frame (seed 1:
    // 113–114 of 114); so none answers those frames with a confident error.
    for variant in ["bright-box", "glare"] {
        let struck = runs[&format!("confidence-{variant}")]
            .method("evidential")
            .and_then(|m| m.faults.as_ref())
            .map(|f| f.corrupted_frames)
            .expect("faults");
        for method in WITH_REGIONS {
            let c = confidence(&runs, variant, method);
            assert!(
                c.abstained_corrupted as f64 >= 0.97 * struck as f64,
                "{variant} {method}: {} of {struck}",
                c.abstained_corrupted
            );
        }
    }
    // The continuous tracker's AURC over all frames is below the GP's under the bright box and
    // glare (and salt-and-pepper, below).
    for variant in ["bright-box", "glare"] {
        assert_aurc_below_the_gps(&runs, variant);
    }
}

fn assert_aurc_below_the_gps(runs: &HashMap<String, RunSummary>, variant: &str) {
    let aurc = |method: &str| confidence(runs, variant, method).all.aurc;
    assert!(
        aurc("continuous") < 0.7 * aurc("gp"),
        "{variant}: {} against {}",
        aurc("continuous"),
        aurc("gp")
    );
}

#[test]
fn the_confidence_sweep_under_salt_and_pepper_and_a_dark_box_meets_the_readme_statements() {
    let runs = confidence_runs(&["salt-pepper", "occluder-dark", "occluder-dark-unchecked"]);
    assert_aurc_below_the_gps(&runs, "salt-pepper");
    assert_the_render_check_catches_the_dark_box(&runs);
    // Under the dark occluder the continuous tracker's AURC is the GP's within 0.8–1.35×, with
    // the check (default; 1.05 on seed 1) as without it (1.19); without it, the continuous
    // tracker's regions miss more than a tenth of the struck frames.
    let aurc = |variant: &str, method: &str| confidence(&runs, variant, method).all.aurc;
    for variant in ["occluder-dark", "occluder-dark-unchecked"] {
        let dark = aurc(variant, "continuous_temporal") / aurc(variant, "gp");
        assert!((0.8..=1.35).contains(&dark), "{variant}: {dark}");
    }
    let dark_cover = confidence(&runs, "occluder-dark-unchecked", "continuous").coverage_corrupted;
    assert!(dark_cover.unwrap() < 0.9, "{dark_cover:?}");
    // The GP's and k-NN's detection score (the frame's features' distance from the samples' at
    // its answer) flags salt-and-pepper frames: their regions or abstentions hold nearly all of
    // them (k-NN's 0.75 with the nearest sample's distance as its score).
    for method in ["gp", "knn"] {
        let c = confidence(&runs, "salt-pepper", method);
        assert!(c.coverage_corrupted.unwrap() >= 0.9, "{method}: {c:?}");
    }
}

/// With the render check (on by default) the continuous tracker, the GP and the particle filter
/// cover or abstain on more than 0.90 of the dark box's struck frames (without it 0.77–0.89 on
/// seed 1), while each abstains on at most 2 % of the clean frames, the check's and its own
/// rule's. The silhouettes come from the sample frames, not the simulator's renderer.
fn assert_the_render_check_catches_the_dark_box(runs: &HashMap<String, RunSummary>) {
    let checked = &runs["confidence-occluder-dark"];
    let unchecked = &runs["confidence-occluder-dark-unchecked"];
    assert!(unchecked.methods.iter().all(|m| m.render_check.is_none()));
    for method in ["continuous", "gp", "particle_filter"] {
        let before = confidence(runs, "occluder-dark-unchecked", method);
        let after = confidence(runs, "occluder-dark", method);
        let (was, now) = (
            before.coverage_corrupted.unwrap(),
            after.coverage_corrupted.unwrap(),
        );
        assert!(now > 0.9 && now > was, "{method}: {was} → {now}");
        let summary = checked.method(method).expect("checked");
        let clean =
            (checked.frames - summary.faults.as_ref().expect("faults").corrupted_frames) as f64;
        let render = summary.render_check.as_ref().expect("a render check");
        assert!(
            render.limit_px.is_some_and(|l| l < 200.0)
                && render.calibration_frames == 400
                && render.from == RenderSource::Samples,
            "{method}: {render:?}"
        );
        assert!(
            render.abstained_clean as f64 <= 0.02 * clean,
            "{method}: {render:?}"
        );
        assert!(
            after.abstained_clean as f64 <= 0.02 * clean,
            "{method}: {after:?}"
        );
    }
    // The centre has no estimate of its own to check.
    assert!(checked
        .method("centre")
        .is_some_and(|m| m.render_check.is_none()));
}

/// Left out of a scenario, the render check runs where the calibration motion can learn its
/// limit (199 frames at the default share) and stays out, without an error, where it cannot:
/// too few calibration frames, or sample frames without a silhouette. Asked for there, the run
/// says why it cannot.
#[test]
fn the_default_render_check_runs_where_it_can_be_learned_and_stays_out_elsewhere() {
    let scenario = |seconds: f64, silhouettes: bool, asked: bool| {
        let contrast = if silhouettes { 20.0 } else { 255.0 };
        let text = format!(
            r#"
name = "default-check"
estimators = ["knn"]
tests = [{{ kind = "circle", radius = 4.0, speed = 8.0, duration = 1.5, fps = 10.0 }}]
[sample]
motion = {{ kind = "mesh", spacing = 2.0 }}
[validation]
kind = "random_path"
seed = 11
speed = 6.0
duration = {seconds:?}
fps = 20.0
[features.silhouette]
min_contrast = {contrast:?}
[features.size_functions]
enabled = false
[features.barycentre]
enabled = true
{}
"#,
            if asked {
                "[confidence]\nrender_check = true"
            } else {
                ""
            }
        );
        ScenarioSet::parse(&text, "default-check.toml")
            .expect("valid")
            .base
    };
    let run = |s| evitrack::experiment::run(&s, crate::bench(), &mut |_, _, _| {});
    let check = |s| {
        let output = run(s).expect("the run succeeds");
        output.summary.methods[0].render_check.clone()
    };
    let on = check(scenario(10.0, true, false)).expect("on by default on 200 frames");
    assert_eq!(
        (on.calibration_frames, on.from),
        (200, RenderSource::Samples)
    );
    assert!(on.limit_px.is_some());
    assert!(
        check(scenario(9.5, true, false)).is_none(),
        "190 frames: off"
    );
    assert!(
        check(scenario(10.0, false, false)).is_none(),
        "no silhouette: off"
    );
    let refused = run(scenario(10.0, false, true)).expect_err("asked for, it cannot run");
    assert!(refused.to_string().contains("fewer than 3"), "{refused}");
}
