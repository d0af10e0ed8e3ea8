//! Features from any language (issue 28): a feature program enters `run`, `sweep`, `features`,
//! `train` and `track`; its failures are named; its output is cached.
//!
//! The program that works is the crate's example `external_feature` (what
//! `examples/features/centroid.py` computes, so no Python is needed): built here with the cargo
//! that runs the tests, into the same target folder and profile, since `cargo test --test main`
//! alone does not build examples. The failing programs are `sh` one-liners.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// The example feature program, built once per test run.
fn example_program() -> &'static Path {
    static PROGRAM: OnceLock<PathBuf> = OnceLock::new();
    PROGRAM.get_or_init(|| {
        // The test binary is `<target>/<profile>/deps/main-…`.
        let exe = std::env::current_exe().expect("the test binary's path");
        let profile_dir = exe
            .parent()
            .and_then(Path::parent)
            .expect("<target>/<profile>");
        let target = profile_dir.parent().expect("<target>");
        let mut build = Command::new(env!("CARGO"));
        build.args(["build", "--quiet", "--example", "external_feature"]);
        build.arg("--manifest-path");
        build.arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml"));
        build.arg("--target-dir").arg(target);
        match profile_dir.file_name().and_then(|n| n.to_str()) {
            Some("debug") => {}
            Some(profile) => {
                build.args(["--profile", profile]);
            }
            None => panic!("no profile folder in {}", exe.display()),
        }
        let status = build.status().expect("cargo starts");
        assert!(status.success(), "building the example failed");
        let program = profile_dir
            .join("examples")
            .join(format!("external_feature{}", std::env::consts::EXE_SUFFIX));
        assert!(program.is_file(), "{} was not built", program.display());
        program
    })
}

