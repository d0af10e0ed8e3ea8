//! A feature program, as `[[features.external]]` runs one: given a dataset folder (its last
//! argument), it writes the CSV `frame,centroid_x,centroid_y` on stdout, one row per frame: the
//! centroid (pixels) of the pixels on the body's side of the frame's mid-grey (half way between
//! its darkest and brightest pixel), empty cells for a frame of one grey. The same as
//! `examples/features/centroid.py`, which needs only Python's standard library.
//!
//! ```toml
//! [[features.external]]
//! command = ["target/release/examples/external_feature"]
//! values = ["centroid_x", "centroid_y"]
//! missing = "allowed"
//! ```

use std::io::Write;
use std::process::ExitCode;

use evitrack::dataset::{Dataset, Polarity};

fn main() -> ExitCode {
    let Some(folder) = std::env::args_os().nth(1) else {
        eprintln!("usage: external_feature DATASET_FOLDER");
        return ExitCode::from(2);
    };
    let dataset = match Dataset::read(&folder) {
        Ok(dataset) => dataset,
        Err(e) => {
            eprintln!("external_feature: {e}");
            return ExitCode::from(2);
        }
    };
    let bright = dataset.manifest.camera.polarity == Polarity::BrightOnDark;
    let mut out = String::from("frame,centroid_x,centroid_y\n");
    for (k, frame) in dataset.frames.iter().enumerate() {
        let (lo, hi) = frame
            .image
            .pixels()
            .fold((u8::MAX, u8::MIN), |(lo, hi), p| {
                (lo.min(p[0]), hi.max(p[0]))
            });
        let mid = (f64::from(lo) + f64::from(hi)) / 2.0;
        let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for (x, y, p) in frame.image.enumerate_pixels() {
            let v = f64::from(p[0]);
            if hi > lo && ((bright && v > mid) || (!bright && v < mid)) {
                n += 1.0;
                sx += f64::from(x);
                sy += f64::from(y);
            }
        }
        match n > 0.0 {
            true => out.push_str(&format!("{k},{},{}\n", sx / n, sy / n)),
            false => out.push_str(&format!("{k},,\n")),
        }
    }
    match std::io::stdout().lock().write_all(out.as_bytes()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("external_feature: writing stdout: {e}");
            ExitCode::FAILURE
        }
    }
}
