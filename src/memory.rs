//! What a run will hold in memory, estimated from its checked settings before anything large is
//! allocated, and the one limit runs are held to (`--memory-limit` of `run`, `sweep`, `train`).
//!
//! The estimate adds up the large allocations, each with the setting that sizes it: the
//! continuous surrogates' tabulated grid (nodes × features × 4 values, once per run: the methods
//! that fit the same surrogates share it), the Gaussian processes' kernel matrices (n² for the
//! factorisation on every sample, m² per optimiser start), the discrete tracker's sub-grid,
//! particle sets, k-NN samples and the images of every motion (a run keeps them all, the kept
//! samples twice: the dense trajectory's and their copy). Transient
//! and lasting allocations are added as if held at once, so it errs high.

use crate::estimator::REFINE_SUBDIVISIONS;
use crate::estimator::{grid_nodes, EstimatorSettings, Method, RenderSource, REFINE_MAX_POINTS};
use crate::scenario::CheckedScenario;

/// What a tiny run fills besides its parts (the binary's pages, buffers): its peak RSS was 22 MB.
pub const BASE_BYTES: u64 = 24 << 20;

/// Address space a process maps but does not fill, per thread that allocates: glibc reserves a
/// 64 MiB arena (at most 8 per core), plus a 2 MiB stack.
const THREAD_RESERVE: u64 = 66 << 20;

/// The binary and its libraries, mapped.
const MAPPED_BINARY: u64 = 128 << 20;

/// When neither `--memory-limit` nor any machine figure is known.
pub const FALLBACK_LIMIT: u64 = 4 << 30;

/// Failures of reading a limit or holding an estimate to it.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MemoryError {
    /// A limit that is not a size.
    #[error("memory limit `{text}`: {reason} (write e.g. `4GiB`, `1500MB` or a number of bytes)")]
    BadLimit {
        /// As given.
        text: String,
        /// What is wrong.
        reason: String,
    },
    /// The estimate is over the limit; the sentence names the costliest settings.
    #[error("{0}")]
    OverLimit(String),
    /// A motion of a checked scenario could not be planned again.
    #[error("estimating the memory of `{scenario}`: {reason}")]
    Plan {
        /// The scenario.
        scenario: String,
        /// The planner's error.
        reason: String,
    },
}

/// One large allocation: what it is, the setting that sizes it, its bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct Part {
    /// What is allocated (`"continuous surrogate grid, 1000 × 1000 nodes × 7 features"`).
    pub what: String,
    /// The setting to change to shrink it (`"continuous.grid_spacing = 0.02"`).
    pub setting: String,
    /// Bytes.
    pub bytes: u64,
}

/// A run's estimated peak: [`BASE_BYTES`] plus its parts.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// The run (scenario or variant name).
    pub name: String,
    /// Its large allocations.
    pub parts: Vec<Part>,
}

impl Estimate {
    /// Base plus every part.
    pub fn total(&self) -> u64 {
        BASE_BYTES.saturating_add(self.parts.iter().map(|p| p.bytes).sum())
    }
}

/// What a fit's memory depends on besides the settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitShape {
    /// Sample poses (at most).
    pub samples: usize,
    /// Features.
    pub features: usize,
    /// The samples' extent (mm) in x and y (at most the workspace's).
    pub extent: [f64; 2],
}

const F64: u64 = 8;

fn square_bytes(n: usize, matrices: u64) -> u64 {
    (n as u64)
        .saturating_mul(n as u64)
        .saturating_mul(F64 * matrices)
}

