//! Commands on datasets and belief functions: `simulate`, `render`, `features`, `combine`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::Args;

use super::{
    ensure_output_writable, ensure_writable, extract_with_progress, feature_config_for, fresh_dir,
    progress_bar, read_dataset, write_output,
};
use evitrack::dataset::Dataset;
use evitrack::evidence::exchange::CombineLimits;
use evitrack::evidence::{self, EvidenceError, WorkLimit, WorkLimits};
use evitrack::experiment::{sample_trajectory, Workbench};
use evitrack::report::Timings;
use evitrack::scenario::{CheckedScenario, SampleSettings, ScenarioSet};
use evitrack::seed::{self, ScenarioPart};
use evitrack::sim::{self, Motion, NoiseSettings, SimSettings};

/// Arguments of `combine`.
#[derive(Debug, Args)]
pub struct CombineArgs {
    /// Input JSON file (`-` reads standard input).
    file: PathBuf,
    /// Most focal sets any one function (an input, all inputs together, or a running result)
    /// may have; beyond it `combine` stops with exit status 2.
    #[arg(long, value_name = "N", default_value_t = WorkLimits::DEFAULT.focal_sets)]
    max_focal_sets: usize,
    /// Most memory, in MiB, the focal sets of any one function may take (focal sets × frame
    /// size / 8 bytes, rounded up to 64 elements).
    #[arg(long, value_name = "MIB", default_value_t = WorkLimits::DEFAULT.set_bytes >> 20)]
    max_set_mib: usize,
    /// Most elements the output may list (the frame's plausibilities plus the elements of the
    /// result's focal sets).
    #[arg(long, value_name = "N", default_value_t = CombineLimits::DEFAULT.output_elements)]
    max_output_elements: usize,
    /// Most tuples of focal sets (one per function) the pcr6 rule may visit.
    #[arg(long, value_name = "N", default_value_t = WorkLimits::DEFAULT.tuples)]
    max_tuples: usize,
    /// Reliability of the sources, in place of the input's "reliability": one α in [0, 1] for
    /// every function, or one per function (comma-separated). Each function is discounted
    /// (m(X) ← α·m(X), m(Ω) += 1 − α) before the rule.
    #[arg(long, value_name = "A[,A...]", value_delimiter = ',')]
    reliability: Option<Vec<f64>>,
}

impl CombineArgs {
    fn limits(&self) -> CombineLimits {
        CombineLimits {
            work: WorkLimits {
                focal_sets: self.max_focal_sets,
                set_bytes: self.max_set_mib.saturating_mul(1 << 20),
                tuples: self.max_tuples,
            },
            output_elements: self.max_output_elements,
        }
    }
}

#[derive(Debug, Args)]
struct SimArgs {
    /// Seed of the image noise (and of random paths).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Render without noise.
    #[arg(long)]
    noise_free: bool,
}

impl SimArgs {
    fn settings(&self) -> SimSettings {
        let mut settings = SimSettings::default();
        if self.noise_free {
            settings.noise = NoiseSettings::none();
        }
        settings
    }
}

