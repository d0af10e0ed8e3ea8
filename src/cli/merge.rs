//! `merge`: the shards of one sweep (`sweep --shard`), each exactly once, back in the sweep's
//! order.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::Args;

use super::ensure_writable;
use super::sweep::{finish_sweep, write_sweep_report, SweepFile};
use evitrack::report::{Comparison, RunSummary};
use evitrack::scenario::CheckedScenario;

#[derive(Debug, Args)]
pub struct MergeArgs {
    /// Shard result files (`sweep-shard-*.json`) written by `sweep --shard`.
    #[arg(required = true)]
    shards: Vec<PathBuf>,
    /// Output folder for the merged table, CSV, JSON and plots.
    #[arg(long)]
    out: PathBuf,
    /// Compare against the expectations; exit 1 with a list of what regressed.
    #[arg(long)]
    check: bool,
}

/// A fingerprint of a whole sweep, before it is sharded: every run's scenario as run (its
/// settings and seed), in order, hashed with 64-bit FNV-1a (stable across builds and machines,
/// unlike `std`'s hasher), with the run count.
pub(super) fn sweep_identity(runs: &[CheckedScenario]) -> Result<String> {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for run in runs {
        let text = run.to_toml()?;
        // The length first, so that no two lists of texts hash the same bytes.
        for byte in (text.len() as u64)
            .to_le_bytes()
            .iter()
            .chain(text.as_bytes())
        {
            hash ^= u64::from(*byte);
            hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    Ok(format!("{} runs, {hash:016x}", runs.len()))
}

pub fn merge(args: &MergeArgs) -> Result<ExitCode> {
    // Every shard of one sweep, each once: (shard index, summaries), by index.
    let mut shards: Vec<(usize, Vec<RunSummary>, &Path)> = Vec::new();
    let mut sweep: Option<(usize, String, &Path)> = None;
    let mut comparisons: Vec<Comparison> = Vec::new();
    for path in &args.shards {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let shard: SweepFile = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a sweep result file", path.display()))?;
        let (Some([i, n]), Some(identity)) = (shard.shard, shard.sweep) else {
            bail!(
                "{} is not the result of `sweep --shard` (or was written by an older evitrack): \
                 merge takes the sweep-shard-*.json files of one sharded sweep",
                path.display()
            );
        };
        if i >= n {
            bail!(
                "{} says it is shard {} of {n}, which cannot be",
                path.display(),
                i + 1
            );
        }
        match &sweep {
            None => sweep = Some((n, identity, path)),
            Some((count, first, first_path)) if (*count, first) != (n, &identity) => bail!(
                "{} is shard {} of {n} of another sweep than {} (shard count, scenario files or \
                 seeds differ: {identity} against {first}): merge the shards of one sweep",
                path.display(),
                i + 1,
                first_path.display()
            ),
            Some(_) => {}
        }
        if let Some((_, _, other)) = shards.iter().find(|(k, _, _)| *k == i) {
            bail!(
                "shard {} of {n} is given twice ({} and {}): merge each shard once",
                i + 1,
                other.display(),
                path.display()
            );
        }
        if !shard.complete {
            bail!(
                "{} is incomplete ({} runs without results: {}): run its sweep again to finish it",
                path.display(),
                shard.pending.len(),
                shard.pending.join(", ")
            );
        }
        for c in shard.comparisons {
            if !comparisons.contains(&c) {
                comparisons.push(c);
            }
        }
        shards.push((i, shard.runs, path));
    }
    let Some((n, _, _)) = sweep else {
        bail!("no shard files to merge");
    };
    let missing: Vec<String> = (0..n)
        .filter(|i| !shards.iter().any(|(k, _, _)| k == i))
        .map(|i| format!("{}/{n}", i + 1))
        .collect();
    if !missing.is_empty() {
        bail!(
            "shard(s) {} of this sweep are missing: run `sweep --shard` for them and merge all \
             {n} shard files",
            missing.join(", ")
        );
    }
    // Run k of shard i of n is run k·n + i of the sweep.
    let mut runs: Vec<(usize, RunSummary)> = Vec::new();
    for (i, summaries, _) in shards {
        runs.extend((summaries.into_iter().enumerate()).map(|(k, run)| (k * n + i, run)));
    }
    runs.sort_by_key(|(position, _)| *position);
    let summaries: Vec<RunSummary> = runs.into_iter().map(|(_, s)| s).collect();
    ensure_writable(&args.out)?;
    let file = SweepFile::new(summaries, Vec::new(), &comparisons);
    write_sweep_report(&args.out, "sweep.json", &file, &[])?;
    finish_sweep(&file.runs, &[], args.check)
}
