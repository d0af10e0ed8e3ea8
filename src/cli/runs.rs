//! Commands that run scenarios: `run` (here), `sweep` and `merge` (in [`super::sweep`]).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;

use super::producer::Producer;
use super::progress::StageBars;
use super::tables::print_tables;
use super::{ensure_writable, fmt_mm, load_scenarios};
use evitrack::experiment::{self, Workbench};
use evitrack::report::write_run;

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Scenario file (TOML); default: the built-in paper setup (a). A file with a [sweep]
    /// section runs its base scenario only (use `sweep` for the variants).
    scenario: Option<PathBuf>,
    /// Output folder; results go to <OUT>/<scenario name>/.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Override the scenario's master seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Also write the run's wall times to `timings.json` (without it, two runs of the same
    /// scenario and seed write byte-identical folders).
    #[arg(long)]
    timings: bool,
    /// Refuse (exit 2) before running when the estimated peak memory is above this (`4GiB`,
    /// `1500MB`, bytes). Default: 3/4 of the smaller of the machine's memory and `ulimit -v`.
    #[arg(long, value_name = "SIZE", value_parser = super::parse_memory_limit)]
    memory_limit: Option<u64>,
}

pub fn run(args: &RunArgs) -> Result<ExitCode> {
    let set = load_scenarios(args.scenario.as_deref())?;
    let scenario = match args.seed {
        Some(seed) => set.base.with_seed(seed)?,
        None => set.base,
    };
    super::check_memory(std::slice::from_ref(&scenario), 1, args.memory_limit)?;
    let dir = args.out.join(scenario.name());
    ensure_writable(&dir)?;
    // Its motions simulated side by side, each frame rendered beside the physics: the same
    // results as on one thread.
    let bench = Workbench::with_threads(super::cores());
    let bars = StageBars::new(&[scenario.name().to_string()]);
    let output = experiment::run(&scenario, &bench, &mut |stage, done, total| {
        bars.update(0, stage, done, total)
    });
    bars.finish();
    let mut output = output.with_context(|| format!("running scenario `{}`", scenario.name()))?;
    output.producer = Some(Producer::of(&scenario)?.to_json());
    let written = write_run(&dir, &output, args.timings)?;
    print_tables(&[&output.summary]);
    for m in &output.summary.methods {
        if m.per_motion.len() > 1 {
            for (label, stats) in &m.per_motion {
                println!(
                    "  {} {label}: mean {}",
                    m.method,
                    fmt_mm(stats.map(|s| s.mean))
                );
            }
        }
    }
    eprintln!(
        "errors in mm; wrote {} files to {}",
        written.len(),
        dir.display()
    );
    let missed = output.summary.regressions();
    for line in &missed {
        eprintln!("regression: {line}");
    }
    Ok(if missed.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
