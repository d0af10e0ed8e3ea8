//! The silhouette of the moving body: threshold, clean-up, largest connected component, its outer
//! contour as an ordered closed polyline, and its centroid.
//!
//! Coordinates are pixel centres: `x` = column, `y` = row (downwards).
//!
//! **Border.** The links leave the field of view, so the silhouette is cut by the image edge. The
//! mask is padded with one pixel of background before contour tracing, so the contour runs along
//! the outermost foreground pixels of the frame where the silhouette is cut: the image border acts
//! as part of the silhouette's outline and the polyline stays closed. The centroid is the centroid
//! of the visible pixels only.

use image::{GrayImage, Luma};
use imageproc::contours::{find_contours, BorderType};
use imageproc::distance_transform::Norm;
use serde::{Deserialize, Serialize};

/// Which side of the grey scale is the body.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    /// Bright body on a dark background (the simulator's frames): foreground is `pixel > level`.
    #[default]
    BrightOnDark,
    /// Dark body on a bright background: foreground is `pixel ≤ level`.
    DarkOnBright,
}

/// How the grey level that splits body from background is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Threshold {
    /// Otsu's level per image; among equally good levels the middle one is taken, so a clean gap
    /// between background and body is split in its middle.
    #[default]
    Otsu,
    /// A fixed level: pixels `≤ level` are dark, `> level` bright.
    Fixed(u8),
}

/// Settings of the silhouette extraction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SilhouetteConfig {
    /// Otsu (default) or a fixed level.
    pub threshold: Threshold,
    /// Minimum difference of the mean grey levels of the two classes; below it the image is taken
    /// as holding no body and the silhouette is missing (guards Otsu against splitting pure noise).
    /// Default 20 grey levels.
    pub min_contrast: f64,
    /// Components smaller than this many pixels are not a silhouette (default 16).
    pub min_area: usize,
    /// Radius (L∞, pixels) of a morphological opening applied before labelling; 0 (default) skips
    /// it — keeping only the largest component already removes isolated specks.
    pub opening: u8,
}

impl Default for SilhouetteConfig {
    fn default() -> Self {
        Self {
            threshold: Threshold::Otsu,
            min_contrast: 20.0,
            min_area: 16,
            opening: 0,
        }
    }
}

/// The extracted silhouette: the largest connected foreground component.
#[derive(Debug, Clone, PartialEq)]
pub struct Silhouette {
    /// Number of pixels of the component.
    pub area: usize,
    /// Centroid of the component's pixels, `[x, y]`.
    pub centroid: [f64; 2],
    /// Outer contour: ordered boundary pixel centres `[x, y]`, closed (the last point joins the
    /// first). Along a cut by the image edge it follows the edge pixels.
    pub contour: Vec<[f64; 2]>,
    /// Whether the component reaches the image edge.
    pub touches_border: bool,
    /// The grey level used to split the image.
    pub level: u8,
}

/// Grey-level histogram. Four interleaved sub-histograms avoid the store-to-load stall of
/// incrementing the same bin over and over on a near-uniform background.
pub(crate) fn histogram(raw: &[u8]) -> [u64; 256] {
    let mut sub = [[0u32; 256]; 4];
    let mut chunks = raw.chunks_exact(4);
    for c in &mut chunks {
        sub[0][c[0] as usize] += 1;
        sub[1][c[1] as usize] += 1;
        sub[2][c[2] as usize] += 1;
        sub[3][c[3] as usize] += 1;
    }
    for &p in chunks.remainder() {
        sub[0][p as usize] += 1;
    }
    let mut hist = [0u64; 256];
    for (v, h) in hist.iter_mut().enumerate() {
        *h = sub.iter().map(|s| u64::from(s[v])).sum();
    }
    hist
}

