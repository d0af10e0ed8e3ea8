//! evitrack — an evidential-reasoning (Dempster–Shafer) pose tracker.
//!
//! The pipeline, one way: a simulated five-bar robot ([`sim`]) moves its end-effector and a
//! software camera renders frames; frames and ground-truth poses form a [`dataset`], the seam where
//! recorded data from a real camera can enter instead. [`features`] turn each image into scalar
//! features. On a sample trajectory, one Gaussian [`hmm`] per feature quantises it into a frame of
//! discernment whose states refine onto the sample poses: the evidential [`model`]. The [`track`]er
//! turns each new frame's features into belief functions ([`evidence`]), projects them onto the
//! sample poses, keeps the most coherent group by its conflict graph, combines it with Dempster's
//! rule and estimates the pose from the relative plausibilities. [`scenario`] files drive
//! [`experiment`]s whose results the [`report`] module writes as tables, CSV, JSON and plots.
#![deny(missing_docs)]

pub mod adaptive;
pub mod dataset;
pub mod estimator;
pub mod evidence;
pub mod experiment;
pub mod features;
pub mod hmm;
pub mod model;
pub mod report;
pub mod scenario;
pub mod seed;
pub mod sim;
pub mod track;
