//! The sample trajectory of a scenario: the simulated motion, every k-th sample kept, and the
//! adaptive refinement of §3.1 (the model's features say where samples are missing, the world
//! renders them). `run` trains on it; `simulate --part sample` writes exactly these frames.

use std::time::Instant;

use super::{ExperimentError, Progress, Timings, Workbench};
use crate::dataset::{frame_file_name, Dataset};
use crate::features::FeatureRows;
use crate::scenario::CheckedScenario;
use crate::seed::{self, ScenarioPart};
use crate::sim::Motion;

/// The sample trajectory a run trains on.
#[derive(Debug, Clone)]
pub struct SampleTrajectory {
    /// Its frames: the kept samples, then the adaptive ones (files renumbered in that order).
    pub dataset: Dataset,
    /// Ground-truth pose of every sample (mm).
    pub poses: Vec<[f64; 2]>,
    /// Feature rows, one per sample.
    pub rows: FeatureRows,
    /// For each sample, the adaptive round that added it (0: the initial trajectory).
    pub rounds: Vec<usize>,
}

impl SampleTrajectory {
    /// Samples added by the adaptive trajectory.
    pub fn adaptive_added(&self) -> usize {
        self.rounds.iter().filter(|&&r| r > 0).count()
    }
}

/// Simulates (or takes from `bench`) the scenario's sample trajectory.
pub fn sample_trajectory(
    scenario: &CheckedScenario,
    bench: &Workbench,
    progress: Progress<'_>,
    timings: &mut Timings,
) -> Result<SampleTrajectory, ExperimentError> {
    let s = scenario.get();
    let sim = &s.sim;
    let set = scenario.feature_set();
    let clock = Instant::now();
    let sample_seed = seed::for_part(s.seed, ScenarioPart::Sample);
    let motion = &s.sample.motion;
    let full = bench.dataset(sim, motion, sample_seed, &mut |d, t| {
        progress(super::SAMPLE_STAGE, d, t)
    })?;
    timings.simulate += clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    let all_rows = {
        let mut step = super::stage_progress(super::SAMPLE_STAGE, progress);
        bench.features(sim, motion, sample_seed, &s.features, set, &mut step)?
    };
    timings.features += clock.elapsed().as_secs_f64();
    let what = "the sample trajectory";
    let all_poses = full
        .truth_positions()
        .ok_or_else(|| ExperimentError::NoTruth(what.into()))?;
    let keep = s.sample.keep_every;
    let mut frames: Vec<_> = full.frames.iter().step_by(keep).cloned().collect();
    let mut poses: Vec<[f64; 2]> = all_poses.iter().step_by(keep).copied().collect();
    let mut rows: FeatureRows = all_rows.iter().step_by(keep).cloned().collect();
    let mut rounds = vec![0; poses.len()];

    if let Some(adaptive) = &s.sample.adaptive {
        let clock = Instant::now();
        let mut round = 0usize;
        let mut added_frames = Vec::new();
        let workspace = sim.geometry.workspace;
        let outcome = crate::adaptive::refine(poses.clone(), rows, adaptive, |points| {
            round += 1;
            // Midpoints of boundary samples can lie a few µm outside the workspace, because the
            // samples are simulated (not commanded) poses: clamp them back in.
            let points = points
                .iter()
                .map(|p| {
                    [
                        p[0].clamp(workspace.x_min, workspace.x_max),
                        p[1].clamp(workspace.y_min, workspace.y_max),
                    ]
                })
                .collect();
            let motion = Motion::Points { points };
            let seed = seed::for_adaptive_round(s.seed, round);
            let threads = bench.threads();
            let data = crate::sim::simulate_on(sim, &motion, seed, threads, &mut |d, t| {
                progress("adaptive", d, t)
            })
            .map_err(|e| e.to_string())?;
            if data.truth_positions().is_none() {
                return Err("the simulator gave no ground truth".to_string());
            }
            let features = crate::external::extract(set, &data, threads, &mut |d, t| {
                progress("adaptive features", d, t)
            })
            .map_err(|e| e.to_string())?;
            added_frames.extend(data.frames);
            Ok(features)
        })?;
        for (round, &count) in outcome.added_per_round.iter().enumerate() {
            rounds.extend(std::iter::repeat_n(round + 1, count));
        }
        for frame in &added_frames {
            if let Some(t) = frame.truth {
                poses.push([t.x, t.y]);
            }
        }
        frames.extend(added_frames);
        rows = outcome.features;
        timings.simulate += clock.elapsed().as_secs_f64();
    }

    // Each adaptive batch starts its clock at 0: shift it to follow the frame before, so the
    // dataset's times keep increasing (1 ms between batches).
    let mut shift = 0.0;
    let mut previous = f64::NEG_INFINITY;
    for (k, frame) in frames.iter_mut().enumerate() {
        frame.file = frame_file_name(k);
        if frame.t + shift < previous {
            shift = previous - frame.t + 1e-3;
        }
        frame.t += shift;
        previous = frame.t;
    }
    let mut manifest = full.manifest.clone();
    manifest.frame_count = frames.len();
    Ok(SampleTrajectory {
        dataset: Dataset { manifest, frames },
        poses,
        rows,
        rounds,
    })
}