/// Otsu's level from a histogram: maximises the between-class variance over splits
/// `≤ t | > t`; ties (a flat maximum across a gap) resolve to the middle of the tied range.
/// Returns `(level, dark mean, bright mean)`, or `None` when one class is always empty.
fn otsu(hist: &[u64; 256]) -> Option<(u8, f64, f64)> {
    let total: u64 = hist.iter().sum();
    let total_sum: f64 = hist
        .iter()
        .enumerate()
        .map(|(v, &c)| v as f64 * c as f64)
        .sum();
    let mut w0 = 0u64;
    let mut s0 = 0.0;
    let mut best = f64::NEG_INFINITY;
    let (mut lo, mut hi) = (0usize, 0usize);
    for (t, &c) in hist.iter().enumerate() {
        w0 += c;
        s0 += t as f64 * c as f64;
        if w0 == 0 {
            continue;
        }
        let w1 = total - w0;
        if w1 == 0 {
            break;
        }
        let m0 = s0 / w0 as f64;
        let m1 = (total_sum - s0) / w1 as f64;
        let var = w0 as f64 * w1 as f64 * (m0 - m1) * (m0 - m1);
        if var > best * (1.0 + 1e-12) {
            best = var;
            lo = t;
            hi = t;
        } else if var >= best * (1.0 - 1e-12) && hi + 1 == t {
            hi = t;
        }
    }
    if !best.is_finite() {
        return None;
    }
    let t = (lo + hi) / 2;
    class_means(hist, t as u8).map(|(m0, m1)| (t as u8, m0, m1))
}

/// Mean grey levels of the classes `≤ t` and `> t`; `None` if one is empty.
fn class_means(hist: &[u64; 256], t: u8) -> Option<(f64, f64)> {
    let (mut w0, mut s0, mut w1, mut s1) = (0u64, 0.0, 0u64, 0.0);
    for (v, &c) in hist.iter().enumerate() {
        if v <= t as usize {
            w0 += c;
            s0 += v as f64 * c as f64;
        } else {
            w1 += c;
            s1 += v as f64 * c as f64;
        }
    }
    (w0 > 0 && w1 > 0).then(|| (s0 / w0 as f64, s1 / w1 as f64))
}

