//! Integration tests: one binary, one module per room.

mod adaptive;
mod baselines;
mod cli;
mod confidence;
mod conformance;
mod continuous;
mod dataset;
mod evidence;
mod external_features;
mod faults;
mod features;
mod front_door;
mod fuzz_corpus;
mod hmm;
mod model;
mod pipeline;
mod reference;
mod reliability;
mod scheduler;
mod sim;
mod temporal;
mod toy_method;
mod track;