/// The large allocations of fitting and running `methods` with `settings` on data of `shape`.
pub fn fit_parts(methods: &[Method], settings: &EstimatorSettings, shape: &FitShape) -> Vec<Part> {
    let n = shape.samples;
    let d = shape.features as u64;
    let part = |what: String, setting: String, bytes: u64| Part {
        what,
        setting,
        bytes,
    };
    let sample_setting = format!("the sample trajectory ({n} poses)");
    let mut parts = Vec::new();
    let uses = |m: Method| methods.contains(&m);
    let surrogates = [
        Method::CONTINUOUS,
        Method::CONTINUOUS_TEMPORAL,
        Method::PARTICLE_FILTER,
    ];
    if surrogates.into_iter().any(uses) {
        let c = &settings.continuous;
        let [gx, gy] = grid_nodes(shape.extent, c.grid_spacing);
        // f, ∂x, ∂y, ∂xy per node and feature; one grid per run, however many methods use it.
        let grid = (gx as u64 * gy as u64).saturating_mul(d * 4 * F64);
        parts.push(part(
            format!("continuous surrogate grid, {gx} × {gy} nodes × {d} features"),
            format!("continuous.grid_spacing = {}", c.grid_spacing),
            grid,
        ));
        if uses(Method::CONTINUOUS) || uses(Method::CONTINUOUS_TEMPORAL) {
            // A frame's groups keep the nodes within their cut, with 7 sums each: up to a grid's worth.
            parts.push(part(
                format!("continuous kept nodes of a frame's groups, up to {gx} × {gy}"),
                format!("continuous.grid_spacing = {}", c.grid_spacing),
                (gx as u64 * gy as u64).saturating_mul(7 * F64 + 4),
            ));
        }
        if uses(Method::CONTINUOUS_TEMPORAL) {
            // The carried belief's residual and slopes per node of the blocks a frame visits: at
            // most every node, one frame at a time.
            parts.push(part(
                format!("continuous_temporal carried belief, {gx} × {gy} nodes"),
                format!("continuous.grid_spacing = {}", c.grid_spacing),
                (gx as u64 * gy as u64).saturating_mul(3 * F64),
            ));
        }
        if uses(Method::PARTICLE_FILTER) {
            // Its block evaluation reads the table regrouped by four features: a second copy
            // of the first `d − d % 4` features' values and slopes.
            let grouped = d - d % 4;
            parts.push(part(
                format!("particle filter's table regrouped by four features, {gx} × {gy} nodes × {grouped} features"),
                format!("continuous.grid_spacing = {}", c.grid_spacing),
                (gx as u64 * gy as u64).saturating_mul(grouped * 4 * F64),
            ));
        }
        // Kernel, its factor and the leave-one-out inverse, one feature at a time.
        parts.push(part(
            "continuous surrogate kernel matrices".into(),
            sample_setting.clone(),
            square_bytes(n, 3),
        ));
        // Two features fitted at once, each with its kernel, factor and inverse.
        parts.push(part(
            "continuous hyperparameter fit".into(),
            format!("continuous.max_fit_samples = {}", c.max_fit_samples),
            square_bytes(n.min(c.max_fit_samples), 6),
        ));
    }
    if uses(Method::GP) {
        let g = &settings.gp;
        parts.push(part(
            format!("GP hyperparameter fit, {} starts at once", g.starts),
            format!("gp.max_fit_samples = {}", g.max_fit_samples),
            square_bytes(n.min(g.max_fit_samples), 3 * g.starts as u64),
        ));
        parts.push(part(
            "GP kernel matrices".into(),
            sample_setting.clone(),
            square_bytes(n, 3),
        ));
    }
    if uses(Method::EVIDENTIAL_TEMPORAL) {
        // Each sample's cell is about one spacing square: SUBDIVISIONS² points, twice for margin.
        let points = (n as f64 * 2.0 * REFINE_SUBDIVISIONS * REFINE_SUBDIVISIONS)
            .min(REFINE_MAX_POINTS) as u64;
        parts.push(part(
            format!("evidential_temporal sub-grid, {points} points"),
            sample_setting.clone(),
            points * 24,
        ));
    }
    if uses(Method::PARTICLE_FILTER) {
        let p = settings.particle_filter.particles as u64;
        // Per particle: its pose and the resampled copy (16 + 16), its draw (24), weight,
        // log-likelihood and p̂/q (8 each), the radius's two key buffers (16 + 16).
        parts.push(part(
            format!("particle sets, {p} particles"),
            format!("particle_filter.particles = {p}"),
            p * 112,
        ));
    }
    let row_users = [Method::KNN, Method::EVIDENTIAL, Method::EVIDENTIAL_TEMPORAL];
    if row_users.into_iter().any(uses) {
        parts.push(part(
            "kept sample rows and cells".into(),
            sample_setting,
            (n as u64).saturating_mul(d * 64),
        ));
    }
    parts
}

