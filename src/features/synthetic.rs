//! Synthetic frames for testing and benchmarking features without the simulator: discs, bars and
//! rectangles rendered with edge supersampling, seeded Gaussian noise, and a rig-like frame of the
//! five-bar's end-effector disc with its two distal links reaching the image border.
//!
//! Coordinates are pixels with pixel centres at integers (`x` = column, `y` = row).

use image::{GrayImage, Luma};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::FeatureError;

/// A filled shape in pixel coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// A disc.
    Disc {
        /// Centre `[x, y]`.
        centre: [f64; 2],
        /// Radius in pixels.
        radius: f64,
    },
    /// A thick segment with round caps: points within `half_width` of the segment.
    Bar {
        /// One end `[x, y]`.
        from: [f64; 2],
        /// The other end `[x, y]`.
        to: [f64; 2],
        /// Half the thickness in pixels.
        half_width: f64,
    },
    /// An axis-aligned rectangle `min ≤ p ≤ max`. With edges on half-integers it covers whole
    /// pixels exactly: `min = [9.5, 4.5], max = [19.5, 6.5]` is columns 10..=19, rows 5..=6.
    Rect {
        /// Corner `[x, y]` with the smaller coordinates.
        min: [f64; 2],
        /// Corner `[x, y]` with the larger coordinates.
        max: [f64; 2],
    },
}

