//! Stored reference outputs: the evidential tracker's per-frame estimates of the paper table, a
//! rendered frame and its feature vector. Runs are deterministic per seed, so any change to these
//! numbers is a change of behaviour: it must be deliberate. To accept one, regenerate with
//! `EVITRACK_UPDATE_REFERENCE=1 cargo test --release -- reference paper_table` and commit the
//! files with the change that explains them.

use std::path::PathBuf;

use evitrack::features::FeatureConfig;
use evitrack::report::FrameRecord;
use evitrack::sim::{render_pose, SimSettings};

/// Relative tolerance of stored numbers (the text keeps every digit; the tolerance only allows
/// for another machine's last-bit rounding of exp and ln).
const TOLERANCE: f64 = 1e-9;

fn path(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/reference")).join(name)
}

fn updating() -> bool {
    std::env::var_os("EVITRACK_UPDATE_REFERENCE").is_some_and(|v| v == "1")
}

/// Compares `text` (lines of comma-separated cells) with the stored file, numbers to
/// [`TOLERANCE`], anything else exactly; writes it instead when updating.
pub fn check_text(name: &str, text: &str) {
    let file = path(name);
    if updating() {
        std::fs::write(&file, text).unwrap();
        eprintln!("wrote {}", file.display());
        return;
    }
    let stored = std::fs::read_to_string(&file).unwrap_or_else(|e| {
        panic!(
            "{}: {e}; generate it with EVITRACK_UPDATE_REFERENCE=1",
            file.display()
        )
    });
    let (got, want): (Vec<&str>, Vec<&str>) = (text.lines().collect(), stored.lines().collect());
    assert_eq!(got.len(), want.len(), "{name}: line count");
    for (k, (g, w)) in got.iter().zip(&want).enumerate() {
        let (gc, wc): (Vec<&str>, Vec<&str>) = (g.split(',').collect(), w.split(',').collect());
        assert_eq!(gc.len(), wc.len(), "{name} line {}: {g} vs {w}", k + 1);
        for (a, b) in gc.iter().zip(&wc) {
            let same = match (a.parse::<f64>(), b.parse::<f64>()) {
                (Ok(x), Ok(y)) => (x - y).abs() <= TOLERANCE * x.abs().max(y.abs()).max(1e-300),
                _ => a == b,
            };
            assert!(
                same,
                "{name} line {}: `{a}` against stored `{b}`\n{g}\n{w}",
                k + 1
            );
        }
    }
}

/// The evidential rows of seed-1 paper runs: variant, frame, estimate, group, level.
pub fn estimates_text(records: &[(String, FrameRecord)]) -> String {
    let mut text = String::from("variant,frame,est_x,est_y,group,conflict_level\n");
    for (variant, r) in records {
        let [x, y] = r.estimate.map_or([f64::NAN; 2], |e| e);
        let group: Vec<String> = r.group.iter().flatten().map(usize::to_string).collect();
        let level = r.conflict_level.map_or(String::new(), |k| k.to_string());
        text += &format!(
            "{variant},{},{x},{y},{},{level}\n",
            r.frame,
            group.join("+")
        );
    }
    text
}

#[test]
fn a_rendered_frame_and_its_features_match_the_stored_ones() {
    let image = render_pose(&SimSettings::default(), 3.25, 44.5, 7).unwrap();
    let file = path("frame-3.25-44.5-seed7.png");
    if updating() {
        image.save(&file).unwrap();
    } else {
        let stored = image::open(&file)
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()))
            .to_luma8();
        assert_eq!(stored.dimensions(), image.dimensions());
        let differing = stored
            .pixels()
            .zip(image.pixels())
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(differing, 0, "pixels differ from the stored frame");
    }
    let set = FeatureConfig::with_barycentre().check().unwrap();
    let values: Vec<String> = set
        .extract(&image)
        .iter()
        .map(|v| v.map_or(String::new(), |v| v.to_string()))
        .collect();
    let text = format!("{}\n{}\n", set.names().join(","), values.join(","));
    check_text("features-3.25-44.5-seed7.csv", &text);
}