/// Per-component statistics gathered while labelling.
#[derive(Debug, Clone, Copy)]
struct Component {
    area: usize,
    sum_x: u64,
    sum_y: u64,
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

/// Extract the silhouette of `image` (body brightness `polarity`): threshold, optional opening, largest 8-connected component
/// (ties: first in raster order), its outer contour and centroid.
///
/// Returns `None` (a missing silhouette) when the image is empty, has too little contrast
/// (`min_contrast`), has no foreground, is foreground everywhere, or when the largest component
/// is smaller than `min_area`. A NaN `min_contrast` disables the contrast guard.
pub fn extract_silhouette(
    image: &GrayImage,
    polarity: Polarity,
    config: &SilhouetteConfig,
) -> Option<Silhouette> {
    let (w, h) = image.dimensions();
    let (wu, hu) = (w as usize, h as usize);
    let Largest {
        labels,
        width: pw,
        label: best_label,
        component: best,
        level,
        ..
    } = largest_silhouette_component(image, polarity, config)?;
    // Crop to the component's bounding box plus one pixel of background on every side (in padded
    // coordinates the box is x0..=x1, so the crop spans x0 − 1..=x1 + 1, always inside the pad).
    let cw = best.x1 - best.x0 + 3;
    let ch = best.y1 - best.y0 + 3;
    let mut crop = vec![0u8; cw * ch];
    for cy in 1..ch - 1 {
        let src = &labels[(best.y0 + cy - 1) * pw + best.x0..][..cw - 2];
        for (d, &l) in crop[cy * cw + 1..][..cw - 2].iter_mut().zip(src) {
            *d = if l == best_label { 255 } else { 0 };
        }
    }
    let crop = GrayImage::from_raw(cw as u32, ch as u32, crop)?;
    let contours = find_contours::<i32>(&crop);
    let outer = contours
        .into_iter()
        .find(|c| c.border_type == BorderType::Outer && c.parent.is_none())?;
    // Crop (cx, cy) is padded (x0 − 1 + cx, …), i.e. image (x0 − 2 + cx, …).
    let (ox, oy) = (best.x0 as f64 - 2.0, best.y0 as f64 - 2.0);
    let contour: Vec<[f64; 2]> = outer
        .points
        .iter()
        .map(|p| [f64::from(p.x) + ox, f64::from(p.y) + oy])
        .collect();
    if contour.is_empty() {
        return None;
    }
    let touches_border = best.x0 == 1 || best.y0 == 1 || best.x1 == wu || best.y1 == hu;
    let area = best.area as f64;
    Some(Silhouette {
        area: best.area,
        // Sums are in padded coordinates: shift back by one pixel.
        centroid: [
            best.sum_x as f64 / area - 1.0,
            best.sum_y as f64 / area - 1.0,
        ],
        contour,
        touches_border,
        level,
    })
}

/// The largest component of a thresholded image, labelled in a padded buffer.
struct Largest {
    /// Component labels of the padded mask (one pixel of background all round).
    labels: Vec<u32>,
    /// The padded row length.
    width: usize,
    /// The largest component's label.
    label: u32,
    /// Its statistics (padded coordinates).
    component: Component,
    /// The grey level that split the image.
    level: u8,
    /// Foreground pixels of the mask, in every component.
    foreground: usize,
}

/// Threshold, optional opening and labelling of [`extract_silhouette`], up to its largest
/// component (`None` where it finds no silhouette before tracing a contour).
fn largest_silhouette_component(
    image: &GrayImage,
    polarity: Polarity,
    config: &SilhouetteConfig,
) -> Option<Largest> {
    let (w, h) = image.dimensions();
    if w == 0 || h == 0 {
        return None;
    }
    let raw = image.as_raw();
    let hist = histogram(raw);
    let (level, m0, m1) = match config.threshold {
        Threshold::Otsu => otsu(&hist)?,
        Threshold::Fixed(t) => {
            let (m0, m1) = class_means(&hist, t)?;
            (t, m0, m1)
        }
    };
    if m1 - m0 < config.min_contrast {
        return None;
    }
    let bright = polarity == Polarity::BrightOnDark;
    let (wu, hu) = (w as usize, h as usize);
    // The mask is padded with one pixel of background all round: labelling needs no bounds
    // checks and contour tracing sees the image edge as background.
    let pw = wu + 2;
    let mut mask = vec![0u8; pw * (hu + 2)];
    for (y, row) in raw.chunks_exact(wu).enumerate() {
        let dst = &mut mask[(y + 1) * pw + 1..][..wu];
        for (d, &p) in dst.iter_mut().zip(row) {
            *d = u8::from((p > level) == bright);
        }
    }
    if config.opening > 0 {
        let mut img = GrayImage::from_fn(w, h, |x, y| {
            Luma([mask[(y as usize + 1) * pw + x as usize + 1] * 255])
        });
        imageproc::morphology::open_mut(&mut img, Norm::LInf, config.opening);
        for (y, row) in img.as_raw().chunks_exact(wu).enumerate() {
            let dst = &mut mask[(y + 1) * pw + 1..][..wu];
            for (d, &p) in dst.iter_mut().zip(row) {
                *d = u8::from(p > 0);
            }
        }
    }
    let fg: usize = mask.iter().map(|&m| usize::from(m)).sum();
    if fg == 0 || fg == wu * hu {
        return None;
    }
    let (labels, label, component) = largest_component(&mut mask, pw)?;
    if component.area < config.min_area.max(1) {
        return None;
    }
    Some(Largest {
        labels,
        width: pw,
        label,
        component,
        level,
        foreground: fg,
    })
}

/// The pixels of the silhouette [`extract_silhouette`] finds in `image` (the same threshold,
/// opening and largest component), row-major; `None` where it finds none.
pub fn silhouette_pixels(
    image: &GrayImage,
    polarity: Polarity,
    config: &SilhouetteConfig,
) -> Option<Vec<bool>> {
    silhouette_and_stray(image, polarity, config).map(|(pixels, _)| pixels)
}

/// [`silhouette_pixels`] with the stray pixels: those on the body's side of the threshold (after
/// the opening) outside the silhouette, which no pose of the robot explains.
pub fn silhouette_and_stray(
    image: &GrayImage,
    polarity: Polarity,
    config: &SilhouetteConfig,
) -> Option<(Vec<bool>, usize)> {
    let w = image.width() as usize;
    let found = largest_silhouette_component(image, polarity, config)?;
    let stray = found.foreground - found.component.area;
    let pixels = (found.labels.chunks_exact(found.width))
        .skip(1)
        .take(image.height() as usize)
        .flat_map(|row| row[1..=w].iter().map(|&l| l == found.label))
        .collect();
    Some((pixels, stray))
}

/// Label 8-connected components of a padded `mask` (row length `pw`, zero border, consumed) by
/// flood fill; return the labels, the label of the largest component and its statistics (padded coordinates).
fn largest_component(mask: &mut [u8], pw: usize) -> Option<(Vec<u32>, u32, Component)> {
    // A pixel is unvisited foreground iff its mask byte is 1; labelling clears it, so the scan
    // for the next seed can skip zero words eight bytes at a time.
    let mut labels = vec![0u32; mask.len()];
    let mut stack: Vec<(usize, usize, usize)> = Vec::new();
    let mut next = 0u32;
    let mut best: Option<(u32, Component)> = None;
    let offsets = [pw - 1, pw, pw + 1, 1];
    let steps = [(-1isize, 1isize), (0, 1), (1, 1), (1, 0)];
    let mut pos = 0usize;
    while pos < mask.len() {
        if pos.is_multiple_of(8) && pos + 8 <= mask.len() {
            let word = u64::from_ne_bytes(mask[pos..pos + 8].try_into().unwrap_or([1; 8]));
            if word == 0 {
                pos += 8;
                continue;
            }
        }
        if mask[pos] == 0 {
            pos += 1;
            continue;
        }
        let start = pos;
        next += 1;
        labels[start] = next;
        mask[start] = 0;
        stack.push((start, start % pw, start / pw));
        let mut c = Component {
            area: 0,
            sum_x: 0,
            sum_y: 0,
            x0: usize::MAX,
            y0: usize::MAX,
            x1: 0,
            y1: 0,
        };
        while let Some((i, x, y)) = stack.pop() {
            c.area += 1;
            c.sum_x += x as u64;
            c.sum_y += y as u64;
            c.x0 = c.x0.min(x);
            c.x1 = c.x1.max(x);
            c.y0 = c.y0.min(y);
            c.y1 = c.y1.max(y);
            // The zero border means i ± offset never leaves the buffer for a foreground i.
            for (&off, &(dx, dy)) in offsets.iter().zip(&steps) {
                for (j, nx, ny) in [
                    (
                        i + off,
                        x.wrapping_add_signed(dx),
                        y.wrapping_add_signed(dy),
                    ),
                    (
                        i - off,
                        x.wrapping_add_signed(-dx),
                        y.wrapping_add_signed(-dy),
                    ),
                ] {
                    if mask[j] != 0 {
                        mask[j] = 0;
                        labels[j] = next;
                        stack.push((j, nx, ny));
                    }
                }
            }
        }
        if best.is_none_or(|(_, b)| c.area > b.area) {
            best = Some((next, c));
        }
    }
    best.map(|(l, c)| (labels, l, c))
}

#[cfg(test)]
mod tests {
    use super::*;

