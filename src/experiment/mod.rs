//! Running a scenario: simulate, extract features, fit the estimator, track the test motions,
//! measure against the ground truth.
//!
//! The stages are rooms of their own: the [`Workbench`] memoises simulated datasets and feature
//! rows shared by the variants of a sweep; [`sample_trajectory`] builds the training samples
//! (kept every k-th, refined adaptively). The estimator is fitted through the
//! [`crate::estimator`] seam and every test frame goes through
//! [`PoseEstimator::estimate`](crate::estimator::PoseEstimator::estimate). What a run measured is
//! recorded and written by [`crate::report`].

mod fits;
mod limit;
mod render_check;
mod sample;
mod sample_silhouettes;
mod workbench;

pub use limit::{frame_bounds, noise_model};
pub use render_check::{estimates_on, render_limit, Observed, RenderCheck};
pub use sample::{sample_trajectory, SampleTrajectory};
pub use sample_silhouettes::SampleSilhouettes;
pub use workbench::{Step, Workbench};

// Everything a run produced lives with the files written from it.
pub use crate::report::RunOutput;

use std::sync::{Arc, Mutex};
use std::time::Instant;

use crate::estimator::{EstimatorError, Evidential, Labelled, TrainingSet};
use crate::faults::FeatureScale;
use crate::features::FeatureRows;
use crate::model_file::Provenance;
use crate::report::{
    CalibrationReach, ErrorStats, EvidentialSummary, FrameRecord, MethodSummary, MethodTimings,
    RenderCheckSummary, RunSummary, Timings,
};
use crate::scenario::CheckedScenario;
use crate::seed::{self, ScenarioPart};
use crate::sim::{Motion, SimError, SimSettings};

