//! The `evitrack` command line.
fn main() {}
