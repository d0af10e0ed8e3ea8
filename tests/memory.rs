//! Memory known before use (issue 29, item 4): the estimate against measured peaks, the refusal,
//! the reproducer under an address-space limit, and the shared grid changing nothing.

use std::path::Path;
use std::process::Command;

use evitrack::memory::of_run;
use evitrack::scenario::ScenarioSet;

/// A tiny scenario with a validation motion, running the three methods that fit the surrogates.
fn surrogate_scenario(name: &str, estimators: &str, extra: &str) -> String {
    let circle = "kind = \"circle\"\nradius = 4.0\nspeed = 10.0\nduration = 2.0\nfps = 10.0\n";
    format!(
        "name = \"{name}\"\nestimators = [{estimators}]\n[sample]\n\
         motion = {{ kind = \"mesh\", spacing = 2.0 }}\n[validation]\n{circle}[[tests]]\n{circle}{extra}"
    )
}

const THREE: &str = "\"continuous\", \"continuous_temporal\", \"particle_filter\"";

fn estimate_mib(path: &Path) -> f64 {
    let set = ScenarioSet::load(path).expect("the scenario is valid");
    of_run(&set.base).expect("estimated").total() as f64 / (1u64 << 20) as f64
}

/// Peak RSS (MiB) of `evitrack ARGS` by GNU time, or `None` where it is not installed.
fn peak_rss_mib(args: &[&str]) -> Option<f64> {
    if !Path::new("/usr/bin/time").is_file() {
        return None;
    }
    let out = Command::new("/usr/bin/time")
        .args(["-f", "peak %M"])
        .arg(env!("CARGO_BIN_EXE_evitrack"))
        .args(args)
        .output()
        .expect("time runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    let kb: f64 = stderr
        .lines()
        .rev()
        .find_map(|l| l.strip_prefix("peak ")?.parse().ok())?;
    Some(kb / 1024.0)
}

#[test]
fn the_estimate_is_above_the_measured_peak_and_within_twice_it() {
    let dir = tempfile::tempdir().unwrap();
    // Measured (GNU time, MiB): tiny 23.1 against 34 estimated, the 0.02 mm grid 278 against
    // 380 (20,000 particles; 177 against 268 before the particle filter's regrouped copy of
    // the table: this test caught the copy uncounted), coarse.toml 29.3 against 35, paper.toml
    // 79.6 against 88 (88 against 87 while the render check held every sample's silhouette
    // beside the fields: caught here too).
    let shipped = |file: &str| {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenarios")
            .join(file)
    };
    for (name, extra) in [
        ("tiny", ""),
        ("fine", "[continuous]\ngrid_spacing = 0.02\n"),
        ("coarse", ""),
        ("paper", ""),
    ] {
        let path = match extra.is_empty() && name != "tiny" {
            true => shipped(&format!("{name}.toml")),
            false => {
                let path = dir.path().join(format!("{name}.toml"));
                std::fs::write(&path, surrogate_scenario(name, THREE, extra)).unwrap();
                path
            }
        };
        let out = dir.path().join(format!("out-{name}"));
        let args = [
            "run",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        let Some(peak) = peak_rss_mib(&args) else {
            eprintln!("no /usr/bin/time: the peak is not measured");
            return;
        };
        let estimate = estimate_mib(&path);
        assert!(
            peak <= estimate && estimate <= 2.0 * peak,
            "{name}: estimated {estimate:.0} MiB, measured {peak:.0} MiB"
        );
    }
}

#[test]
fn over_the_limit_exits_2_naming_the_setting_before_writing_anything() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fine.toml");
    let extra = "[continuous]\ngrid_spacing = 0.02\n";
    std::fs::write(&path, surrogate_scenario("fine", THREE, extra)).unwrap();
    let out = dir.path().join("out");
    let run = crate::cli::evitrack(
        &[
            "run",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--memory-limit",
            "100MiB",
        ],
        "",
    );
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    for needed in [
        "over the memory limit of 100 MiB",
        "`continuous.grid_spacing = 0.02`",
        "951 × 951 nodes × 6 features",
        "`--memory-limit`",
    ] {
        assert!(stderr.contains(needed), "`{needed}` missing: {stderr}");
    }
    assert!(!out.exists(), "refused before the run's folder was made");
    let bad = crate::cli::evitrack(&["run", "--memory-limit", "lots"], "");
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("memory limit `lots`"));
}

/// The reproducer: a 0.02 mm grid in a 2-variant sweep on 2 jobs under a 2 GB
/// address-space limit aborted (exit 134); 8 variants on 8 jobs would too.
#[test]
fn a_fine_grid_sweep_under_2_gb_of_address_space_finishes_or_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    for variants in [2, 8] {
        let mut text = surrogate_scenario("fine", THREE, "[continuous]\ngrid_spacing = 0.02\n");
        for v in 1..=variants {
            // Distinct grids, so no two runs share one.
            text += &format!(
                "[[sweep.variant]]\nname = \"v{v}\"\nset = {{ \"continuous.grid_spacing\" = 0.02{v:02} }}\n"
            );
        }
        let path = dir.path().join(format!("sweep{variants}.toml"));
        std::fs::write(&path, text).unwrap();
        let out = dir.path().join(format!("out{variants}"));
        let command = format!(
            "ulimit -v 2000000; exec '{}' sweep '{}' --jobs {variants} --out '{}'",
            env!("CARGO_BIN_EXE_evitrack"),
            path.display(),
            out.display()
        );
        let result = Command::new("bash")
            .args(["-c", &command])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr);
        let code = result.status.code();
        assert!(
            matches!(code, Some(0 | 2)),
            "{variants} variants: {code:?}: {stderr}"
        );
        if code == Some(2) {
            assert!(stderr.contains("continuous.grid_spacing"), "{stderr}");
        }
        if variants == 2 {
            assert_eq!(code, Some(0), "two runs of 200 MiB fit in 2 GB: {stderr}");
        }
    }
}

/// One run shares one grid between the three methods: every number is as when each method
/// runs alone (in its own process, where nothing can be shared).
#[test]
fn sharing_the_grid_changes_no_number() {
    let dir = tempfile::tempdir().unwrap();
    let frames = |name: &str, estimators: &str| -> Vec<String> {
        let path = dir.path().join(format!("{name}.toml"));
        std::fs::write(&path, surrogate_scenario("s", estimators, "")).unwrap();
        let out = dir.path().join(name);
        crate::cli::run_expecting("run", &path, &out, 0);
        let text = std::fs::read_to_string(out.join("s/frames.csv")).unwrap();
        text.lines().skip(1).map(str::to_string).collect()
    };
    let together = frames("together", THREE);
    let mut alone = Vec::new();
    for method in ["continuous", "continuous_temporal", "particle_filter"] {
        alone.extend(frames(method, &format!("\"{method}\"")));
    }
    assert_eq!(together.len(), 60);
    assert_eq!(together, alone);
}
