//! evitrack's side of the peer comparison (`benches/peers/run.sh`, README there): `export DIR`
//! writes the inputs of evitrack's Dempster, EM and GP benches as JSON for the Python peers;
//! `time TASK REPS [RESULT]` times evitrack on the same inputs and prints one JSON line (every
//! repetition's seconds), writing what it computed to RESULT for the agreement check.
//! Not a criterion bench: `bench = false` keeps it out of `cargo bench`, and nothing of it runs
//! in `cargo test`.

#[path = "../common/inputs.rs"]
mod inputs;

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use evitrack::estimator::{Gp, GpSettings, PoseEstimator};
use evitrack::evidence::{dempster_all, MassFunction, Subset};
use evitrack::hmm::{GaussianHmm, HmmSettings};
use evitrack::standardisation::Standardisation;
use serde_json::{json, Value};

/// EM bench size: `hmm_em_8_features_3_states/400`.
const EM_SAMPLES: usize = 400;
/// GP bench size: `baseline_fit/gp/400` (a 20 × 20 mesh).
const GP_SIDE: usize = 20;
/// Test frames for the GP's error (`baseline_frame`'s 64 frames).
const GP_FRAMES: usize = 64;

type Fail = Box<dyn std::error::Error>;

fn main() -> Result<(), Fail> {
    // `cargo bench` appends `--bench`; nothing else is expected.
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    match args.iter().map(String::as_str).collect::<Vec<_>>()[..] {
        ["export", dir] => export(Path::new(dir)),
        ["time", task, reps] => time(task, reps.parse()?, None),
        ["time", task, reps, result] => time(task, reps.parse()?, Some(Path::new(result))),
        _ => Err(
            "usage: peers export DIR | peers time TASK REPS [RESULT_FILE]; tasks: \
                  dempster_fixed, dempster_seed5, em, em_log, gp_1start, gp_2starts"
                .into(),
        ),
    }
}

/// The C400 shapes of `benches/evidence.rs`: `fixed/200_of_400` and `draws/…_seed5`.
fn c400(task: &str) -> Option<Vec<MassFunction>> {
    match task {
        "dempster_fixed" => Some(inputs::mass_functions(200, 400, 2026, 0.1)),
        "dempster_seed5" => Some(inputs::mass_functions(200, 400, 5, 0.0)),
        _ => None,
    }
}

/// A subset as a hexadecimal integer whose bit i is element i (Python's `int(h, 16)`).
fn hex(s: &Subset) -> String {
    s.words()
        .iter()
        .rev()
        .map(|w| format!("{w:016x}"))
        .collect()
}

fn write(path: &Path, value: &Value) -> Result<(), Fail> {
    std::fs::write(path, serde_json::to_string(value)?)
        .map_err(|e| format!("cannot write {}: {e}", path.display()).into())
}

fn hmm_json(h: &GaussianHmm) -> Value {
    json!({"initial": h.initial(), "transitions": h.transitions(), "means": h.means(),
           "variances": h.variances()})
}

/// The GP bench's training samples and test frames, and the standardisations the GP fits them
/// in (rebuilt by the same operations as `Gp::fit`, so the peer sees the same numbers).
struct GpInputs {
    samples: inputs::Samples,
    test_poses: Vec<[f64; 2]>,
    test_rows: Vec<Vec<Option<f64>>>,
}

impl GpInputs {
    fn new() -> Self {
        let (test_poses, test_rows) = inputs::frames(GP_FRAMES, 8);
        Self {
            samples: inputs::Samples::mesh(GP_SIDE),
            test_poses,
            test_rows,
        }
    }

    fn export(&self) -> Value {
        let complete = |rows: &[Vec<Option<f64>>]| -> Vec<Vec<f64>> {
            rows.iter()
                .map(|r| r.iter().map(|v| v.expect("complete rows")).collect())
                .collect()
        };
        let (rows, test_rows) = (complete(&self.samples.rows), complete(&self.test_rows));
        let pose_rows: Vec<Vec<f64>> = self.samples.poses.iter().map(|p| p.to_vec()).collect();
        let features = Standardisation::fit(&rows, 8);
        let output = Standardisation::fit(&pose_rows, 2);
        let chunks = |flat: Vec<f64>, w: usize| -> Vec<Vec<f64>> {
            flat.chunks(w).map(<[f64]>::to_vec).collect()
        };
        let settings = GpSettings::default();
        json!({
            "inputs": chunks(features.apply_rows(&rows), 8),
            "outputs": chunks(output.apply_rows(&pose_rows), 2),
            "output_means": output.means, "output_scales": output.scales,
            "test_inputs": chunks(features.apply_rows(&test_rows), 8),
            "test_poses": self.test_poses,
            "initial_length_scale": settings.initial_length_scale,
            "initial_noise": settings.initial_noise,
        })
    }
}