/// Failures while running a scenario.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExperimentError {
    /// The simulator failed (bad settings or motion, or the physics).
    #[error("simulating {what}: {source}")]
    Simulate {
        /// Which trajectory.
        what: String,
        /// The simulator's error (shared by the sweep variants that asked for the dataset).
        source: Arc<SimError>,
    },
    /// An external feature program failed on a motion's frames.
    #[error("the features of {what}: {source}")]
    External {
        /// Which motion.
        what: String,
        /// The program's error (shared by the sweep variants that asked for the rows).
        source: Arc<crate::external::ExternalError>,
    },
    /// The adaptive sample trajectory failed.
    #[error("the adaptive sample trajectory: {0}")]
    Adaptive(#[from] crate::adaptive::AdaptiveError),
    /// Fitting or running the estimator failed.
    #[error("{stage}: {source}")]
    Estimator {
        /// Which stage (`training`, `tracking test0:lissajous`, …).
        stage: String,
        /// The estimator's error.
        source: EstimatorError,
    },
    /// A dataset has no ground truth where the run needs it.
    #[error("{0} has no ground truth; simulated datasets always do")]
    NoTruth(String),
    /// The scenario has no TOML form to keep beside its results.
    #[error(transparent)]
    Scenario(#[from] crate::scenario::ScenarioError),
    /// The render check cannot be set up.
    #[error("the render check: {0}")]
    RenderCheck(String),
    /// The variant was not run (a worker thread stopped early).
    #[error("the variant was not run")]
    NotRun,
}

/// Receives progress: stage name, done, total.
pub type Progress<'a> = &'a mut dyn FnMut(&str, usize, usize);

/// The penalty of a frame without an estimate: the workspace diagonal, the largest error an
/// estimate inside the workspace can have.
pub fn missing_penalty(sim: &SimSettings) -> f64 {
    sim.geometry.workspace.diagonal()
}

/// Runs one checked scenario: simulate, extract, fit, track, measure.
pub fn run(
    scenario: &CheckedScenario,
    bench: &Workbench,
    progress: Progress<'_>,
) -> Result<RunOutput, ExperimentError> {
    let s = scenario.get();
    let mut timings = Timings::default();
    let set = scenario.feature_set();
    let names = set.names();
    let master = s.seed;
    let sim = &s.sim;

    if bench.threads() > 1 {
        simulate_ahead(scenario, bench, progress, &mut timings);
    }
    let sample = sample_trajectory(scenario, bench, progress, &mut timings)?;

    // Validation data, for tuning by validation error, the fallback ranking and the threshold.
    let validation = match &s.validation {
        Some(motion) => {
            let seed = seed::for_part(master, ScenarioPart::Validation);
            let what = VALIDATION_STAGE;
            let (truth, times, rows) =
                labelled_motion(scenario, bench, motion, seed, what, progress, &mut timings)?;
            Some((truth, times, rows))
        }
        None => None,
    };

    // The calibration motion, when the scenario has one apart from the validation motion.
    let calibration = match &s.calibration {
        Some(motion) => {
            let seed = seed::for_part(master, ScenarioPart::Calibration);
            let what = CALIBRATION_STAGE;
            Some(labelled_motion(
                scenario,
                bench,
                motion,
                seed,
                what,
                progress,
                &mut timings,
            )?)
        }
        None => None,
    };

    // The render check's calibration frames, and then each test frame's silhouette.
    let render = render_check::Harness::new(scenario, bench, &sample.dataset)?;
    let mut observed = Vec::new();

    // The test frames: simulated and their features extracted once, for every method; then
    // the faults, if any, each test motion on its own stream.
    let plan = scenario.fault_plan();
    let scales = FeatureScale::of_rows(&sample.rows, names.len());
    let mut tests: Vec<TestMotion> = Vec::with_capacity(s.tests.len());
    for (k, motion) in s.tests.iter().enumerate() {
        let label = test_label(k, motion);
        let seed = seed::for_part(master, ScenarioPart::Test(k));
        let (truth, times, rows) = labelled_motion(
            scenario,
            bench,
            motion,
            seed,
            &label,
            progress,
            &mut timings,
        )?;
        let mut painted = Vec::new();
        let (rows, labels) = if plan.is_empty() {
            (rows, None)
        } else {
            let clock = Instant::now();
            let data = bench.dataset(&s.sim, motion, seed, &mut |_, _| {})?;
            let corrupted = plan
                .apply_with(
                    seed::for_faults(master, k),
                    data.images(),
                    &rows,
                    &scales,
                    &mut |at, images| {
                        if let Some(render) = &render {
                            painted.extend(render.observe_painted(at, images));
                        }
                        corrupted_features(set, &data, at, images, bench.threads())
                    },
                )
                .map_err(|source| ExperimentError::External {
                    what: format!("{label} (with its faults)"),
                    source: Arc::new(source),
                })?;
            timings.features += clock.elapsed().as_secs_f64();
            (Arc::new(corrupted.rows), Some(corrupted.labels))
        };
        if let Some(render) = &render {
            let data = bench.dataset(&s.sim, motion, seed, &mut |_, _| {})?;
            observed.push(render.observe_motion(&data, painted, labels.as_deref()));
        }
        tests.push((label, truth, times, rows, labels));
    }

    // Every method fits on the same training set and estimates the same feature rows.
    let mut settings = s.estimator_settings();
    // Training on its own stream of the master seed (`model.seed` picks among streams).
    settings.evidential.model.seed = seed::for_training(master, s.model.seed);
    let training = TrainingSet {
        feature_names: &names,
        feature_config: Some(&s.features),
        sample: Labelled {
            poses: &sample.poses,
            rows: &sample.rows,
        },
        validation: validation
            .as_ref()
            .map(|(truth, _, rows)| Labelled { poses: truth, rows }),
        validation_times: validation.as_ref().map(|(_, times, _)| times.as_slice()),
        calibration: calibration
            .as_ref()
            .map(|(truth, _, rows)| Labelled { poses: truth, rows }),
        calibration_times: calibration.as_ref().map(|(_, times, _)| times.as_slice()),
        missing_penalty: missing_penalty(sim),
        provenance: Provenance::new(Some(s.name.clone()), master)
            .with_workspace(Some(sim.geometry.workspace)),
    };
    let mut estimators = Vec::with_capacity(s.estimators.len());
    let mut records = Vec::new();
    let mut methods = Vec::with_capacity(s.estimators.len());
    let mut ahead = fits::fit_heavy_ahead(&s.estimators, bench, &settings, &training);
    for (&method, ahead) in s.estimators.iter().zip(&mut ahead) {
        let stage = format!("fit {method}");
        let clock = Instant::now();
        progress(&stage, 0, 1);
        let (fitted, fit_seconds) = ahead.take().unwrap_or_else(|| {
            let fitted = bench.fit(method, &settings, &training);
            (fitted, clock.elapsed().as_secs_f64())
        });
        let mut estimator =
            fitted.map_err(|source| ExperimentError::Estimator { stage, source })?;
        let clock = Instant::now();
        let calibrating = calibration.as_ref().or(validation.as_ref());
        let render_limit = match &render {
            Some(render) => render.method_limit(method, estimator.as_ref(), calibrating)?,
            None => None,
        };
        // The model file keeps the limit, for `track --samples`.
        if let (Some(render), Some(limit)) = (&render, &render_limit) {
            let any = estimator.as_mut() as &mut dyn std::any::Any;
            if let Some(calibrated) = any.downcast_mut::<crate::estimator::Calibrated>() {
                calibrated.set_render_limits(render.limits_to_keep(limit));
            }
        }
        let mut method_records = Vec::new();
        let mut per_motion = Vec::with_capacity(tests.len());
        let track_stage = format!("track {method}");
        let frames: usize = tests.iter().map(|t| t.3.len()).sum();
        for (k, (label, truth, times, rows, faults)) in tests.iter().enumerate() {
            let mut errors = Vec::new();
            let mut motion = estimator.start_motion();
            for (i, row) in rows.iter().enumerate() {
                progress(&track_stage, method_records.len(), frames);
                let mut estimate =
                    motion
                        .next(times[i], row)
                        .map_err(|source| ExperimentError::Estimator {
                            stage: format!("{method} on {label}"),
                            source,
                        })?;
                if let (Some(render), Some(limit)) = (&render, &render_limit) {
                    render.judge(&mut estimate, &observed[k][i], limit);
                }
                let record = FrameRecord::new(
                    method.name(),
                    label,
                    i,
                    times[i],
                    Some(truth[i]),
                    &estimate,
                    &names,
                );
                let record = match faults {
                    Some(labels) => record.with_faults(labels[i].clone()),
                    None => record,
                };
                errors.extend(record.error);
                method_records.push(record);
            }
            per_motion.push((label.clone(), ErrorStats::from_errors(&errors)));
        }
        progress(&track_stage, frames, frames);
        let track_seconds = clock.elapsed().as_secs_f64();
        let mut summary = MethodSummary::new(method.name(), &method_records, per_motion);
        summary.render_check = (render.as_ref().zip(render_limit)).map(|(r, l)| {
            let limits = (l.limit, r.stray_limit());
            RenderCheckSummary::of(r.source(), limits, r.calibration_frames(), &method_records)
        });
        methods.push(summary);
        timings.methods.push(MethodTimings {
            method: method.name().to_string(),
            fit_seconds,
            track_seconds,
        });
        records.extend(method_records);
        estimators.push(estimator);
    }

    let views: Vec<_> = (tests.iter())
        .map(|t| (t.1.as_slice(), t.3.as_slice()))
        .collect();
    let limits = limit::measure(&estimators, bench, &settings, &training, &views);
    let limit = limits.map(|found| limit::attach(found, &tests, &mut records, &mut methods));

    let evidential = estimators
        .iter()
        .find_map(|e| {
            (crate::estimator::underlying(e.as_ref()) as &dyn std::any::Any)
                .downcast_ref::<Evidential>()
        })
        .map(|e| e.model());
    let summary = RunSummary {
        scenario: s.name.clone(),
        seed: master,
        samples: sample.poses.len(),
        adaptive_added: sample.adaptive_added(),
        features: names.clone(),
        frames: tests.iter().map(|t| t.1.len()).sum(),
        evidential: evidential.map(EvidentialSummary::of),
        methods,
        paper_error: s.paper_error,
        limit,
        expect: s.expect.clone(),
        calibration_reach: (calibration.as_ref().or(validation.as_ref()))
            .and_then(|(poses, _, _)| CalibrationReach::of(poses, &records)),
    };
    Ok(RunOutput {
        summary,
        records,
        estimators,
        samples: sample.poses,
        sample_rounds: sample.rounds,
        timings,
        scenario_toml: scenario.to_toml()?,
        producer: None,
        workspace: Some(sim.geometry.workspace),
    })
}

/// A test motion as a run holds it: label, truth, times, feature rows, fault labels.
type TestMotion = (
    String,
    Vec<[f64; 2]>,
    Vec<f64>,
    Arc<FeatureRows>,
    Option<Vec<crate::faults::FrameFaults>>,
);

/// The features of the images a fault changed (`images`, frames `at` of `data`), the external
/// programs' included: they run on those frames as a dataset of their own.
pub(crate) fn corrupted_features(
    set: &crate::features::FeatureSet,
    data: &crate::dataset::Dataset,
    at: &[usize],
    images: &[image::GrayImage],
    threads: usize,
) -> Result<FeatureRows, crate::external::ExternalError> {
    let refs: Vec<_> = images.iter().collect();
    let mut rows = set.extract_on(&refs, threads, &mut |_, _| {});
    if !set.external().is_empty() {
        let frames = at
            .iter()
            .zip(images)
            .map(|(&i, image)| crate::dataset::Frame {
                image: image.clone(),
                ..data.frames[i].clone()
            })
            .collect::<Vec<_>>();
        let mut manifest = data.manifest.clone();
        manifest.frame_count = frames.len();
        let edited = crate::dataset::Dataset { manifest, frames };
        crate::external::fill(set, &edited, &mut rows)?;
    }
    Ok(rows)
}

/// Ground truth (mm), frame times (s) and feature rows of one motion.
type LabelledMotion = (Vec<[f64; 2]>, Vec<f64>, Arc<FeatureRows>);

/// Ground truth, frame times and feature rows of one of the scenario's motions (simulated and
/// extracted once per workbench); `label` names it in progress and errors.
fn labelled_motion(
    scenario: &CheckedScenario,
    bench: &Workbench,
    motion: &Motion,
    seed: u64,
    label: &str,
    progress: Progress<'_>,
    timings: &mut Timings,
) -> Result<LabelledMotion, ExperimentError> {
    let s = scenario.get();
    let clock = Instant::now();
    let data = bench.dataset(&s.sim, motion, seed, &mut |d, t| progress(label, d, t))?;
    timings.simulate += clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    let mut step = stage_progress(label, progress);
    let rows = bench.features(
        &s.sim,
        motion,
        seed,
        &s.features,
        scenario.feature_set(),
        &mut step,
    )?;
    timings.features += clock.elapsed().as_secs_f64();
    let truth = data
        .truth_positions()
        .ok_or_else(|| ExperimentError::NoTruth(label.to_string()))?;
    let times = data.frames.iter().map(|f| f.t).collect();
    Ok((truth, times, rows))
}

/// Progress of [`Workbench::features`] under `label`: its simulation as `label`, its
/// extraction as `label features`.
fn stage_progress<'a>(
    label: &'a str,
    progress: Progress<'a>,
) -> impl FnMut(Step, usize, usize) + 'a {
    let extracting = format!("{label} features");
    move |step, done, total| match step {
        Step::Simulate => progress(label, done, total),
        Step::Extract => progress(&extracting, done, total),
    }
}