/// `evitrack ARGS` with its program cache in `cache` (`None`: no cache).
fn evitrack(args: &[&str], cache: Option<&Path>) -> Output {
    Command::new(env!("CARGO_BIN_EXE_evitrack"))
        .args(args)
        .env("EVITRACK_CACHE_DIR", cache.map_or(Path::new(""), |c| c))
        .output()
        .expect("evitrack runs")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A TOML string of `text`.
fn toml_str(text: &str) -> String {
    format!("{text:?}")
}

/// A program's settings: `command`, then the rest of the table.
fn program_toml(command: &[&str], rest: &str) -> String {
    let command: Vec<String> = command.iter().map(|c| toml_str(c)).collect();
    format!("command = [{}]\n{rest}\n", command.join(", "))
}

/// The example program behind `sh`, counting its runs in `count`.
fn counted_example(count: &Path) -> Vec<String> {
    vec![
        "sh".into(),
        "-c".into(),
        format!(
            "echo run >> '{}'; exec '{}' \"$0\"",
            count.display(),
            example_program().display()
        ),
    ]
}

fn runs(count: &Path) -> usize {
    std::fs::read_to_string(count).map_or(0, |t| t.lines().count())
}

fn simulate(dir: &Path, name: &str, motion: &str) -> PathBuf {
    let out = dir.join(name);
    let status = evitrack(
        &[
            "simulate",
            "--out",
            out.to_str().unwrap(),
            "--motion",
            motion,
        ],
        None,
    );
    assert!(status.status.success(), "{}", stderr(&status));
    out
}

#[test]
fn a_program_enters_features_train_and_track_and_is_cached() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let count = dir.path().join("count");
    let sample = simulate(dir.path(), "sample", "kind = \"mesh\", spacing = 2");
    let test = simulate(
        dir.path(),
        "test",
        "kind = \"circle\", radius = 4, speed = 10, duration = 1, fps = 10",
    );
    let command = counted_example(&count);
    let command: Vec<&str> = command.iter().map(String::as_str).collect();
    let program = dir.path().join("centroid.toml");
    let values = "values = [\"centroid_x\", \"centroid_y\"]\nmissing = \"allowed\"";
    std::fs::write(&program, program_toml(&command, values)).unwrap();
    let program = program.to_str().unwrap();

    let features = |cache| {
        evitrack(
            &[
                "features",
                test.to_str().unwrap(),
                "--feature-program",
                program,
            ],
            cache,
        )
    };
    let out = features(Some(&cache));
    assert!(out.status.success(), "{}", stderr(&out));
    let csv = String::from_utf8_lossy(&out.stdout).into_owned();
    let header = csv.lines().next().unwrap();
    assert!(
        header.contains("size_line5,centroid_x,centroid_y,x,y"),
        "{header}"
    );
    assert_eq!(csv.lines().count(), 11);
    // The values are the program's own output, to the bit.
    let own = Command::new(example_program()).arg(&test).output().unwrap();
    let own = String::from_utf8_lossy(&own.stdout).into_owned();
    let second_row: Vec<&str> = csv.lines().nth(2).unwrap().split(',').collect();
    let own_row: Vec<&str> = own.lines().nth(2).unwrap().split(',').collect();
    assert_eq!(&second_row[8..10], &own_row[1..3]);
    assert_eq!(runs(&count), 1);
    // A hit skips the program; without the cache it runs again.
    let again = features(Some(&cache));
    assert_eq!(again.stdout, out.stdout);
    assert_eq!(runs(&count), 1, "the second call is a cache hit");
    assert_eq!(features(None).stdout, out.stdout);
    assert_eq!(runs(&count), 2);

    let model = dir.path().join("model.json");
    let out = evitrack(
        &[
            "train",
            sample.to_str().unwrap(),
            "--out",
            model.to_str().unwrap(),
            "--states",
            "2",
            "--feature-program",
            program,
        ],
        Some(&cache),
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    assert_eq!(json["features"][7]["name"], "centroid_y");
    assert_eq!(
        json["feature_config"]["external"][0]["values"][0],
        "centroid_x"
    );
    // A model file runs no program by itself.
    let track = |extra: &[&str]| {
        let mut args = vec![
            "track",
            test.to_str().unwrap(),
            "--model",
            model.to_str().unwrap(),
        ];
        args.extend(extra);
        evitrack(&args, Some(&cache))
    };
    let out = track(&[]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("--feature-program") && stderr(&out).contains("sh -c"),
        "{}",
        stderr(&out)
    );
    let out = track(&["--feature-program", program]);
    assert!(out.status.success(), "{}", stderr(&out));
    let estimates = String::from_utf8_lossy(&out.stdout).into_owned();
    assert_eq!(estimates.lines().count(), 11, "{estimates}");
    assert!(stderr(&out).contains("error mean"), "{}", stderr(&out));
    // Programs giving other values are refused.
    let other = dir.path().join("other.toml");
    std::fs::write(&other, program_toml(&command, "values = [\"cx\", \"cy\"]")).unwrap();
    let out = track(&["--feature-program", other.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("[\"cx\", \"cy\"]"),
        "{}",
        stderr(&out)
    );
}

/// A small scenario whose features include `command`'s, with a fault on the images and one on
/// the program's first value.
fn scenario(command: &[String]) -> String {
    let command: Vec<String> = command.iter().map(|c| toml_str(c)).collect();
    format!(
        "name = \"ext\"\nestimators = [\"evidential\", \"knn\"]\n\
         [sample]\nmotion = {{ kind = \"mesh\", spacing = 2.0 }}\n\
         [[tests]]\nkind = \"circle\"\nradius = 4.0\nspeed = 10.0\nduration = 2.0\nfps = 10.0\n\
         [model]\nstates = 2\n\
         [[features.external]]\ncommand = [{}]\nvalues = [\"centroid_x\", \"centroid_y\"]\n\
         missing = \"allowed\"\n\
         [[faults]]\nkind = \"occluder\"\nrect = [38, 12, 48, 48]\nintensity = 0\nshare = 0.3\n\
         [[faults]]\nkind = \"stuck\"\nfeatures = [\"centroid_x\"]\nvalue = 3.0\nshare = 0.2\n\
         [[sweep.variant]]\nname = \"consonant\"\nset = {{ \"track.constructor\" = \"consonant\" }}\n",
        command.join(", ")
    )
}

#[test]
fn a_scenario_with_a_program_runs_and_sweeps_from_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let count = dir.path().join("count");
    let file = dir.path().join("ext.toml");
    std::fs::write(&file, scenario(&counted_example(&count))).unwrap();
    let out_dir = dir.path().join("out");
    let out = evitrack(
        &[
            "run",
            file.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ],
        Some(&cache),
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("ext/results.json")).unwrap())
            .unwrap();
    assert_eq!(results["features"][6], "centroid_x");
    assert_eq!(results["frames"], 20);
    // The sample, validation and test motions, then the test frames the occluder changed.
    assert_eq!(runs(&count), 4);
    let sweep_dir = dir.path().join("sweep");
    let out = evitrack(
        &[
            "sweep",
            file.to_str().unwrap(),
            "--out",
            sweep_dir.to_str().unwrap(),
        ],
        Some(&cache),
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let sweep = std::fs::read_to_string(sweep_dir.join("sweep.json")).unwrap();
    assert!(sweep.contains("ext-consonant"), "{sweep}");
    assert_eq!(runs(&count), 4, "every frame of the sweep was in the cache");
    // A failing program stops the run with status 2, named.
    let failing = vec![
        "sh".to_string(),
        "-c".into(),
        "echo no camera >&2; exit 3".into(),
    ];
    std::fs::write(&file, scenario(&failing)).unwrap();
    let out = evitrack(
        &[
            "run",
            file.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ],
        None,
    );
    assert_eq!(out.status.code(), Some(2));
    let message = stderr(&out);
    assert!(
        message.contains("feature program `sh -c echo no camera >&2; exit 3` failed"),
        "{message}"
    );
    assert!(message.contains("no camera"), "{message}");
}

#[test]
fn every_failure_of_a_program_is_named_with_its_row() {
    let dir = tempfile::tempdir().unwrap();
    let data = simulate(
        dir.path(),
        "data",
        "kind = \"circle\", radius = 4, speed = 10, duration = 0.3, fps = 10",
    );
    let header = "printf 'frame,a,b\\n";
    for (script, rest, expected) in [
        (
            format!("{header}0,1,2\\n1,1,2\\n'"),
            "",
            "wrote 2 rows for 3 frames",
        ),
        (
            format!("{header}0,1,2\\n1,1,2\\n2,1,2\\n3,1,2\\n'"),
            "",
            "wrote 4 rows for 3 frames",
        ),
        (
            "printf 'frame,a,c\\n'".into(),
            "",
            "line 1 (the header): column `c` is not a declared value",
        ),
        (
            "printf 'frame,a\\n'".into(),
            "",
            "no column for the declared value `b`",
        ),
        (
            format!("{header}0,1,2\\n1,nan,2\\n2,1,2\\n'"),
            "",
            "line 3 (frame 1), column `a`: `nan` is not finite",
        ),
        (
            format!("{header}0,1,2\\n1,1,2\\n2,1,\\n'"),
            "",
            "line 4 (frame 2), column `b`: the value is missing",
        ),
        (
            "echo cannot read frames >&2; exit 4".into(),
            "",
            "failed (exit status: 4); the end of its stderr:\ncannot read frames",
        ),
        (
            "sleep 5".into(),
            "timeout_seconds = 0.3",
            "was still running after 0.3 s and was stopped",
        ),
    ] {
        let program = dir.path().join("p.toml");
        let rest = format!("values = [\"a\", \"b\"]\n{rest}");
        std::fs::write(&program, program_toml(&["sh", "-c", &script], &rest)).unwrap();
        let out = evitrack(
            &[
                "features",
                data.to_str().unwrap(),
                "--feature-program",
                program.to_str().unwrap(),
            ],
            None,
        );
        assert_eq!(out.status.code(), Some(2), "{script}");
        let message = stderr(&out);
        assert!(
            message.contains(&format!("feature program `sh -c {script}`")),
            "{message}"
        );
        assert!(message.contains(expected), "{script}: {message}");
    }
    // The same missing value is a missing feature when the program declares it may be.
    let program = dir.path().join("p.toml");
    let script = format!("{header}0,1,2\\n1,1,2\\n2,1,NA\\n'");
    std::fs::write(
        &program,
        program_toml(
            &["sh", "-c", &script],
            "values = [\"a\", \"b\"]\nmissing = \"allowed\"",
        ),
    )
    .unwrap();
    let out = evitrack(
        &[
            "features",
            data.to_str().unwrap(),
            "--feature-program",
            program.to_str().unwrap(),
        ],
        None,
    );
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("1 missing values"),
        "{}",
        stderr(&out)
    );
    // Bad settings are refused before anything runs.
    std::fs::write(&program, program_toml(&["sh"], "values = [\"size_line0\"]")).unwrap();
    let out = evitrack(
        &[
            "features",
            data.to_str().unwrap(),
            "--feature-program",
            program.to_str().unwrap(),
        ],
        None,
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("size_line0"), "{}", stderr(&out));
}
