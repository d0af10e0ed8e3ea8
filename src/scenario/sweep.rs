//! Sweeps: the `[sweep]` section (listed variants, grids, seeds, findings) and scenario files
//! read into a [`ScenarioSet`].

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{CheckedScenario, Scenario, ScenarioError};

/// Most variants a scenario file may have (listed plus the grid's product), counted before the
/// grid is expanded: a 6-key grid of 10 values each is 10⁶ variants.
pub const MAX_VARIANTS: usize = 1000;

/// Most runs (variants × seeds) one sweep may ask for.
pub const MAX_RUNS: usize = 10_000;

/// The `[sweep]` section: variants of the base scenario.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Sweep {
    /// Listed variants (`[[sweep.variant]]`).
    pub variant: Vec<VariantSpec>,
    /// Dotted path → values; the variants are their cartesian product (`[sweep.grid]`).
    pub grid: BTreeMap<String, Vec<toml::Value>>,
    /// Master seeds every variant runs with (`seeds = 10`: its own seed and the next 9; or a
    /// list); default: the variant's own seed only.
    pub seeds: Option<SeedList>,
    /// Comparisons between variants, measured as paired differences across the seeds
    /// (`[[sweep.finding]]`).
    pub finding: Vec<FindingSpec>,
}

/// Master seeds: a count (from each variant's own seed on) or a list.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum SeedList {
    /// This many consecutive seeds, from the variant's own.
    Count(u64),
    /// These seeds.
    List(Vec<u64>),
}

impl SeedList {
    /// Reads `10` or `1,4,7` (the command line's form).
    ///
    /// # Errors
    /// What is wrong, as a sentence.
    pub fn parse(text: &str) -> Result<Self, String> {
        let list = if text.contains(',') {
            let seeds: Result<Vec<u64>, _> = text.split(',').map(|s| s.trim().parse()).collect();
            SeedList::List(seeds.map_err(|e| format!("`{text}`: {e}"))?)
        } else {
            SeedList::Count(text.trim().parse().map_err(|e| format!("`{text}`: {e}"))?)
        };
        list.check()?;
        Ok(list)
    }

    /// At least one seed, none twice, a count that does not overflow.
    ///
    /// # Errors
    /// What is wrong, as a sentence.
    pub fn check(&self) -> Result<(), String> {
        match self {
            SeedList::Count(0) => Err("seeds: give at least one".into()),
            SeedList::Count(n) if *n > 10_000 => Err(format!("seeds: {n} is more than 10000")),
            SeedList::Count(_) => Ok(()),
            SeedList::List(list) if list.is_empty() => Err("seeds: the list is empty".into()),
            SeedList::List(list) if list.iter().any(|&s| s > super::MAX_SEED) => {
                let seed = list.iter().find(|&&s| s > super::MAX_SEED).copied();
                Err(format!(
                    "seeds: {}",
                    super::seed_too_large(seed.unwrap_or(0))
                ))
            }
            SeedList::List(list) => match list
                .iter()
                .enumerate()
                .find(|(i, s)| list[..*i].contains(s))
            {
                Some((_, s)) => Err(format!("seeds: {s} is listed twice")),
                None => Ok(()),
            },
        }
    }

    /// The seeds of a variant whose own seed is `own`.
    pub fn expand(&self, own: u64) -> Vec<u64> {
        match self {
            SeedList::Count(n) => (0..*n).map(|k| own.wrapping_add(k)).collect(),
            SeedList::List(list) => list.clone(),
        }
    }
}

/// A comparison between two variants (or methods) of a file: `left − right` of the mean errors,
/// paired by seed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FindingSpec {
    /// How the README states it (`b < a`).
    pub name: String,
    /// Left variant, by the name after the scenario's (`b`).
    pub left: String,
    /// Right variant.
    pub right: String,
    /// Method of the left side (default `evidential`).
    #[serde(default = "evidential_name")]
    pub method: String,
    /// Method of the right side (default: the left's).
    #[serde(default)]
    pub right_method: Option<String>,
}

