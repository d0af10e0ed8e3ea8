//! Painting image faults onto a rendered frame.

use image::GrayImage;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::Effect;

/// Paints an image fault onto `image`; `offset` is the number of frames since the fault's window
/// opened (a moving occluder has moved `offset` times its velocity). Feature faults and dropped
/// frames are not painted.
pub(super) fn paint(image: &mut GrayImage, effect: &Effect, offset: f64, rng: &mut ChaCha8Rng) {
    let (w, h) = image.dimensions();
    match *effect {
        Effect::Occluder {
            rect,
            intensity,
            velocity,
        } => {
            let x0 = rect[0] + velocity[0] * offset;
            let y0 = rect[1] + velocity[1] * offset;
            // Pixels whose centre lies inside the rectangle.
            let cols = pixel_span(x0, x0 + rect[2], w);
            let rows = pixel_span(y0, y0 + rect[3], h);
            for y in rows {
                for x in cols.clone() {
                    image.put_pixel(x, y, image::Luma([intensity]));
                }
            }
        }
        Effect::Glare {
            centre,
            radius,
            peak,
        } => {
            let inv = 1.0 / (2.0 * radius * radius);
            for (x, y, p) in image.enumerate_pixels_mut() {
                let dx = x as f64 + 0.5 - centre[0];
                let dy = y as f64 + 0.5 - centre[1];
                let add = peak * (-(dx * dx + dy * dy) * inv).exp();
                p.0[0] = (f64::from(p.0[0]) + add).round().min(255.0) as u8;
            }
        }
        Effect::SaltPepper { density } => {
            for p in image.pixels_mut() {
                // Two draws per pixel whatever the outcome, so the pattern is stable.
                let hit = rng.random::<f64>() < density;
                let white = rng.random::<bool>();
                if hit {
                    p.0[0] = if white { 255 } else { 0 };
                }
            }
        }
        Effect::Black => image.pixels_mut().for_each(|p| p.0[0] = 0),
        Effect::Dropped | Effect::Features { .. } => {}
    }
}

/// Indices of the pixels (of `n`) whose centre lies in [from, to).
fn pixel_span(from: f64, to: f64, n: u32) -> std::ops::Range<u32> {
    let first = (from - 0.5).ceil().max(0.0);
    let end = (to - 0.5).ceil().clamp(0.0, f64::from(n));
    if first >= end {
        return 0..0;
    }
    first as u32..end as u32
}
