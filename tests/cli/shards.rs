//! What `sweep` and `merge` refuse: shards missing, repeated or of another sweep, zero jobs,
//! seeds a scenario file cannot hold.

use super::*;

#[test]
fn merge_takes_every_shard_of_one_sweep_exactly_once() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("grid.toml");
    let extra = "[expect]\nmax_mean_error = 0.001\n[sweep.grid]\n\"model.states\" = [2, 3, 4]\n";
    std::fs::write(&scenario, small_scenario("grid", extra)).unwrap();
    let scenario = scenario.to_str().unwrap();
    let shard = |name: &str, shard: &str, seeds: &str| {
        let out_dir = dir.path().join(name);
        let mut args = vec!["sweep", scenario, "--shard", shard, "--jobs", "2"];
        args.extend(["--out", out_dir.to_str().unwrap()]);
        if !seeds.is_empty() {
            args.extend(["--seeds", seeds]);
        }
        let out = evitrack(&args, "");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let i = &shard[..1];
        let n = &shard[2..];
        let file = out_dir.join(format!("sweep-shard-{i}-of-{n}.json"));
        file.to_str().unwrap().to_string()
    };
    let (one, two, three) = (
        shard("a", "1/3", ""),
        shard("b", "2/3", ""),
        shard("c", "3/3", ""),
    );
    // One run of a sweep of the same file with 2 seeds: 6 runs, not 3.
    let foreign = shard("d", "2/3", "2");
    let merged = dir.path().join("merged");
    let merge = |files: &[&str], check: bool| {
        let mut args = vec!["merge"];
        args.extend(files);
        args.extend(["--out", merged.to_str().unwrap()]);
        if check {
            args.push("--check");
        }
        evitrack(&args, "")
    };
    for (files, needle) in [
        (
            vec![one.as_str(), two.as_str()],
            "shard(s) 3/3 of this sweep are missing",
        ),
        (
            vec![one.as_str()],
            "shard(s) 2/3, 3/3 of this sweep are missing",
        ),
        (
            vec![one.as_str(), two.as_str(), two.as_str(), three.as_str()],
            "shard 2 of 3 is given twice",
        ),
        (
            vec![one.as_str(), foreign.as_str(), three.as_str()],
            "of another sweep",
        ),
    ] {
        let out = merge(&files, true);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{files:?}: {stderr}");
        assert!(stderr.contains(needle), "{files:?}: {stderr}");
        assert!(!stderr.contains("meet their expectations"), "{stderr}");
        assert!(!merged.join("sweep.json").exists());
    }
    // A plain sweep.json is not a shard.
    let whole = dir.path().join("whole");
    let out = evitrack(&["sweep", scenario, "--out", whole.to_str().unwrap()], "");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let plain = whole.join("sweep.json");
    let out = merge(&[plain.to_str().unwrap()], false);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not the result of `sweep --shard`"));
    // All three, in any order: the whole sweep, and the check judges every run of it.
    let out = merge(&[three.as_str(), one.as_str(), two.as_str()], true);
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        std::fs::read(merged.join("sweep.json")).unwrap(),
        std::fs::read(&plain).unwrap()
    );
}

#[test]
fn zero_jobs_and_seeds_beyond_toml_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("s.toml");
    std::fs::write(&scenario, small_scenario("s", "")).unwrap();
    let (scenario, out_dir) = (scenario.to_str().unwrap(), dir.path().join("out"));
    let out_text = out_dir.to_str().unwrap();
    let out = evitrack(&["sweep", scenario, "--jobs", "0", "--out", out_text], "");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("at least 1"));
    let too_large = (1u64 << 63).to_string();
    for args in [
        vec![
            "run",
            scenario,
            "--seed",
            too_large.as_str(),
            "--out",
            out_text,
        ],
        vec![
            "sweep",
            scenario,
            "--seeds",
            "1,9223372036854775808",
            "--out",
            out_text,
        ],
    ] {
        let out = evitrack(&args, "");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains("2^63"), "{args:?}: {stderr}");
    }
    assert!(!out_dir.join("s").exists(), "nothing ran");
}