fn evidential_name() -> String {
    "evidential".into()
}

/// One listed variant: a name and the values it replaces.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VariantSpec {
    /// Appended to the scenario's name.
    pub name: String,
    /// Dotted path → replacement value, e.g. `"model.states" = [2, 3, 3, 3, 3, 2]`.
    #[serde(default)]
    pub set: BTreeMap<String, toml::Value>,
}

/// A scenario file: the base scenario and the variants its sweep section spans.
#[derive(Debug, Clone)]
pub struct ScenarioSet {
    /// Where it came from (a path, or `built-in`).
    pub source: String,
    /// The base scenario.
    pub base: CheckedScenario,
    /// The variants, in file order (listed first, then the grid); a file without a sweep section
    /// has one variant, the base itself.
    pub variants: Vec<CheckedScenario>,
    /// The seeds `[sweep] seeds` asks for (`None`: each variant's own).
    pub seeds: Option<SeedList>,
    /// The comparisons of `[[sweep.finding]]`, with full variant names.
    pub comparisons: Vec<Comparison>,
}

/// `scenarios/paper.toml`, built in: its base scenario is the built-in default.
const PAPER_SCENARIO: &str = include_str!("../../scenarios/paper.toml");

impl ScenarioSet {
    /// The built-in default: the paper's dense Bayesian setup, run once.
    ///
    /// # Errors
    /// None expected: the default settings pass their check (a unit test guards it).
    pub fn builtin_default() -> Result<Self, ScenarioError> {
        // The paper file's base scenario itself (validation seed, calibration motion and all),
        // so that `run` and `run scenarios/paper.toml` give the same numbers.
        let paper = Self::parse(PAPER_SCENARIO, "scenarios/paper.toml")?;
        let base = Scenario {
            name: "default".into(),
            description: "The paper's dense Bayesian setup (Figure 2a): 1 mm mesh, 6 size \
                          functions, n = 2,2,2,3,3,2"
                .into(),
            expect: Default::default(),
            sweep: Default::default(),
            ..paper.base.get().clone()
        }
        .check()?;
        Ok(Self {
            source: "built-in".into(),
            variants: vec![base.clone()],
            base,
            seeds: None,
            comparisons: Vec::new(),
        })
    }

    /// Every variant once per seed (`seeds` replaces the file's `[sweep] seeds`), variant by
    /// variant, seeds in the order given.
    ///
    /// # Errors
    /// A variant that does not check with one of the seeds.
    pub fn seeded(&self, seeds: Option<&SeedList>) -> Result<Vec<CheckedScenario>, ScenarioError> {
        let Some(list) = seeds.or(self.seeds.as_ref()) else {
            return Ok(self.variants.clone());
        };
        let per_variant = match list {
            SeedList::Count(n) => usize::try_from(*n).unwrap_or(usize::MAX),
            SeedList::List(l) => l.len(),
        };
        let runs = self.variants.len().saturating_mul(per_variant);
        if runs > MAX_RUNS {
            return Err(ScenarioError::Variant {
                path: self.source.clone(),
                variant: "[sweep]".into(),
                message: format!(
                    "{} variants × {per_variant} seeds = {runs} runs, more than the {MAX_RUNS} a \
                     sweep may ask for: use fewer seeds or split the sweep",
                    self.variants.len()
                ),
            });
        }
        let mut runs = Vec::new();
        for variant in &self.variants {
            for seed in list.expand(variant.seed) {
                runs.push(variant.with_seed(seed)?);
            }
        }
        Ok(runs)
    }

