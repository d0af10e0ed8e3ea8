//! The scheduler scripts of `.ci/slurm/` (which the GitHub matrix workflow calls too), run with
//! plain bash as Slurm would run them: every array task, then the merge; their logs hold no
//! progress bars.

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `bash .ci/slurm/<script>` with `env`, run from `cwd` (outside the repository).
fn script(script: &str, cwd: &Path, env: &[(&str, &str)]) -> Command {
    let mut command = Command::new("bash");
    command
        .arg(repo().join(".ci/slurm").join(script))
        .current_dir(cwd)
        .env("EVITRACK", env!("CARGO_BIN_EXE_evitrack"));
    // The test's own environment must not choose the shard.
    for name in [
        "SHARD",
        "SHARDS",
        "SLURM_ARRAY_TASK_ID",
        "SLURM_ARRAY_TASK_COUNT",
    ] {
        command.env_remove(name);
    }
    command.envs(env.iter().copied());
    command
}

/// Runs the script as [`script`] and asserts that it succeeds with a clean log.
fn run_script(name: &str, cwd: &Path, env: &[(&str, &str)]) {
    let out = script(name, cwd, env).output().expect("bash runs");
    assert!(
        out.status.success(),
        "{name} {env:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_clean_log(&out.stderr);
}

/// A batch job's log (stderr is a file or a pipe there) holds no progress bars: no terminal
/// escapes, no bar or spinner characters.
fn assert_clean_log(stderr: &[u8]) {
    let text = String::from_utf8_lossy(stderr);
    assert!(
        !text.contains('\x1b') && !text.contains("[=") && !text.contains('⠁'),
        "{text:?}"
    );
}

#[test]
fn slurm_array_tasks_then_merge_give_the_unsharded_sweep() {
    let dir = tempfile::tempdir().unwrap();
    // Five quick variants (2 mm mesh, a 20-frame circle), so that three shards are uneven.
    let scenario = dir.path().join("grid.toml");
    std::fs::write(
        &scenario,
        "name = \"grid\"\n[sample]\nmotion = { kind = \"mesh\", spacing = 2.0 }\n\
         [[tests]]\nkind = \"circle\"\nradius = 4.0\nspeed = 10.0\nduration = 2.0\nfps = 10.0\n\
         [sweep.grid]\n\"model.states\" = [2, 3, 4, 5, 6]\n",
    )
    .unwrap();
    let scenario = scenario.to_str().unwrap();
    let sharded = dir.path().join("sharded");
    let sharded_text = sharded.to_str().unwrap();
    let shards = 3;
    let count = shards.to_string();
    for task in 0..shards {
        let id = task.to_string();
        let env = [
            ("SLURM_ARRAY_TASK_ID", id.as_str()),
            ("SLURM_ARRAY_TASK_COUNT", count.as_str()),
            ("SWEEP_FILE", scenario),
            ("SWEEP_OUT", sharded_text),
        ];
        run_script("sweep-array.sh", dir.path(), &env);
        let file = sharded.join(format!("shard-{task}/sweep-shard-{}-of-3.json", task + 1));
        assert!(file.is_file(), "{} missing", file.display());
    }
    let env = [("SHARDS", count.as_str()), ("SWEEP_OUT", sharded_text)];
    run_script("merge.sh", dir.path(), &env);

    let whole = dir.path().join("whole");
    let out = super::cli::evitrack(&["sweep", scenario, "--out", whole.to_str().unwrap()], "");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_clean_log(&out.stderr);
    for file in ["sweep.json", "sweep.csv"] {
        let merged = std::fs::read(sharded.join("merged").join(file)).unwrap();
        assert_eq!(merged, std::fs::read(whole.join(file)).unwrap(), "{file}");
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(whole.join("sweep.json")).unwrap()).unwrap();
    assert_eq!(json["runs"].as_array().unwrap().len(), 5);
}

#[test]
fn a_task_outside_the_array_and_a_missing_shard_fail() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let status = |name: &str, env: &[(&str, &str)]| {
        let output = script(name, dir.path(), env).env("SWEEP_OUT", out).output();
        output.unwrap().status.code()
    };
    let env = [
        ("SLURM_ARRAY_TASK_ID", "3"),
        ("SLURM_ARRAY_TASK_COUNT", "3"),
    ];
    assert_eq!(status("sweep-array.sh", &env), Some(2));
    // No shard has run: the merge names what is missing instead of merging fewer shards.
    assert_eq!(status("merge.sh", &[("SHARDS", "3")]), Some(2));
    // Without a task id (not an array task, no SHARD) the task refuses to guess.
    assert_ne!(status("sweep-array.sh", &[]), Some(0));
}

/// The workflow and the array script agree on the shard count and call the tested scripts.
#[test]
fn the_ci_matrix_and_the_array_match_the_scripts() {
    let workflow = std::fs::read_to_string(repo().join(".ci/github/sweep-matrix.yml")).unwrap();
    let array = std::fs::read_to_string(repo().join(".ci/slurm/sweep-array.sh")).unwrap();
    assert!(workflow.contains("shard: [0, 1, 2]"));
    assert!(workflow.contains("SHARDS: 3"));
    assert!(workflow.contains("bash .ci/slurm/sweep-array.sh"));
    assert!(workflow.contains("bash .ci/slurm/merge.sh"));
    assert!(workflow.contains("needs: shard"));
    assert!(array.contains("#SBATCH --array=0-2"));
    assert!(array.contains("SLURM_ARRAY_TASK_COUNT:-3"));
}

/// `submit.sh` sends `--check` to the merge, everything else to the array, and lets the merge
/// run after any end of the array (a failed shard is then named, not waited for): checked with
/// an `sbatch` stand-in that logs its arguments.
#[test]
fn submit_sends_check_to_the_merge_only() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("sbatch.log");
    let fake = dir.path().join("sbatch");
    std::fs::write(
        &fake,
        format!("#!/bin/sh\necho \"$*\" >> '{}'\necho 42\n", log.display()),
    )
    .unwrap();
    let chmod = Command::new("chmod").arg("+x").arg(&fake).status().unwrap();
    assert!(chmod.success());
    let path = format!(
        "{}:{}",
        dir.path().display(),
        std::env::var("PATH").unwrap()
    );
    let out = script("submit.sh", dir.path(), &[("PATH", path.as_str())])
        .args(["--seeds", "10", "--check"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let calls = std::fs::read_to_string(&log).unwrap();
    let lines: Vec<&str> = calls.lines().collect();
    assert_eq!(lines.len(), 2, "{calls}");
    assert!(lines[0].ends_with("sweep-array.sh --seeds 10"), "{calls}");
    assert!(lines[0].contains("--array=0-2"), "{calls}");
    assert!(lines[1].contains("--dependency=afterany:42"), "{calls}");
    assert!(lines[1].ends_with("merge.sh --check"), "{calls}");
}

/// A shard refuses `--check` before running anything: it would judge a slice of the sweep.
#[test]
fn a_shard_refuses_check() {
    let dir = tempfile::tempdir().unwrap();
    let env = [("SHARD", "0"), ("SHARDS", "3")];
    let out = script("sweep-array.sh", dir.path(), &env)
        .arg("--check")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("belongs on the merge"));
    assert!(std::fs::read_dir(dir.path()).unwrap().next().is_none());
}