    const B: Polarity = Polarity::BrightOnDark;

    fn frame(w: u32, h: u32, on: impl Fn(u32, u32) -> bool) -> GrayImage {
        GrayImage::from_fn(w, h, |x, y| Luma([if on(x, y) { 200 } else { 30 }]))
    }

    #[test]
    fn otsu_level_is_as_good_as_imageprocs() {
        let img = GrayImage::from_fn(40, 30, |x, y| Luma([((x * 7 + y * 13) % 256) as u8]));
        let mut hist = [0u64; 256];
        for &p in img.as_raw() {
            hist[p as usize] += 1;
        }
        let between = |t: u8| {
            let (m0, m1) = class_means(&hist, t).unwrap();
            let w0: u64 = hist[..=t as usize].iter().sum();
            let w1: u64 = hist[t as usize + 1..].iter().sum();
            w0 as f64 * w1 as f64 * (m1 - m0).powi(2)
        };
        let (ours, _, _) = otsu(&hist).unwrap();
        let theirs = imageproc::contrast::otsu_level(&img);
        assert!(between(ours) >= between(theirs) * (1.0 - 1e-9));
    }

    #[test]
    fn otsu_splits_a_clean_gap_in_the_middle() {
        let img = frame(20, 20, |x, _| x < 5);
        let s = extract_silhouette(&img, B, &SilhouetteConfig::default()).unwrap();
        assert_eq!(s.level, (30 + 199) / 2);
        assert_eq!(s.area, 100);
        assert!(s.touches_border);
    }

