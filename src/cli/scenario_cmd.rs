//! `evitrack scenario`: a scenario as it runs, every setting filled in and explained.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Result};
use clap::Args;

use evitrack::scenario::{annotate, ScenarioSet};

#[derive(Debug, Args)]
pub struct ScenarioArgs {
    /// Scenario file (TOML); without it, the built-in default (the paper's setup a).
    scenario: Option<PathBuf>,
    /// Print the built-in default scenario (the same as giving no file).
    #[arg(long, conflicts_with = "scenario")]
    defaults: bool,
    /// The sweep variant of the file to print, by its full name (`paper-c`) or the part after
    /// the file's name (`c`); default: the base scenario.
    #[arg(long, requires = "scenario")]
    variant: Option<String>,
}

/// Prints the scenario as TOML with a comment above every table and key; `evitrack run` of the
/// printed text is the same run.
pub fn scenario(args: &ScenarioArgs) -> Result<ExitCode> {
    let checked = match &args.scenario {
        Some(path) => super::data::scenario_variant(path, args.variant.as_deref())?,
        None => ScenarioSet::builtin_default()?.base,
    };
    let (text, missing) = annotate(&checked.to_toml()?);
    if text.trim().is_empty() {
        bail!("the scenario printed as empty TOML; please report this as a bug");
    }
    let source = match &args.scenario {
        Some(path) => path.display().to_string(),
        None => "the built-in default (paper setup a)".to_string(),
    };
    print!(
        "# {source} as `evitrack run` reads it: every setting, defaults filled in.\n\
         # Left-out values take these; save this text and edit it to make a scenario.\n\n{text}"
    );
    if !missing.is_empty() {
        eprintln!("note: no description for {}", missing.join(", "));
    }
    Ok(ExitCode::SUCCESS)
}