    /// Reads and checks a scenario file.
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses and checks scenario text; `source` names it in errors.
    pub fn parse(text: &str, source: &str) -> Result<Self, ScenarioError> {
        let parse_error = |message: String| ScenarioError::Parse {
            path: source.to_string(),
            message,
        };
        // First pass over the text itself, so unknown fields are reported with line and column.
        let sweep = toml::from_str::<Scenario>(text)
            .map_err(|e| parse_error(e.to_string()))?
            .sweep;
        // Second pass: the file's values laid over setup (a), so that a partial table (say
        // `[model]` with only a seed) keeps the defaults of the fields it leaves out.
        let mut file: toml::Table = toml::from_str(text).map_err(|e| parse_error(e.to_string()))?;
        file.remove("sweep");
        let mut table = match toml::Value::try_from(Scenario::default()) {
            Ok(toml::Value::Table(table)) => table,
            _ => {
                return Err(parse_error(
                    "the default scenario does not serialise".into(),
                ))
            }
        };
        table.remove("sweep");
        overlay(&mut table, file);
        let mut base: Scenario = toml::Value::Table(table.clone())
            .try_into()
            .map_err(|e: toml::de::Error| parse_error(e.to_string()))?;
        if base.name.is_empty() {
            // A file without a name is named after itself.
            base.name = Path::new(source)
                .file_stem()
                .map(|stem| stem.to_string_lossy().into_owned())
                .unwrap_or_default();
        }
        let base = base.check()?;
        if let Some((path, _)) = sweep.grid.iter().find(|(_, values)| values.is_empty()) {
            return Err(ScenarioError::Variant {
                path: source.to_string(),
                variant: format!("grid `{path}`"),
                message: "the list of values is empty: give at least one".into(),
            });
        }
        let count = (sweep.grid.values())
            .fold(1usize, |n, values| n.saturating_mul(values.len()))
            .saturating_add(sweep.variant.len());
        if count > MAX_VARIANTS {
            return Err(ScenarioError::Variant {
                path: source.to_string(),
                variant: "[sweep]".into(),
                message: format!(
                    "{count} variants ({} listed, a grid of {}), more than the {MAX_VARIANTS} a \
                     file may have: split the sweep into several files or shorten the grid",
                    sweep.variant.len(),
                    (sweep.grid.iter())
                        .map(|(key, values)| format!("{} × `{key}`", values.len()))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
        let mut specs = sweep.variant.clone();
        specs.extend(grid_variants(&sweep.grid));
        let variants = if specs.is_empty() {
            vec![base.clone()]
        } else {
            let mut seen = std::collections::HashSet::new();
            specs
                .iter()
                .map(|spec| {
                    let variant_error = |message: String| ScenarioError::Variant {
                        path: source.to_string(),
                        variant: spec.name.clone(),
                        message,
                    };
                    if !seen.insert(spec.name.clone()) {
                        return Err(variant_error("two variants have this name".into()));
                    }
                    let mut value = toml::Value::Table(table.clone());
                    if spec.set.contains_key("name") {
                        return Err(variant_error(
                            "`name` cannot be set: a variant is named `<scenario>-<variant>`"
                                .into(),
                        ));
                    }
                    for (path, replacement) in &spec.set {
                        set_path(&mut value, path, replacement.clone()).map_err(variant_error)?;
                    }
                    let mut scenario: Scenario = value
                        .try_into()
                        .map_err(|e: toml::de::Error| variant_error(e.to_string()))?;
                    scenario.name = format!("{}-{}", base.name(), spec.name);
                    scenario.check()
                })
                .collect::<Result<Vec<_>, _>>()?
        };
        let sweep_error = |message: String| ScenarioError::Variant {
            path: source.to_string(),
            variant: "[sweep]".into(),
            message,
        };
        if let Some(seeds) = &sweep.seeds {
            seeds.check().map_err(sweep_error)?;
        }
        let comparisons = sweep
            .finding
            .iter()
            .map(|f| {
                let side = |short: &str, method: &str| {
                    let full = format!("{}-{short}", base.name());
                    let variant = variants
                        .iter()
                        .find(|v| v.name() == full || v.name() == short)
                        .ok_or_else(|| {
                            sweep_error(format!("finding `{}`: no variant `{short}`", f.name))
                        })?;
                    if !variant.estimators.iter().any(|m| m.name() == method) {
                        return Err(sweep_error(format!(
                            "finding `{}`: variant `{short}` does not run method `{method}`",
                            f.name
                        )));
                    }
                    Ok(Side {
                        scenario: variant.name().to_string(),
                        method: method.to_string(),
                    })
                };
                Ok(Comparison {
                    name: f.name.clone(),
                    left: side(&f.left, &f.method)?,
                    right: side(&f.right, f.right_method.as_deref().unwrap_or(&f.method))?,
                })
            })
            .collect::<Result<Vec<_>, ScenarioError>>()?;
        Ok(Self {
            source: source.to_string(),
            base,
            variants,
            seeds: sweep.seeds.clone(),
            comparisons,
        })
    }
}

/// The cartesian product of a grid, each point a variant named `key=value,...` (the key without
/// its first segment).
fn grid_variants(grid: &BTreeMap<String, Vec<toml::Value>>) -> Vec<VariantSpec> {
    if grid.is_empty() {
        return Vec::new();
    }
    let mut points: Vec<VariantSpec> = vec![VariantSpec {
        name: String::new(),
        set: BTreeMap::new(),
    }];
    for (path, values) in grid {
        // The path without its room (`noise.sigma`, `states`) names the value.
        let short = path.split_once('.').map_or(path.as_str(), |(_, rest)| rest);
        points = points
            .into_iter()
            .flat_map(|point| {
                values.iter().map(move |value| {
                    let mut next = point.clone();
                    let label = format!("{short}={}", compact(value));
                    next.name = if next.name.is_empty() {
                        label
                    } else {
                        format!("{},{label}", next.name)
                    };
                    next.set.insert(path.clone(), value.clone());
                    next
                })
            })
            .collect();
    }
    points
}

/// A value as a short label for variant names (array items and table values joined with `_`).
fn compact(value: &toml::Value) -> String {
    match value {
        toml::Value::String(s) => s.clone(),
        toml::Value::Array(items) => items.iter().map(compact).collect::<Vec<_>>().join("_"),
        toml::Value::Table(table) => table.values().map(compact).collect::<Vec<_>>().join("_"),
        other => other.to_string(),
    }
}

/// Lays `top` over `base`: tables merge key by key, anything else replaces. A table that names
/// its variant (`kind`, `method` or `policy`, as motions, tunings and selection policies do) is
/// a different value, not an amendment, so it replaces too.
fn overlay(base: &mut toml::Table, top: toml::Table) {
    const TAGS: [&str; 3] = ["kind", "method", "policy"];
    for (key, value) in top {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(below)), toml::Value::Table(above))
                if !TAGS.iter().any(|tag| above.contains_key(*tag)) =>
            {
                overlay(below, above)
            }
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

/// Replaces the value at a dotted path, creating missing tables along the way.
pub(super) fn set_path(
    root: &mut toml::Value,
    path: &str,
    value: toml::Value,
) -> Result<(), String> {
    let keys: Vec<&str> = path.split('.').collect();
    if keys.iter().any(|k| k.is_empty()) {
        return Err(format!("`{path}` is not a dotted path like `model.states`"));
    }
    // The sweep section is read once per file, before any variant exists: a variant's value
    // there would be dropped without a word.
    if keys[0] == "sweep" {
        return Err(format!(
            "`{path}` is a setting of the sweep itself, which a variant cannot change: set it in \
             the file's [sweep] section"
        ));
    }
    let mut node = root;
    for (depth, key) in keys.iter().enumerate() {
        let toml::Value::Table(table) = node else {
            return Err(format!(
                "`{}` is not a table, so `{path}` cannot be set",
                keys[..depth].join(".")
            ));
        };
        if depth + 1 == keys.len() {
            table.insert((*key).to_string(), value);
            return Ok(());
        }
        node = table
            .entry((*key).to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    }
    Ok(())
}

/// One side of a comparison: a variant's method.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Side {
    /// Full variant name (`paper-b`).
    pub scenario: String,
    /// Method name.
    pub method: String,
}

/// A comparison to make: `left − right` of the mean errors, paired by seed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Comparison {
    /// How the README states it (`b < a`).
    pub name: String,
    /// Left side.
    pub left: Side,
    /// Right side.
    pub right: Side,
}
