//! The files of a run: `results.json`, `frames.csv`, `samples.csv`, one model file per method
//! and one trajectory plot per test motion and method.

use std::path::{Path, PathBuf};

use super::run_plots::write_run_plots;
use super::{write_frames_csv, FrameRecord, ReportError};
use super::{RunSummary, Timings};
use crate::estimator::PoseEstimator;
use crate::planar::Rect;

fn write_error(
    path: &Path,
    source: impl Into<Box<dyn std::error::Error + Send + Sync>>,
) -> ReportError {
    ReportError::Write {
        path: path.display().to_string(),
        source: source.into(),
    }
}

/// Everything a run produced.
#[derive(Debug)]
pub struct RunOutput {
    /// The numbers.
    pub summary: RunSummary,
    /// Every test frame, once per method (methods in the scenario's order).
    pub records: Vec<FrameRecord>,
    /// The fitted estimators, in the scenario's order (their model files are self-contained).
    pub estimators: Vec<Box<dyn PoseEstimator>>,
    /// The sample poses it was trained on.
    pub samples: Vec<[f64; 2]>,
    /// For each sample pose, the adaptive round that added it (0: the initial trajectory).
    pub sample_rounds: Vec<usize>,
    /// Wall times (not in the summary, so that the same scenario and seed give the same one).
    pub timings: Timings,
    /// The scenario as TOML ([`crate::scenario::CheckedScenario::to_toml`]).
    pub scenario_toml: String,
    /// What produced it (the command line sets it: its version, a digest of its build and of
    /// every feature program), written as `producer.json`; a sweep resumes a run only when it
    /// matches.
    pub producer: Option<String>,
    /// The workspace the test motions ran in (outlined in the track plots).
    pub workspace: Option<Rect>,
}

/// A run's (and a sweep's) page with its tables, findings and plots.
pub const REPORT_FILE: &str = "report.html";

/// The file of a run folder whose presence says the run finished: written last.
pub const RESULTS_FILE: &str = "results.json";

/// The scenario a run folder's results belong to ([`crate::scenario::CheckedScenario::to_toml`]).
pub const SCENARIO_FILE: &str = "scenario.toml";

/// What produced a run folder's results ([`RunOutput::producer`]).
pub const PRODUCER_FILE: &str = "producer.json";

/// The name of a run's model file of `method`: `model-<method>.json` for every method (until
/// issue 31 the evidential tracker's was `model.json`; such files still load, by any name).
pub fn model_file_name(method: &str) -> String {
    format!("model-{method}.json")
}

/// Writes a run's outputs into `dir`, each file atomically: `scenario.toml` (the scenario as run),
/// `frames.csv` (one row per frame and method), `samples.csv` (the sample poses and the adaptive
/// round that added each), `producer.json` (what produced it, when the caller says), one self-contained model file per method that `evitrack track` reads
/// ([`model_file_name`]: `model-<method>.json`, the evidential tracker's too), one
/// `timings.json` when `timings` is set (wall times differ between runs, everything else is
/// byte-identical for a scenario and seed), the plots (`errors-<motion>.png`, one
/// `track-<motion>.png` per test motion and method — the other methods' end in `-<method>` —,
/// `risk-coverage.png`, `roc.png` with faults), `report.html` (tables,
/// expectations, plots embedded), and last `results.json`, so that a folder with it holds a finished run. Returns the
/// files written.
pub fn write_run(
    dir: &Path,
    output: &RunOutput,
    timings: bool,
) -> Result<Vec<PathBuf>, ReportError> {
    std::fs::create_dir_all(dir).map_err(|e| write_error(dir, e))?;
    // An older run's results must not stand beside this run's files until they are all written.
    match std::fs::remove_file(dir.join(RESULTS_FILE)) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(write_error(&dir.join(RESULTS_FILE), e))
        }
        _ => {}
    }
    let mut written = Vec::new();
    let mut put = |name: &str, bytes: &[u8]| put_file(dir, name, bytes, &mut written);
    put(SCENARIO_FILE, output.scenario_toml.as_bytes())?;
    if let Some(producer) = &output.producer {
        put(PRODUCER_FILE, producer.as_bytes())?;
    }

    let mut frames = Vec::new();
    write_frames_csv(&mut frames, &output.records, &output.summary.features)
        .map_err(|e| write_error(&dir.join("frames.csv"), e))?;
    put("frames.csv", &frames)?;

    let mut samples = String::from("x,y,added_in_round\n");
    for (i, (pose, round)) in output.samples.iter().zip(&output.sample_rounds).enumerate() {
        let [x, y] =
            [0, 1].map(|c| super::finite::number(&format!("samples.csv, row {i}"), pose[c]));
        samples.push_str(&format!("{},{},{round}\n", x?, y?));
    }
    put("samples.csv", samples.as_bytes())?;

    for estimator in &output.estimators {
        let name = model_file_name(estimator.method());
        let text = estimator
            .to_json()
            .map_err(|e| write_error(&dir.join(&name), e))?;
        put(&name, text.as_bytes())?;
    }
    if timings {
        super::check_json_numbers("timings.json", &output.timings)?;
        let json = serde_json::to_string_pretty(&output.timings)
            .map_err(|e| write_error(&dir.join("timings.json"), e))?;
        put("timings.json", (json + "\n").as_bytes())?;
    }

    let plots = write_run_plots(dir, output)?;
    let html = super::pages::run_page(&output.summary, &plots)?;
    written.extend(plots.into_iter().map(|w| w.path));
    put_file(dir, REPORT_FILE, html.as_bytes(), &mut written)?;
    super::check_json_numbers(RESULTS_FILE, &output.summary)?;
    let json = serde_json::to_string_pretty(&output.summary)
        .map_err(|e| write_error(&dir.join(RESULTS_FILE), e))?;
    put_file(dir, RESULTS_FILE, (json + "\n").as_bytes(), &mut written)?;
    Ok(written)
}

/// Writes `dir/name` atomically and adds it to `written`.
fn put_file(
    dir: &Path,
    name: &str,
    bytes: &[u8],
    written: &mut Vec<PathBuf>,
) -> Result<(), ReportError> {
    let path = dir.join(name);
    crate::atomic::write(&path, bytes).map_err(|e| write_error(&path, e))?;
    written.push(path);
    Ok(())
}