/// Runs several scenarios on `jobs` threads sharing one workbench; results come back in input
/// order. `progress(variant, stage, done, total)` may be called from any thread.
pub fn run_all(
    scenarios: &[CheckedScenario],
    jobs: usize,
    bench: &Workbench,
    progress: &(dyn Fn(usize, &str, usize, usize) + Sync),
) -> Vec<Result<RunOutput, ExperimentError>> {
    let results: Mutex<Vec<Option<Result<RunOutput, ExperimentError>>>> =
        Mutex::new((0..scenarios.len()).map(|_| None).collect());
    run_each(scenarios, jobs, bench, progress, &|i, result| {
        results.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(result);
    });
    results
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .map(|r| r.unwrap_or(Err(ExperimentError::NotRun)))
        .collect()
}

/// [`run_all`] handing each result to `finished(variant, result)` as soon as it is ready (on the
/// thread that ran it), so that a sweep can write each run's files before the others finish.
///
/// With `jobs` ≥ 2 the longest runs start first; results do not depend on the order.
pub fn run_each(
    scenarios: &[CheckedScenario],
    jobs: usize,
    bench: &Workbench,
    progress: &(dyn Fn(usize, &str, usize, usize) + Sync),
    finished: &(dyn Fn(usize, Result<RunOutput, ExperimentError>) + Sync),
) {
    // Longest first, so that no long run is left alone on the machine at the end.
    let mut order: Vec<usize> = (0..scenarios.len()).collect();
    if jobs > 1 {
        order.sort_by(|&a, &b| {
            expected_cost(&scenarios[b]).total_cmp(&expected_cost(&scenarios[a]))
        });
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    std::thread::scope(|scope| {
        for _ in 0..jobs.clamp(1, scenarios.len().max(1)) {
            scope.spawn(|| loop {
                let t = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(&i) = order.get(t) else {
                    break;
                };
                let result = run(&scenarios[i], bench, &mut |stage, done, total| {
                    progress(i, stage, done, total)
                });
                finished(i, result);
            });
        }
    });
}

/// A rough, relative cost of running `scenario`, to start the longest runs first: the Gaussian
/// process and continuous fits dominate, growing with the feature count and, cubically, with
/// the samples kept. It only orders the runs; the results do not depend on it.
fn expected_cost(scenario: &CheckedScenario) -> f64 {
    let s = scenario.get();
    let heavy = s.estimators.iter().filter(|m| m.entry().heavy_fit).count();
    let kept = 1.0 / s.sample.keep_every.max(1) as f64;
    let features = scenario.feature_set().len() as f64;
    (heavy as f64 + 0.01 * s.estimators.len() as f64) * features * kept.powi(3)
}

/// A motion whose dataset a run asks the workbench for.
struct Need<'a> {
    motion: &'a Motion,
    seed: u64,
    /// The stage name the run shows while it is simulated.
    label: String,
}