/// One run's estimate from its checked scenario (before anything is simulated).
///
/// # Errors
/// [`MemoryError::Plan`] if a motion cannot be planned (a checked scenario's always can).
pub fn of_run(scenario: &CheckedScenario) -> Result<Estimate, MemoryError> {
    let s = scenario.get();
    let fail = |reason: String| MemoryError::Plan {
        scenario: s.name.clone(),
        reason,
    };
    let rig = s.sim.check().map_err(|e| fail(e.to_string()))?;
    let frames = |m: &crate::sim::Motion| {
        m.targets(&rig.five_bar)
            .map(|t| t.len())
            .map_err(|e| fail(e.to_string()))
    };
    let dense = frames(&s.sample.motion)?;
    let kept = dense.div_ceil(s.sample.keep_every.max(1));
    // The adaptive budget caps the total sample count; the added samples are new frames.
    let samples = s
        .sample
        .adaptive
        .as_ref()
        .map_or(kept, |a| a.max_samples.max(kept));
    let adaptive = samples - kept;
    let mut other = 0;
    for m in s.validation.iter().chain(&s.calibration) {
        other += frames(m)?;
    }
    let mut test = 0;
    for m in &s.tests {
        test += frames(m)?;
    }
    // The kept samples are a copy of the dense trajectory's frames (both held), and faulted
    // images a second copy of the test motions'.
    let copies = if scenario.fault_plan().is_empty() {
        1
    } else {
        2
    };
    let held = dense + samples + adaptive + other + copies * test;
    let features = scenario.feature_set().names().len();
    let camera = &s.sim.camera;
    let w = &s.sim.geometry.workspace;
    let shape = FitShape {
        samples,
        features,
        extent: [w.x_max - w.x_min, w.y_max - w.y_min],
    };
    let mut parts = vec![Part {
        what: format!(
            "images of every motion, {held} frames of {} × {} px",
            camera.width, camera.height
        ),
        setting: format!(
            "sim.camera.width × height = {} × {} and the motions' frames",
            camera.width, camera.height
        ),
        bytes: (held as u64).saturating_mul(camera.width as u64 * camera.height as u64),
    }];
    // Every frame's row of optional values (16 bytes each), the kept ones copied too.
    parts.push(Part {
        what: format!("feature rows, {held} frames × {features} features"),
        setting: "the features and the motions' frames".into(),
        bytes: (held as u64).saturating_mul(features as u64 * 16),
    });
    // The render check from the samples keeps a distance field per sample, 2 bytes a pixel;
    // either source keeps the calibration and test frames' silhouettes, a bit a pixel.
    let confidence = &s.confidence;
    let calibration = s.calibration.as_ref().or(s.validation.as_ref());
    let calibration_frames = calibration.map(frames).transpose()?;
    if confidence.render_check_on(calibration_frames) {
        let pixels = camera.width as u64 * camera.height as u64;
        let checked = calibration_frames.unwrap_or(0) + test;
        parts.push(Part {
            what: format!("the render check's silhouettes, {checked} frames, a bit a pixel"),
            setting: "confidence.render_check".into(),
            bytes: (checked as u64).saturating_mul(pixels.div_ceil(64) * 8),
        });
        if confidence.render_from == RenderSource::Samples {
            parts.push(Part {
                what: format!(
                    "the render check's distance fields, {samples} samples of {} × {} px",
                    camera.width, camera.height
                ),
                setting: "confidence.render_check with render_from = \"samples\"".into(),
                bytes: (samples as u64).saturating_mul(pixels * 2),
            });
        }
    }
    parts.extend(fit_parts(&s.estimators, &s.estimator_settings(), &shape));
    Ok(Estimate {
        name: s.name.clone(),
        parts,
    })
}

/// Where a limit came from, for the message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LimitSource {
    /// `--memory-limit`.
    Option,
    /// The address-space limit less what `jobs` runs map but do not fill, or three quarters of
    /// the machine's memory, whichever is smaller.
    Machine,
    /// [`FALLBACK_LIMIT`].
    Fallback,
}

/// The limit estimates are held to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limit {
    /// Bytes.
    pub bytes: u64,
    /// Where it came from.
    pub source: LimitSource,
}

impl Limit {
    /// `--memory-limit` if given, else [`Limit::machine`] for `jobs` runs at once.
    pub fn from_option(bytes: Option<u64>, jobs: usize) -> Self {
        match bytes {
            Some(bytes) => Self {
                bytes,
                source: LimitSource::Option,
            },
            None => Self::machine(jobs),
        }
    }

    /// The smaller of the process's address-space limit (`ulimit -v`) less what `jobs` runs
    /// map without filling ([`reserved_address_space`]) and three quarters of the machine's
    /// memory; [`FALLBACK_LIMIT`] when neither is known.
    pub fn machine(jobs: usize) -> Self {
        let read = |path| std::fs::read_to_string(path).unwrap_or_default();
        let address_space = read("/proc/self/limits")
            .lines()
            .find(|l| l.starts_with("Max address space"))
            .and_then(|l| l.split_whitespace().nth(3)?.parse::<u64>().ok());
        let total = read("/proc/meminfo")
            .lines()
            .find(|l| l.starts_with("MemTotal:"))
            .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
            .map(|kb| kb.saturating_mul(1024) / 4 * 3);
        let address_space = address_space.map(|b| b.saturating_sub(reserved_address_space(jobs)));
        match address_space.into_iter().chain(total).min() {
            Some(bytes) => Self {
                bytes,
                source: LimitSource::Machine,
            },
            None => Self {
                bytes: FALLBACK_LIMIT,
                source: LimitSource::Fallback,
            },
        }
    }
}

