//! The files of a run: `results.json`, `frames.csv`, `samples.csv`, one model file per method
//! and one trajectory plot per test motion and method.

use std::path::{Path, PathBuf};

use super::{plot_trajectory, write_frames_csv, FrameRecord, ReportError};
use crate::experiment::RunOutput;

fn write_error(
    path: &Path,
    source: impl Into<Box<dyn std::error::Error + Send + Sync>>,
) -> ReportError {
    ReportError::Write {
        path: path.display().to_string(),
        source: source.into(),
    }
}

/// Writes a run's outputs into `dir`: `results.json`, `frames.csv` (one row per frame and
/// method), `samples.csv` (the sample poses and the adaptive round that added each), one
/// self-contained model file per method that `evitrack track` reads (`model.json` for the
/// evidential tracker, `model-<method>.json` for the others) and one `track-<motion>.png` per test
/// motion and method (true against estimated positions, like the paper's Figure 2; the other
/// methods' plots end in `-<method>`). Returns the files written.
pub fn write_run(dir: &Path, output: &RunOutput) -> Result<Vec<PathBuf>, ReportError> {
    std::fs::create_dir_all(dir).map_err(|e| write_error(dir, e))?;
    let mut written = Vec::new();
    let results = dir.join("results.json");
    let json =
        serde_json::to_string_pretty(&output.summary).map_err(|e| write_error(&results, e))?;
    std::fs::write(&results, json + "\n").map_err(|e| write_error(&results, e))?;
    written.push(results);

    let frames = dir.join("frames.csv");
    let file = std::fs::File::create(&frames).map_err(|e| write_error(&frames, e))?;
    write_frames_csv(
        std::io::BufWriter::new(file),
        &output.records,
        &output.summary.features,
    )
    .map_err(|e| write_error(&frames, e))?;
    written.push(frames);

    let samples = dir.join("samples.csv");
    let mut csv = csv::Writer::from_path(&samples).map_err(|e| write_error(&samples, e))?;
    csv.write_record(["x", "y", "added_in_round"])
        .map_err(|e| write_error(&samples, e))?;
    for (pose, round) in output.samples.iter().zip(&output.sample_rounds) {
        csv.write_record([pose[0].to_string(), pose[1].to_string(), round.to_string()])
            .map_err(|e| write_error(&samples, e))?;
    }
    csv.flush().map_err(|e| write_error(&samples, e))?;
    written.push(samples);

    for estimator in &output.estimators {
        let method = estimator.method();
        let model = match method {
            "evidential" => dir.join("model.json"),
            other => dir.join(format!("model-{other}.json")),
        };
        let text = estimator.to_json().map_err(|e| write_error(&model, e))?;
        std::fs::write(&model, text).map_err(|e| write_error(&model, e))?;
        written.push(model);
    }

    for summary in &output.summary.methods {
        let method = summary.method.as_str();
        let suffix = match method {
            "evidential" => String::new(),
            other => format!("-{other}"),
        };
        for (label, stats) in &summary.per_motion {
            let records: Vec<&FrameRecord> = output
                .records
                .iter()
                .filter(|r| &r.motion == label && r.method == method)
                .collect();
            let truth: Vec<[f64; 2]> = records.iter().filter_map(|r| r.truth).collect();
            let estimate: Vec<Option<[f64; 2]>> = records.iter().map(|r| r.estimate).collect();
            let file = dir.join(format!("track-{}{suffix}.png", label.replace(':', "-")));
            let title = match stats {
                Some(s) => format!(
                    "{} — {label}, {method}: mean error {:.3} mm",
                    output.summary.scenario, s.mean
                ),
                None => format!(
                    "{} — {label}, {method}: no estimate",
                    output.summary.scenario
                ),
            };
            plot_trajectory(&file, &title, &truth, &estimate, Some(&output.samples))?;
            written.push(file);
        }
    }
    Ok(written)
}