    #[test]
    fn largest_component_wins_and_centroid_is_its_own() {
        let img = frame(50, 40, |x, y| {
            (10..20).contains(&x) && (10..30).contains(&y) || (40..44).contains(&x) && y < 4
        });
        let s = extract_silhouette(&img, B, &SilhouetteConfig::default()).unwrap();
        assert_eq!(s.area, 200);
        assert_eq!(s.centroid, [14.5, 19.5]);
        assert!(!s.touches_border);
        // Outer boundary pixels of a 10 × 20 rectangle: 2·(10 + 20) − 4.
        assert_eq!(s.contour.len(), 56);
        for p in &s.contour {
            assert!(p[0] == 10.0 || p[0] == 19.0 || p[1] == 10.0 || p[1] == 29.0);
        }
    }

    #[test]
    fn the_silhouette_pixels_are_the_largest_components() {
        let img = frame(50, 40, |x, y| {
            (10..20).contains(&x) && (10..30).contains(&y) || (40..44).contains(&x) && y < 4
        });
        let cfg = SilhouetteConfig::default();
        let pixels = silhouette_pixels(&img, B, &cfg).unwrap();
        assert_eq!(pixels.len(), 50 * 40);
        let on: Vec<usize> = (0..pixels.len()).filter(|&i| pixels[i]).collect();
        assert_eq!(on.len(), extract_silhouette(&img, B, &cfg).unwrap().area);
        // The small component is left out; the rectangle's corners are in.
        assert!(!pixels[41] && pixels[10 * 50 + 10] && pixels[29 * 50 + 19]);
        assert!(silhouette_pixels(&GrayImage::new(20, 10), B, &cfg).is_none());
    }

    #[test]
    fn stray_pixels_are_the_bodys_side_outside_the_silhouette() {
        // The 4 × 4 square and two lone specks lie outside the 10 × 20 rectangle; a dark hole
        // inside it is not stray (no body pixel), nor is anything in a frame of one body.
        let cfg = SilhouetteConfig::default();
        let speckled = frame(50, 40, |x, y| {
            let body = (10..20).contains(&x) && (10..30).contains(&y) && (x, y) != (15, 15);
            body || (40..44).contains(&x) && y < 4 || [(2, 35), (30, 20)].contains(&(x, y))
        });
        let (pixels, stray) = silhouette_and_stray(&speckled, B, &cfg).unwrap();
        assert_eq!((pixels.iter().filter(|&&p| p).count(), stray), (199, 18));
        let alone = frame(50, 40, |x, y| {
            (10..20).contains(&x) && (10..30).contains(&y)
        });
        assert_eq!(silhouette_and_stray(&alone, B, &cfg).unwrap().1, 0);
        // Dark on bright: the body's side is the dark one.
        let dark = GrayImage::from_fn(30, 20, |x, y| {
            Luma([if x < 10 || (x, y) == (25, 5) { 20 } else { 220 }])
        });
        let dark_cfg = SilhouetteConfig::default();
        let (_, stray) = silhouette_and_stray(&dark, Polarity::DarkOnBright, &dark_cfg).unwrap();
        assert_eq!(stray, 1);
    }