impl Shape {
    /// Signed distance from `p` (negative inside; exact for discs and bars, exact outside and a
    /// lower bound inside for rectangles).
    fn distance(&self, p: [f64; 2]) -> f64 {
        match *self {
            Shape::Disc { centre, radius } => (p[0] - centre[0]).hypot(p[1] - centre[1]) - radius,
            Shape::Bar {
                from,
                to,
                half_width,
            } => {
                let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
                let len2 = dx * dx + dy * dy;
                let t = if len2 > 0.0 {
                    (((p[0] - from[0]) * dx + (p[1] - from[1]) * dy) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                (p[0] - from[0] - t * dx).hypot(p[1] - from[1] - t * dy) - half_width
            }
            Shape::Rect { min, max } => {
                let qx = (min[0] - p[0]).max(p[0] - max[0]);
                let qy = (min[1] - p[1]).max(p[1] - max[1]);
                qx.max(0.0).hypot(qy.max(0.0)) + qx.max(qy).min(0.0)
            }
        }
    }
}

/// Render the union of `shapes` as `foreground` on `background`. Pixels whose centre is within
/// one pixel of an edge are supersampled on an `supersample × supersample` grid and get the
/// covered fraction's blend; `supersample ≤ 1` tests the pixel centre only (a boundary point
/// counts as inside).
pub fn render(
    width: u32,
    height: u32,
    shapes: &[Shape],
    background: u8,
    foreground: u8,
    supersample: u32,
) -> GrayImage {
    let dist = |p: [f64; 2]| {
        shapes
            .iter()
            .map(|s| s.distance(p))
            .fold(f64::INFINITY, f64::min)
    };
    let ss = supersample.max(1);
    let (bg, fg) = (f64::from(background), f64::from(foreground));
    GrayImage::from_fn(width, height, |x, y| {
        let c = [f64::from(x), f64::from(y)];
        let d = dist(c);
        let cover = if ss == 1 {
            f64::from(u8::from(d <= 0.0))
        } else if d < -0.75 {
            1.0
        } else if d > 0.75 {
            0.0
        } else {
            let mut inside = 0u32;
            for j in 0..ss {
                for i in 0..ss {
                    let p = [
                        c[0] - 0.5 + (f64::from(i) + 0.5) / f64::from(ss),
                        c[1] - 0.5 + (f64::from(j) + 0.5) / f64::from(ss),
                    ];
                    inside += u32::from(dist(p) <= 0.0);
                }
            }
            f64::from(inside) / f64::from(ss * ss)
        };
        Luma([(bg + cover * (fg - bg)).round().clamp(0.0, 255.0) as u8])
    })
}

/// Add seeded Gaussian noise of standard deviation `sigma` grey levels (rounded, clamped to
/// 0..=255). Same seed, same image → same result. `sigma` must be finite and ≥ 0.
pub fn add_noise(image: &mut GrayImage, sigma: f64, seed: u64) -> Result<(), FeatureError> {
    if !(sigma.is_finite() && sigma >= 0.0) {
        return Err(FeatureError::BadNoise { sigma });
    }
    let normal = Normal::new(0.0, sigma).map_err(|_| FeatureError::BadNoise { sigma })?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for p in image.pixels_mut() {
        let v = f64::from(p.0[0]) + normal.sample(&mut rng);
        p.0[0] = v.round().clamp(0.0, 255.0) as u8;
    }
    Ok(())
}

/// Width of the rig camera's frames, pixels.
pub const RIG_WIDTH: u32 = 170;
/// Height of the rig camera's frames, pixels.
pub const RIG_HEIGHT: u32 = 120;
/// Millimetres per pixel of the rig camera.
pub const RIG_MM_PER_PX: f64 = 0.2;

/// A rig-like 170 × 120 frame for end-effector position `pose_mm = [x, y]` (mm): a five-bar with
/// base pivots at (±10, 0), proximal links 30 mm, distal links 50 mm, elbows out; the camera,
/// 0.2 mm/px, is centred on (0, 47.5) mm with +y up the image. Drawn: the end-effector disc
/// (radius 2.5 mm) and the two distal links (2 mm thick) — bright (200) on dark (40) with 4 × 4
/// edge supersampling, then Gaussian noise of `noise_sigma` grey levels from `seed`.
///
/// This is a stand-in for the simulator's camera, not a copy of it. An unreachable position or a
/// bad `noise_sigma` is an error.
pub fn rig_like_frame(
    pose_mm: [f64; 2],
    noise_sigma: f64,
    seed: u64,
) -> Result<GrayImage, FeatureError> {
    let (l1, l2) = (30.0, 50.0);
    let to_px = |p: [f64; 2]| {
        [
            (p[0] + 17.0) / RIG_MM_PER_PX - 0.5,
            (59.5 - p[1]) / RIG_MM_PER_PX - 0.5,
        ]
    };
    let mut shapes = vec![Shape::Disc {
        centre: to_px(pose_mm),
        radius: 2.5 / RIG_MM_PER_PX,
    }];
    for side in [-1.0f64, 1.0] {
        let base = [10.0 * side, 0.0];
        let (dx, dy) = (pose_mm[0] - base[0], pose_mm[1] - base[1]);
        let d = dx.hypot(dy);
        let a = (l1 * l1 - l2 * l2 + d * d) / (2.0 * d);
        let h2 = l1 * l1 - a * a;
        if !(d.is_finite() && d > 0.0 && h2 >= 0.0) {
            return Err(FeatureError::Unreachable { pose_mm });
        }
        let h = h2.sqrt();
        let m = [base[0] + a * dx / d, base[1] + a * dy / d];
        let cands = [
            [m[0] - h * dy / d, m[1] + h * dx / d],
            [m[0] + h * dy / d, m[1] - h * dx / d],
        ];
        // Elbows out: the left elbow is the one further left, the right one further right.
        let elbow = if (cands[0][0] - cands[1][0]) * side > 0.0 {
            cands[0]
        } else {
            cands[1]
        };
        shapes.push(Shape::Bar {
            from: to_px(elbow),
            to: to_px(pose_mm),
            half_width: 1.0 / RIG_MM_PER_PX,
        });
    }
    let mut img = render(RIG_WIDTH, RIG_HEIGHT, &shapes, 40, 200, 4);
    add_noise(&mut img, noise_sigma, seed)?;
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rect_covers_whole_pixels() {
        let img = render(
            30,
            20,
            &[Shape::Rect {
                min: [9.5, 4.5],
                max: [19.5, 6.5],
            }],
            0,
            255,
            4,
        );
        let on: Vec<(u32, u32)> = img
            .enumerate_pixels()
            .filter(|p| p.2 .0[0] > 0)
            .map(|p| (p.0, p.1))
            .collect();
        assert_eq!(on.len(), 20);
        assert!(on
            .iter()
            .all(|&(x, y)| (10..=19).contains(&x) && (5..=6).contains(&y)));
        assert!(img.pixels().all(|p| p.0[0] == 0 || p.0[0] == 255));
    }

    #[test]
    fn disc_edges_are_blended() {
        let img = render(
            40,
            40,
            &[Shape::Disc {
                centre: [20.3, 19.6],
                radius: 8.2,
            }],
            0,
            200,
            4,
        );
        assert!(img.pixels().any(|p| p.0[0] > 0 && p.0[0] < 200));
        assert_eq!(img.get_pixel(20, 20).0[0], 200);
        assert_eq!(img.get_pixel(2, 2).0[0], 0);
    }

    #[test]
    fn noise_is_seeded() {
        let a = rig_like_frame([1.0, 45.0], 2.0, 7).unwrap();
        let b = rig_like_frame([1.0, 45.0], 2.0, 7).unwrap();
        let c = rig_like_frame([1.0, 45.0], 2.0, 8).unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        let mut img = GrayImage::new(3, 3);
        assert!(add_noise(&mut img, -1.0, 0).is_err());
        assert!(add_noise(&mut img, f64::NAN, 0).is_err());
    }

    #[test]
    fn rig_frame_shows_disc_and_links_to_the_border() {
        let img = rig_like_frame([0.0, 47.5], 0.0, 0).unwrap();
        assert_eq!(img.dimensions(), (RIG_WIDTH, RIG_HEIGHT));
        // Disc at the centre of the frame.
        assert_eq!(img.get_pixel(85, 60).0[0], 200);
        // The links reach the bottom row.
        let bottom = (0..RIG_WIDTH)
            .filter(|&x| img.get_pixel(x, RIG_HEIGHT - 1).0[0] > 120)
            .count();
        assert!(bottom >= 10, "{bottom} bright pixels on the bottom row");
        assert!(rig_like_frame([0.0, 200.0], 0.0, 0).is_err());
    }
}