/// Simulates the run's motions side by side into `bench` (the sample trajectory on this thread,
/// showing its progress); the run then takes them from the workbench, failures included.
fn simulate_ahead(
    scenario: &CheckedScenario,
    bench: &Workbench,
    progress: Progress<'_>,
    timings: &mut Timings,
) {
    let s = scenario.get();
    let clock = Instant::now();
    let needs = needs(scenario);
    std::thread::scope(|scope| {
        for need in &needs[1..] {
            scope.spawn(move || bench.dataset(&s.sim, need.motion, need.seed, &mut |_, _| {}));
        }
        let sample = &needs[0];
        let _ = bench.dataset(&s.sim, sample.motion, sample.seed, &mut |d, t| {
            progress(&sample.label, d, t)
        });
    });
    timings.simulate += clock.elapsed().as_secs_f64();
}

/// The sample, validation and test motions of a run, with the seeds and stage names `run` uses
/// (the adaptive rounds depend on the fit, so they are not here).
fn needs(scenario: &CheckedScenario) -> Vec<Need<'_>> {
    let s = scenario.get();
    let master = s.seed;
    let mut needs = vec![Need {
        motion: &s.sample.motion,
        seed: seed::for_part(master, ScenarioPart::Sample),
        label: SAMPLE_STAGE.to_string(),
    }];
    if let Some(motion) = &s.validation {
        needs.push(Need {
            motion,
            seed: seed::for_part(master, ScenarioPart::Validation),
            label: VALIDATION_STAGE.to_string(),
        });
    }
    if let Some(motion) = &s.calibration {
        needs.push(Need {
            motion,
            seed: seed::for_part(master, ScenarioPart::Calibration),
            label: CALIBRATION_STAGE.to_string(),
        });
    }
    for (k, motion) in s.tests.iter().enumerate() {
        needs.push(Need {
            motion,
            seed: seed::for_part(master, ScenarioPart::Test(k)),
            label: test_label(k, motion),
        });
    }
    needs
}

/// The stage name of the sample trajectory's simulation.
const SAMPLE_STAGE: &str = "sample";
/// The stage name of the validation motion's simulation.
const VALIDATION_STAGE: &str = "the validation motion";
/// The stage name of the calibration motion's simulation.
const CALIBRATION_STAGE: &str = "the calibration motion";

/// The name of test motion `k` in records, progress and errors (`test0:lissajous`).
fn test_label(k: usize, motion: &Motion) -> String {
    format!("test{k}:{}", motion.name())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_penalty_is_the_workspace_diagonal() {
        let diagonal = missing_penalty(&SimSettings::default());
        assert!((diagonal - 19.0 * 2f64.sqrt()).abs() < 1e-9);
    }
}
