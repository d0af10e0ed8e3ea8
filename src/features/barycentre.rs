//! The intensity barycentre: the intensity-weighted centroid of the image, in pixels
//! (`x` = column, `y` = row, pixel centres at integer coordinates).

use image::GrayImage;
use serde::{Deserialize, Serialize};

use super::silhouette::Polarity;

/// What is subtracted from each pixel's body intensity before weighting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Background {
    /// Weights are the body intensities themselves.
    None,
    /// Subtract the image's median (the background, when the body covers under half the frame).
    Median,
    /// Subtract the median plus four robust noise deviations (`4 · 1.4826 · MAD`), so background
    /// noise gets (almost) no weight and cannot pull the barycentre toward the frame centre.
    #[default]
    MedianPlusNoise,
    /// Subtract a fixed level.
    Level(u8),
}

/// The smallest value whose cumulative count reaches half of `total`.
fn median_of_hist(hist: &[u64; 256], total: u64) -> u8 {
    let half = total.div_ceil(2);
    let mut acc = 0u64;
    for (v, &c) in hist.iter().enumerate() {
        acc += c;
        if acc >= half {
            return v as u8;
        }
    }
    255
}

/// Intensity-weighted centroid `[x, y]` of `image`.
///
/// The body intensity of a pixel is its grey level `v` (bright on dark) or `255 − v` (dark on
/// bright); its weight is `max(body − background, 0)`. Returns `None` when all weights are zero
/// (an empty image, a constant image with background subtraction).
pub fn barycentre(
    image: &GrayImage,
    polarity: Polarity,
    background: Background,
) -> Option<[f64; 2]> {
    let (w, h) = image.dimensions();
    let raw = image.as_raw();
    if raw.is_empty() {
        return None;
    }
    let flip = polarity == Polarity::DarkOnBright;
    let body = |v: u8| if flip { 255 - v } else { v };
    let bg: u8 = match background {
        Background::None => 0,
        Background::Level(l) => l,
        Background::Median | Background::MedianPlusNoise => {
            let grey = super::silhouette::histogram(raw);
            let mut hist = [0u64; 256];
            for (v, &c) in grey.iter().enumerate() {
                hist[body(v as u8) as usize] += c;
            }
            let med = median_of_hist(&hist, raw.len() as u64);
            if background == Background::Median {
                med
            } else {
                let mut dev = [0u64; 256];
                for (v, &c) in hist.iter().enumerate() {
                    dev[v.abs_diff(med as usize)] += c;
                }
                let mad = f64::from(median_of_hist(&dev, raw.len() as u64));
                (f64::from(med) + 4.0 * 1.4826 * mad).round().min(255.0) as u8
            }
        }
    };
    // Integer sums are exact; a per-row u32 accumulation keeps the inner loop narrow
    // (≤ 255 · w · w fits u32 for rows up to 4000 pixels; wider rows fall back to u64 per pixel).
    let mut lut = [0u32; 256];
    for (v, l) in lut.iter_mut().enumerate() {
        *l = u32::from(body(v as u8).saturating_sub(bg));
    }
    let (mut sw, mut sx, mut sy) = (0u64, 0u64, 0u64);
    for (y, row) in raw.chunks_exact(w as usize).enumerate().take(h as usize) {
        let (mut row_w, mut row_x) = (0u64, 0u64);
        if w <= 4000 {
            let (mut rw, mut rx) = (0u32, 0u32);
            for (x, &v) in row.iter().enumerate() {
                let wt = lut[v as usize];
                rw += wt;
                rx += wt * x as u32;
            }
            row_w += u64::from(rw);
            row_x += u64::from(rx);
        } else {
            for (x, &v) in row.iter().enumerate() {
                let wt = u64::from(lut[v as usize]);
                row_w += wt;
                row_x += wt * x as u64;
            }
        }
        sw += row_w;
        sx += row_x;
        sy += row_w * y as u64;
    }
    (sw > 0).then(|| [sx as f64 / sw as f64, sy as f64 / sw as f64])
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Luma;

    #[test]
    fn barycentre_of_a_block_with_and_without_background() {
        let img = GrayImage::from_fn(40, 30, |x, y| {
            Luma([if (10..14).contains(&x) && (20..22).contains(&y) {
                130
            } else {
                30
            }])
        });
        assert_eq!(
            barycentre(&img, Polarity::BrightOnDark, Background::Median),
            Some([11.5, 20.5])
        );
        assert_eq!(
            barycentre(&img, Polarity::BrightOnDark, Background::Level(30)),
            Some([11.5, 20.5])
        );
        // Without subtraction the background pulls the centroid toward the frame centre.
        let [x, y] = barycentre(&img, Polarity::BrightOnDark, Background::None).unwrap();
        assert!(x > 11.5 && x < 19.5 && y < 20.5 && y > 14.5);
    }

    #[test]
    fn noise_margin_removes_the_pull_toward_the_frame_centre() {
        use crate::features::synthetic::add_noise;
        let mut img = GrayImage::from_fn(170, 120, |x, y| {
            Luma([if (10..30).contains(&x) && (10..30).contains(&y) {
                200
            } else {
                40
            }])
        });
        add_noise(&mut img, 2.0, 5).unwrap();
        let err = |b| {
            let [x, y] = barycentre(&img, Polarity::BrightOnDark, b).unwrap();
            (x - 19.5).hypot(y - 19.5)
        };
        let (plain, robust) = (err(Background::Median), err(Background::MedianPlusNoise));
        assert!(robust < 0.05, "robust error {robust}");
        assert!(plain > 5.0 * robust, "median {plain} vs robust {robust}");
    }

    #[test]
    fn dark_polarity_weights_dark_pixels() {
        let img = GrayImage::from_fn(20, 20, |x, y| {
            Luma([if x == 3 && y == 7 { 0 } else { 255 }])
        });
        assert_eq!(
            barycentre(&img, Polarity::DarkOnBright, Background::Median),
            Some([3.0, 7.0])
        );
    }

    #[test]
    fn empty_and_constant_images_are_missing() {
        let bg = Background::Median;
        assert_eq!(
            barycentre(&GrayImage::new(0, 0), Polarity::BrightOnDark, bg),
            None
        );
        assert_eq!(
            barycentre(
                &GrayImage::new(5, 5),
                Polarity::BrightOnDark,
                Background::None
            ),
            None
        );
        let white = GrayImage::from_pixel(5, 5, Luma([255]));
        assert_eq!(barycentre(&white, Polarity::BrightOnDark, bg), None);
        assert_eq!(
            barycentre(&white, Polarity::BrightOnDark, Background::None),
            Some([2.0, 2.0])
        );
    }
}
