//! How often each fault kind changes each feature: every fault on its own, on a seeded sample of
//! the frames, judged by the faults module's own test of a changed value.

use std::collections::BTreeMap;

use crate::dataset::Dataset;
use crate::faults::{FaultPlan, FaultSpec, FeatureScale};
use crate::features::FeatureSet;

use super::FeatureReportError;

/// Per feature and fault, the share of the struck frames the fault changed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FaultChanges {
    /// Frames each fault was applied to.
    pub frames: usize,
    /// Fault names, in order.
    pub faults: Vec<String>,
    /// Per feature: fault name → share of its struck frames whose value changed.
    pub per_feature: Vec<BTreeMap<String, f64>>,
}

/// The image faults of `src/faults/`, one of each, on every frame: a dark and a bright
/// 15 × 15 px box and a glare blob at the frame's centre, 1 % salt-and-pepper pixels, a black
/// frame.
pub fn default_faults(width: u32, height: u32) -> Vec<FaultSpec> {
    let (cx, cy) = (f64::from(width) / 2.0, f64::from(height) / 2.0);
    let text = format!(
        r#"
        [[faults]]
        kind = "occluder"
        name = "dark_box"
        rect = [{x}, {y}, 15, 15]
        intensity = 0
        [[faults]]
        kind = "occluder"
        name = "bright_box"
        rect = [{x}, {y}, 15, 15]
        intensity = 255
        [[faults]]
        kind = "glare"
        centre = [{cx}, {cy}]
        radius = 8
        [[faults]]
        kind = "salt_pepper"
        density = 0.01
        [[faults]]
        kind = "black"
        "#,
        x = (cx - 7.5).floor(),
        y = (cy - 7.5).floor(),
    );
    #[derive(serde::Deserialize)]
    struct Faults {
        faults: Vec<FaultSpec>,
    }
    // A fixed text of valid tables: parsing cannot fail, and an empty list would only report
    // no faults.
    toml::from_str::<Faults>(&text)
        .map(|f| f.faults)
        .unwrap_or_default()
}

/// Applies each of `specs` alone (seeded by `seed`) to at most `max_frames` evenly spaced frames
/// of `dataset`, whose clean features are `rows`, and counts the changed values.
///
/// # Errors
/// An invalid spec (named); a feature program that fails on the faulted frames.
pub fn fault_changes(
    specs: &[FaultSpec],
    set: &FeatureSet,
    dataset: &Dataset,
    rows: &[Vec<Option<f64>>],
    max_frames: usize,
    seed: u64,
    threads: usize,
) -> Result<FaultChanges, FeatureReportError> {
    let names = set.names();
    let size = [
        dataset.manifest.camera.width,
        dataset.manifest.camera.height,
    ];
    // Checked together, so that an error names the spec's place in the list.
    FaultPlan::check(specs, &names, size)?;
    let total = dataset.len().min(rows.len());
    let count = total.min(max_frames);
    let chosen: Vec<usize> = (0..count).map(|k| k * total / count.max(1)).collect();
    let mut manifest = dataset.manifest.clone();
    manifest.frame_count = chosen.len();
    let sample = Dataset {
        manifest,
        frames: chosen.iter().map(|&i| dataset.frames[i].clone()).collect(),
    };
    let clean: Vec<Vec<Option<f64>>> = chosen.iter().map(|&i| rows[i].clone()).collect();
    let scales = FeatureScale::of_rows(rows, names.len());
    let mut out = FaultChanges {
        frames: chosen.len(),
        faults: Vec::new(),
        per_feature: vec![BTreeMap::new(); names.len()],
    };
    for (k, spec) in specs.iter().enumerate() {
        let name = spec.name.clone().unwrap_or_else(|| {
            serde_json::to_value(spec.kind)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_else(|| format!("fault{k}"))
        });
        // Two specs of one kind without names stay apart.
        let name = if out.faults.contains(&name) {
            format!("{name}#{k}")
        } else {
            name
        };
        let plan = FaultPlan::check(std::slice::from_ref(spec), &names, size)?;
        let corrupted = plan.apply_with(
            crate::seed::derive(seed, &format!("report-fault{k}")),
            sample.images(),
            &clean,
            &scales,
            &mut |at, images| {
                crate::experiment::corrupted_features(set, &sample, at, images, threads)
            },
        )?;
        let struck: Vec<_> = corrupted
            .labels
            .iter()
            .filter(|l| !l.faults.is_empty())
            .collect();
        for (j, per) in out.per_feature.iter_mut().enumerate() {
            let changed = struck.iter().filter(|l| l.changed.contains(&j)).count();
            let share = if struck.is_empty() {
                0.0
            } else {
                changed as f64 / struck.len() as f64
            };
            per.insert(name.clone(), share);
        }
        out.faults.push(name);
    }
    Ok(out)
}