fn export(dir: &Path) -> Result<(), Fail> {
    std::fs::create_dir_all(dir)?;
    for task in ["dempster_fixed", "dempster_seed5"] {
        let fs = c400(task).expect("a C400 task");
        let functions: Vec<Value> = fs
            .iter()
            .map(|f| {
                let sets: Vec<String> = f.focal_sets().iter().map(hex).collect();
                json!({"sets": sets, "masses": f.masses()})
            })
            .collect();
        write(
            &dir.join(format!("{task}.json")),
            &json!({"n": 400, "functions": functions}),
        )?;
    }
    let settings = HmmSettings::default();
    let mut features = Vec::new();
    for (i, col) in inputs::em_features(EM_SAMPLES).iter().enumerate() {
        let starts = GaussianHmm::starts(col, 3, &settings, i as u64)?;
        let starts: Vec<Value> = starts.iter().map(hmm_json).collect();
        features.push(json!({"values": col, "starts": starts}));
    }
    write(
        &dir.join("em.json"),
        &json!({"n_states": 3, "tolerance_per_observation": settings.tolerance,
                "max_iterations": settings.max_iterations, "features": features}),
    )?;
    write(&dir.join("gp.json"), &GpInputs::new().export())
}

/// Times `reps` calls of `run` after one warm-up call; returns the seconds and the last result.
fn repeat<T>(reps: usize, mut run: impl FnMut() -> T) -> (Vec<f64>, T) {
    let mut last = run();
    let mut seconds = Vec::with_capacity(reps);
    for _ in 0..reps {
        let t = Instant::now();
        last = black_box(run());
        seconds.push(t.elapsed().as_secs_f64());
    }
    (seconds, last)
}

fn time(task: &str, reps: usize, result: Option<&Path>) -> Result<(), Fail> {
    let (seconds, value) = if let Some(fs) = c400(task) {
        // What `benches/evidence.rs` times: the combination and every singleton plausibility.
        let (seconds, (c, contour)) = repeat(reps, || {
            let c = dempster_all(black_box(&fs)).expect("same frames");
            let contour = c.mass.as_ref().map(MassFunction::contour);
            (c, contour)
        });
        let m = c.mass.ok_or("total conflict")?;
        let sets: Vec<String> = m.focal_sets().iter().map(hex).collect();
        let value = json!({"conflict_mass": c.conflict_mass, "sets": sets,
                           "masses": m.masses(), "contour": contour});
        (seconds, value)
    } else if task == "em" || task == "em_log" {
        // `em_log` differs only on the peer's side (hmmlearn's default implementation).
        let data = inputs::em_features(EM_SAMPLES);
        let settings = HmmSettings::default();
        let (seconds, fits) = repeat(reps, || {
            let fits: Result<Vec<_>, _> = (data.iter().enumerate())
                .map(|(i, col)| GaussianHmm::fit(black_box(col), 3, &settings, i as u64))
                .collect();
            fits
        });
        let fits = fits?;
        let ll: Vec<f64> = fits.iter().map(|f| f.log_likelihood).collect();
        let iterations: Vec<usize> = fits.iter().map(|f| f.iterations).collect();
        (
            seconds,
            json!({"log_likelihood": ll, "iterations": iterations}),
        )
    } else if let Some(starts) = match task {
        "gp_1start" => Some(1),
        "gp_2starts" => Some(2),
        _ => None,
    } {
        let data = GpInputs::new();
        let training = data.samples.training();
        let settings = GpSettings {
            starts,
            ..GpSettings::default()
        };
        let (seconds, gp) = repeat(reps, || Gp::fit(&settings, black_box(&training)));
        let gp = gp?;
        let mut predictions = Vec::new();
        for row in &data.test_rows {
            predictions.push(gp.estimate(row)?.pose.ok_or("no estimate")?);
        }
        let h = gp.hyperparameters();
        let value = json!({"log_marginal_likelihood": gp.log_marginal_likelihood(),
                           "length_scales": h.length_scales, "signal_std": h.signal_std,
                           "noise_std": h.noise_std, "predictions": predictions});
        (seconds, value)
    } else {
        return Err(format!("unknown task {task}").into());
    };
    if let Some(path) = result {
        write(path, &value)?;
    }
    println!(
        "{}",
        json!({"task": task, "who": "evitrack", "seconds": seconds})
    );
    Ok(())
}