#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Output folder (created; must be empty or absent).
    #[arg(long)]
    out: PathBuf,
    /// The motion as an inline TOML table, e.g.
    /// 'kind = "lissajous", freq_x = 0.3, freq_y = 0.2, duration = 10, fps = 10'.
    /// Default: the 1 mm mesh of the sample trajectory (400 nodes).
    #[arg(long, conflicts_with = "scenario")]
    motion: Option<String>,
    /// Simulate a motion of this scenario file instead, with its rig and the seed its run
    /// uses, so the dataset is the one `run` trains or tests on (`--seed`/`--noise-free` are
    /// ignored).
    #[arg(long)]
    scenario: Option<PathBuf>,
    /// Which of the scenario's motions: `sample` (the frames `run` trains on, after
    /// `keep_every` and the adaptive samples), `validation`, `calibration` or `test0`, `test1`,
    /// … (the test motions in file order, named as in `frames.csv` and the plots; `test` is
    /// `test0`; the clean frames, before the scenario's [[faults]]).
    #[arg(long, default_value = "sample", requires = "scenario")]
    part: String,
    /// The sweep variant of the scenario file, by its full name (`paper-c`) or the part after
    /// the scenario's name (`c`). Default: the base scenario.
    #[arg(long, requires = "scenario")]
    variant: Option<String>,
    #[command(flatten)]
    sim: SimArgs,
}

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// End-effector x (mm, robot frame; the workspace is x ∈ [−9.5, 9.5]).
    #[arg(long, allow_negative_numbers = true)]
    x: f64,
    /// End-effector y (mm, robot frame; the workspace is y ∈ [38, 57]).
    #[arg(long, allow_negative_numbers = true)]
    y: f64,
    /// Output PNG file.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    sim: SimArgs,
}

#[derive(Debug, Args)]
pub struct FeaturesArgs {
    /// Dataset folder (frames + poses.csv + manifest.json).
    dataset: PathBuf,
    /// Feature configuration (TOML, the `[features]` table of a scenario without its header).
    /// Default: the paper's 6 size functions.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Add the barycentre features (x, y) to the default configuration.
    #[arg(long, conflicts_with = "config")]
    barycentre: bool,
    /// An external feature program's settings (TOML: `command`, `values`, `missing`,
    /// `timeout_seconds`, as in a scenario's `[[features.external]]`); its values follow the
    /// configuration's. Repeatable.
    #[arg(long = "feature-program", value_name = "FILE.toml")]
    feature_program: Vec<PathBuf>,
    /// Output CSV file (default: standard output); with --report, a folder.
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    report: super::feature_report::ReportArgs,
}

fn parse_motion(text: &str) -> Result<Motion> {
    let table = format!("motion = {{ {text} }}");
    #[derive(serde::Deserialize)]
    struct Wrapper {
        motion: Motion,
    }
    let wrapper: Wrapper = toml::from_str(&table)
        .with_context(|| format!("--motion '{text}' is not a valid motion table"))?;
    Ok(wrapper.motion)
}

/// The base scenario or the named sweep variant of a scenario file.
pub(crate) fn scenario_variant(path: &Path, variant: Option<&str>) -> Result<CheckedScenario> {
    let set = ScenarioSet::load(path)?;
    let Some(name) = variant else {
        return Ok(set.base);
    };
    let full = format!("{}-{name}", set.base.name());
    let names: Vec<&str> = set.variants.iter().map(|v| v.name()).collect();
    set.variants
        .iter()
        .find(|v| v.name() == name || v.name() == full)
        .cloned()
        .with_context(|| {
            format!(
                "{} has no variant `{name}`; its variants are {}",
                path.display(),
                names.join(", ")
            )
        })
}

/// The index of test motion `testN` (0-based, as `frames.csv` and the plots name it; `test` is
/// `test0`).
fn test_index(part: &str) -> Result<usize> {
    match &part[4..] {
        "" => Ok(0),
        digits if digits.bytes().all(|b| b.is_ascii_digit()) => digits
            .parse()
            .with_context(|| format!("--part `{part}`: test number too large")),
        _ => bail!("--part `{part}`: expected test0, test1, … (test is test0)"),
    }
}

