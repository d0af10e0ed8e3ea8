//! evitrack — an evidential-reasoning (Dempster–Shafer) pose tracker.
//!
//! Train on a folder of frames with ground-truth poses, then track another folder:
//!
//! ```
//! use evitrack::dataset::Dataset;
//! use evitrack::estimator::{DatasetFeatures, Evidential, EvidentialSettings, PoseEstimator, TrainingSet};
//! use evitrack::features::FeatureConfig;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! # let dir = tempfile::tempdir()?;
//! # let (sample_dir, test_dir) = (dir.path().join("sample"), dir.path().join("test"));
//! # let rig = evitrack::sim::SimSettings::default();
//! # let mesh = evitrack::sim::Motion::Mesh { spacing: 1.0 };
//! # evitrack::sim::simulate(&rig, &mesh, 1, &mut |_, _| {})?.write(&sample_dir)?;
//! # let circle: evitrack::sim::Motion =
//! #     toml::from_str("kind = 'circle'\nradius = 5\nspeed = 10\nduration = 2\nfps = 10")?;
//! # evitrack::sim::simulate(&rig, &circle, 2, &mut |_, _| {})?.write(&test_dir)?;
//! // The sample trajectory: frames and poses on disk (PNG + poses.csv + manifest.json).
//! let sample = Dataset::read(&sample_dir)?;
//! let config = FeatureConfig::with_barycentre(); // 6 size functions + the barycentre
//! let features = config.check()?;
//! let labelled = DatasetFeatures::extract(&sample, &features, "the sample trajectory")?;
//! let names = features.names();
//! let training = TrainingSet::new(&names, labelled.labelled()).with_config(&config);
//! let estimator = Evidential::fit(&EvidentialSettings::default(), &training)?;
//!
//! // Any other recorded frames: one estimate (and its diagnostics) per frame.
//! let test = Dataset::read(&test_dir)?;
//! let mut total = 0.0;
//! for frame in &test.frames {
//!     let estimate = estimator.estimate(&features.extract(&frame.image))?;
//!     let (pose, truth) = (estimate.pose.unwrap(), frame.truth.unwrap());
//!     total += (pose[0] - truth.x).hypot(pose[1] - truth.y);
//! }
//! assert!(total / (test.len() as f64) < 2.0, "mean error in mm");
//! // The model file is self-contained: `evitrack track DATASET --model model.json` reads it.
//! std::fs::write(dir.path().join("model.json"), estimator.to_json()?)?;
//! # Ok(())
//! # }
//! ```
//!
//! The pipeline, one way: a simulated five-bar robot ([`sim`]) moves its end-effector and a
//! software camera renders frames; frames and ground-truth poses form a [`dataset`], the seam where
//! recorded data from a real camera can enter instead. [`features`] turn each image into scalar
//! features. Every pose [`estimator`] plugs into one seam: it is fitted on the features of a
//! sample trajectory and estimates a pose per frame. The paper's evidential estimator quantises
//! each feature with one Gaussian [`hmm`] into a frame of discernment whose states refine onto the
//! sample poses (the evidential [`model`]); its [`track`]er turns each new frame's features into
//! belief functions ([`evidence`]), projects them onto the sample poses, keeps the most coherent
//! group by its conflict graph, combines it with Dempster's rule and estimates the pose from the
//! relative plausibilities. [`scenario`] files drive [`experiment`]s whose results the [`report`]
//! module writes as tables, CSV, JSON and plots; every random draw derives from one [`seed`].
#![deny(missing_docs)]

pub mod adaptive;
pub mod atomic;
pub mod dataset;
pub mod estimator;
pub mod evidence;
pub mod experiment;
pub mod external;
pub mod faults;
pub mod feature_report;
pub mod features;
pub(crate) mod gaussian_process;
pub mod hmm;
pub mod information;
pub mod memory;
pub mod model;
pub mod model_file;
pub mod planar;
pub mod range;
pub mod report;
pub mod scenario;
pub mod seed;
pub mod sim;
mod simd;
pub mod standardisation;
pub mod track;