    #[test]
    fn contour_runs_along_the_image_edge_where_cut() {
        // A bar entering from the left edge: the contour includes the edge column x = 0.
        let img = frame(30, 20, |x, y| x < 15 && (5..10).contains(&y));
        let s = extract_silhouette(&img, B, &SilhouetteConfig::default()).unwrap();
        assert!(s.touches_border);
        let on_edge = s.contour.iter().filter(|p| p[0] == 0.0).count();
        assert_eq!(on_edge, 5);
        // Consecutive contour points are 8-neighbours: the polyline is connected and closed.
        let n = s.contour.len();
        for i in 0..n {
            let (p, q) = (s.contour[i], s.contour[(i + 1) % n]);
            assert!((p[0] - q[0]).abs() <= 1.0 && (p[1] - q[1]).abs() <= 1.0);
        }
    }

    #[test]
    fn dark_on_bright_and_fixed_level() {
        let img = GrayImage::from_fn(30, 30, |x, y| {
            Luma([if (8..16).contains(&x) && (8..16).contains(&y) {
                20
            } else {
                220
            }])
        });
        let cfg = SilhouetteConfig {
            threshold: Threshold::Fixed(100),
            ..SilhouetteConfig::default()
        };
        let s = extract_silhouette(&img, Polarity::DarkOnBright, &cfg).unwrap();
        assert_eq!((s.area, s.level), (64, 100));
        assert_eq!(s.centroid, [11.5, 11.5]);
    }

    #[test]
    fn opening_removes_a_thin_spur() {
        let img = frame(40, 40, |x, y| {
            (10..20).contains(&x) && (10..20).contains(&y) || (20..35).contains(&x) && y == 15
        });
        let plain = extract_silhouette(&img, B, &SilhouetteConfig::default()).unwrap();
        assert_eq!(plain.area, 115);
        let opened = SilhouetteConfig {
            opening: 1,
            ..SilhouetteConfig::default()
        };
        let s = extract_silhouette(&img, B, &opened).unwrap();
        assert_eq!(s.area, 100);
    }

    #[test]
    fn missing_silhouettes() {
        let cfg = SilhouetteConfig::default();
        assert!(extract_silhouette(&GrayImage::new(0, 0), B, &cfg).is_none());
        assert!(extract_silhouette(&GrayImage::new(20, 10), B, &cfg).is_none());
        let white = GrayImage::from_pixel(20, 10, Luma([255]));
        assert!(extract_silhouette(&white, B, &cfg).is_none());
        // Low-contrast texture: Otsu would split it, the contrast guard refuses.
        let noise = GrayImage::from_fn(20, 10, |x, y| Luma([30 + ((x * 3 + y * 5) % 7) as u8]));
        assert!(extract_silhouette(&noise, B, &cfg).is_none());
        // A speck below min_area.
        let speck = frame(20, 20, |x, y| x == 3 && y == 3);
        assert!(extract_silhouette(&speck, B, &cfg).is_none());
        // Everything foreground under a fixed level.
        let fixed = SilhouetteConfig {
            threshold: Threshold::Fixed(10),
            ..cfg
        };
        assert!(extract_silhouette(&frame(20, 20, |x, _| x < 3), B, &fixed).is_none());
    }
}