/// Exactly the dataset a run of the scenario uses for `part`.
fn scenario_part(scenario: &CheckedScenario, part: &str) -> Result<Dataset> {
    let s = scenario.get();
    let bar = progress_bar("simulate");
    // The sample trajectory's stages: its simulation, its features, adaptive rounds.
    let mut progress = |stage: &str, done: usize, total: usize| {
        if !stage.is_empty() && bar.message() != stage {
            bar.set_message(stage.to_string());
        }
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let (motion, part) = match part {
        "sample" => {
            let bench = Workbench::with_threads(super::cores());
            let sample =
                sample_trajectory(scenario, &bench, &mut progress, &mut Timings::default())?;
            bar.finish_and_clear();
            return Ok(sample.dataset);
        }
        "validation" => (
            s.validation
                .clone()
                .with_context(|| format!("scenario `{}` has no validation motion", s.name))?,
            ScenarioPart::Validation,
        ),
        "calibration" => (
            s.calibration
                .clone()
                .with_context(|| format!("scenario `{}` has no calibration motion", s.name))?,
            ScenarioPart::Calibration,
        ),
        test if test.starts_with("test") => {
            let index = test_index(test)?;
            let motion = s.tests.get(index).cloned().with_context(|| {
                format!(
                    "scenario `{}` has {} test motion(s): use --part test0 … test{}",
                    s.name,
                    s.tests.len(),
                    s.tests.len().saturating_sub(1)
                )
            })?;
            if !scenario.fault_plan().is_empty() {
                eprintln!(
                    "note: scenario `{}` has [[faults]]; these are the clean test frames (a run \
                     applies the faults to them and records in frames.csv which frames they struck)",
                    s.name
                );
            }
            (motion, ScenarioPart::Test(index))
        }
        other => bail!(
            "--part `{other}` must be sample, validation, calibration or testN (test0, test1, …)"
        ),
    };
    let seed = seed::for_part(s.seed, part);
    let threads = super::cores();
    let dataset = sim::simulate_on(&s.sim, &motion, seed, threads, &mut |d, t| {
        progress("", d, t)
    })?;
    bar.finish_and_clear();
    Ok(dataset)
}

pub fn simulate(args: &SimulateArgs) -> Result<ExitCode> {
    fresh_dir(&args.out)?;
    ensure_writable(&args.out)?;
    let dataset = match (&args.scenario, &args.motion) {
        (Some(path), _) => {
            let scenario = scenario_variant(path, args.variant.as_deref())?;
            scenario_part(&scenario, &args.part)?
        }
        (None, motion_text) => {
            let motion = match motion_text {
                Some(text) => parse_motion(text)?,
                None => SampleSettings::default().motion,
            };
            // A random path without its own seed takes --seed.
            let motion = motion.with_default_seed(args.sim.seed);
            let bar = progress_bar("simulate");
            let dataset = sim::simulate_on(
                &args.sim.settings(),
                &motion,
                args.sim.seed,
                super::cores(),
                &mut |done, total| {
                    bar.set_length(total as u64);
                    bar.set_position(done as u64);
                },
            )?;
            bar.finish_and_clear();
            dataset
        }
    };
    dataset
        .write(&args.out)
        .with_context(|| format!("writing the dataset to {}", args.out.display()))?;
    eprintln!(
        "wrote {} frames of `{}` to {}",
        dataset.len(),
        dataset.manifest.scenario,
        args.out.display()
    );
    Ok(ExitCode::SUCCESS)
}

pub fn render(args: &RenderArgs) -> Result<ExitCode> {
    let image = sim::render_pose(&args.sim.settings(), args.x, args.y, args.sim.seed)?;
    let format = image::ImageFormat::from_path(&args.out).with_context(|| {
        format!(
            "{}: name the image with an extension (`.png`)",
            args.out.display()
        )
    })?;
    let mut bytes = Vec::new();
    image
        .write_to(&mut std::io::Cursor::new(&mut bytes), format)
        .with_context(|| format!("encoding {}", args.out.display()))?;
    evitrack::atomic::write(&args.out, &bytes)
        .with_context(|| format!("writing {}", args.out.display()))?;
    eprintln!(
        "rendered ({}, {}) mm to {} ({}×{} px)",
        args.x,
        args.y,
        args.out.display(),
        image.width(),
        image.height()
    );
    Ok(ExitCode::SUCCESS)
}

pub fn combine(args: &CombineArgs) -> Result<ExitCode> {
    let file = args.file.as_path();
    let (text, name) = if file == Path::new("-") {
        let text = std::io::read_to_string(std::io::stdin()).context("reading standard input")?;
        (text, "standard input".to_string())
    } else {
        let text =
            std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
        (text, file.display().to_string())
    };
    let parsed = evidence::exchange::parse_input(&text).and_then(|mut input| {
        if let Some(r) = &args.reliability {
            input.reliability = Some(evidence::exchange::Reliability::Each(r.clone()));
        }
        evidence::exchange::combine_input_within(&input, &args.limits())
    });
    let report = match parsed {
        Ok(report) => report,
        Err(EvidenceError::WorkLimit { limit, max }) => {
            let flag = match limit {
                WorkLimit::FocalSets => format!("--max-focal-sets (now {max})"),
                WorkLimit::SetBytes => format!("--max-set-mib (now {})", max >> 20),
                WorkLimit::OutputElements => format!("--max-output-elements (now {max})"),
                WorkLimit::Tuples => format!("--max-tuples (now {max})"),
            };
            bail!(
                "combining {name} would need more than {max} {limit}, the limit: \
                 raise it with {flag} if the machine has the memory"
            );
        }
        Err(e) => return Err(e).with_context(|| format!("{name} is not a valid combine input")),
    };
    if report.is_total_conflict() && !report.has_result() {
        eprintln!(
            "warning: the mass functions are in total conflict (κ = 1): no combination exists"
        );
    } else if report.is_total_conflict() {
        eprintln!("warning: the mass functions are in total conflict (κ = 1); the rule still gives the result printed");
    }
    println!("{}", serde_json::to_string(&report)?);
    Ok(ExitCode::SUCCESS)
}

pub fn features(args: &FeaturesArgs) -> Result<ExitCode> {
    ensure_output_writable(args.out.as_deref())?;
    let dataset = read_dataset(&args.dataset)?;
    let what = args.dataset.display().to_string();
    let mut config = feature_config_for(args.config.as_deref(), args.barycentre, &dataset, &what)?;
    config
        .external
        .extend(super::programs::read_programs(&args.feature_program)?);
    let set = config.check()?;
    let rows = extract_with_progress(&set, &dataset, &what)?;
    if args.report.report {
        return super::feature_report::report(
            &args.report,
            &dataset,
            &set,
            &rows,
            args.out.as_deref(),
        );
    }
    let mut csv = csv::Writer::from_writer(Vec::new());
    let with_truth = dataset.frames.iter().all(|f| f.truth.is_some());
    let mut header = vec!["file".to_string(), "t".to_string()];
    header.extend(set.names());
    if with_truth {
        header.extend(["x", "y", "theta1", "theta2"].map(String::from));
    }
    csv.write_record(&header)?;
    for (frame, values) in dataset.frames.iter().zip(&rows) {
        let mut record = vec![frame.file.clone(), frame.t.to_string()];
        record.extend(
            values
                .iter()
                .map(|v| v.map(|v| v.to_string()).unwrap_or_default()),
        );
        if let (true, Some(truth)) = (with_truth, frame.truth) {
            record.extend([truth.x, truth.y].map(|v| v.to_string()));
            // Empty angle cells for a frame without them (a real object has none).
            let angles = truth.angles.map(|a| a.map(|v| v.to_string()));
            record.extend(angles.unwrap_or_default());
        }
        csv.write_record(&record)?;
    }
    let bytes = csv.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
    write_output(args.out.as_deref(), &bytes)?;
    let missing = rows.iter().flatten().filter(|v| v.is_none()).count();
    eprintln!(
        "{} frames × {} features{}",
        rows.len(),
        set.len(),
        if missing > 0 {
            format!(", {missing} missing values (empty cells)")
        } else {
            String::new()
        }
    );
    Ok(ExitCode::SUCCESS)
}