/// Address space `jobs` runs at once map but do not fill: the binary, and per allocating thread
/// (about three per run and two more, at most 8 per core) an allocator arena and a stack. A
/// run that fills 170 MB mapped 507 MB.
pub fn reserved_address_space(jobs: usize) -> u64 {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = jobs.saturating_mul(3).saturating_add(2).min(8 * cores);
    MAPPED_BINARY + threads as u64 * THREAD_RESERVE
}

/// Holds `jobs` runs at once to `limit`: the `jobs` largest estimates run side by side (one
/// base between them).
///
/// # Errors
/// [`MemoryError::OverLimit`] naming the total, the limit, the costliest parts and their settings.
pub fn check(estimates: &[Estimate], jobs: usize, limit: Limit) -> Result<(), MemoryError> {
    let mut order: Vec<&Estimate> = estimates.iter().collect();
    order.sort_by_key(|e| std::cmp::Reverse(e.total()));
    let at_once = &order[..jobs.max(1).min(order.len())];
    let need = BASE_BYTES.saturating_add(
        (at_once.iter())
            .map(|e| e.total() - BASE_BYTES)
            .fold(0u64, u64::saturating_add),
    );
    if need <= limit.bytes {
        return Ok(());
    }
    let Some(largest) = at_once.first() else {
        return Ok(());
    };
    let mut parts: Vec<&Part> = largest.parts.iter().collect();
    parts.sort_by_key(|p| std::cmp::Reverse(p.bytes));
    let costliest: Vec<String> = (parts.iter().take(3))
        .map(|p| format!("{} ({}, set by `{}`)", p.what, size(p.bytes), p.setting))
        .collect();
    let runs = match at_once.len() {
        1 => format!("`{}` would need about {}", largest.name, size(need)),
        k => format!(
            "{k} runs at once (`--jobs`) would need about {}, `{}` alone {}",
            size(need),
            largest.name,
            size(largest.total())
        ),
    };
    let whence = match limit.source {
        LimitSource::Option => "`--memory-limit`",
        LimitSource::Machine => {
            "the default: `ulimit -v` less what the runs map unfilled, or 3/4 of the memory"
        }
        LimitSource::Fallback => "the default",
    };
    let top = parts.first().map_or("the settings", |p| p.setting.as_str());
    Err(MemoryError::OverLimit(format!(
        "{runs}, over the memory limit of {} ({whence}); the costliest: {}. Change `{top}` \
         (a coarser grid, fewer samples or particles), run fewer `--jobs`, or raise \
         `--memory-limit` if the machine has the memory",
        size(limit.bytes),
        costliest.join("; ")
    )))
}

/// `bytes` in KiB, MiB or GiB, for messages.
pub fn size(bytes: u64) -> String {
    let b = bytes as f64;
    match bytes {
        n if n >= 1 << 30 => format!("{:.2} GiB", b / (1u64 << 30) as f64),
        n if n >= 1 << 20 => format!("{:.0} MiB", b / (1u64 << 20) as f64),
        _ => format!("{:.0} KiB", b / 1024.0),
    }
}

/// Reads a size: a number with an optional unit, `B`, `K`/`KB` (10³), `KiB` (2¹⁰), `M`, `MB`,
/// `MiB`, `G`, `GB`, `GiB`, `T`, `TB`, `TiB` (any case, a space allowed).
///
/// # Errors
/// [`MemoryError::BadLimit`] for anything else, zero, or a size beyond 2⁶⁴ bytes.
pub fn parse_size(text: &str) -> Result<u64, MemoryError> {
    let bad = |reason: &str| MemoryError::BadLimit {
        text: text.to_string(),
        reason: reason.to_string(),
    };
    let trimmed = text.trim();
    let split = trimmed
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(trimmed.len());
    let (number, unit) = trimmed.split_at(split);
    let value: f64 = number.parse().map_err(|_| bad("no number"))?;
    let factor: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kb" => 1e3,
        "m" | "mb" => 1e6,
        "g" | "gb" => 1e9,
        "t" | "tb" => 1e12,
        "kib" => 1024.0,
        "mib" => 1024f64.powi(2),
        "gib" => 1024f64.powi(3),
        "tib" => 1024f64.powi(4),
        _ => return Err(bad("unknown unit")),
    };
    let bytes = value * factor;
    if bytes < 1.0 {
        return Err(bad("must be at least one byte"));
    }
    if bytes >= u64::MAX as f64 {
        return Err(bad("too large"));
    }
    Ok(bytes as u64)
}

#[cfg(test)]
#[path = "memory_tests.rs"]
mod tests;
