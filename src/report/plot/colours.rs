//! One colour per method in every plot, and the fixed colours of what is not a method.

use plotters::style::RGBColor;

/// The built-in methods' colours (Okabe–Ito, readable by the colour-blind), in a fixed table.
const TABLE: [(&str, RGBColor); 8] = [
    ("evidential", RGBColor(0, 114, 178)),
    ("evidential_temporal", RGBColor(86, 180, 233)),
    ("continuous", RGBColor(213, 94, 0)),
    ("continuous_temporal", RGBColor(230, 159, 0)),
    ("particle_filter", RGBColor(204, 121, 167)),
    ("knn", RGBColor(0, 158, 115)),
    ("gp", RGBColor(117, 112, 179)),
    ("centre", RGBColor(140, 86, 75)),
];

/// Colours for methods registered from outside, chosen by the name's hash (stable across runs).
const SPARE: [RGBColor; 6] = [
    RGBColor(27, 158, 119),
    RGBColor(217, 95, 2),
    RGBColor(102, 166, 30),
    RGBColor(166, 118, 29),
    RGBColor(231, 41, 138),
    RGBColor(31, 120, 180),
];

/// Across-seed interval whiskers: not a grey (antialiased text is grey) nor a method's colour.
pub const INTERVAL: RGBColor = RGBColor(110, 0, 40);
/// The paper's figures: black marks over the coloured bars.
pub const PAPER: RGBColor = RGBColor(0, 0, 0);
/// Frames a fault struck, shaded behind the errors over time.
pub const FAULT_SHADE: RGBColor = RGBColor(255, 205, 205);
/// Estimates of frames a fault struck, ringed in track plots.
pub const FAULT_MARK: RGBColor = RGBColor(200, 30, 30);
/// Frames some method lost (no estimate), shaded behind the errors over time: bluish, since
/// antialiased text is grey.
pub const LOST_SHADE: RGBColor = RGBColor(218, 218, 240);
/// The workspace's outline in track plots.
pub const WORKSPACE: RGBColor = RGBColor(60, 60, 60);

/// The colour of `method` in every plot.
pub fn method_colour(method: &str) -> RGBColor {
    if let Some((_, colour)) = TABLE.iter().find(|(name, _)| *name == method) {
        return *colour;
    }
    // FNV-1a: a fixed hash, unlike std's randomly keyed one.
    let hash = method.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    SPARE[(hash % SPARE.len() as u64) as usize]
}
