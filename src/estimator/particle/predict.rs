//! The prediction step of one motion (`motion`): each particle's random draw, taken in the
//! serial filter's order on one thread and published block by block, and the move it makes.

use std::sync::atomic::{AtomicUsize, Ordering};

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::likelihood::BLOCK;
use super::motion::WAITED_AT_MOST;
use super::pool::Disjoint;
use super::recover::Guess;

/// One particle's random draw for the prediction: its Gaussian step (in σ) along the line,
/// the uniform numbers of its point in the disc of the reach, or its standard normals about
/// the frame's own estimate (`recover`).
#[derive(Clone, Copy)]
pub(super) enum Draw {
    Line([f64; 2]),
    Disc([f64; 2]),
    Guess([f64; 2]),
}

/// The frame's prediction: the Gaussian step's spread (mm), the disc's radius (mm), the line's
/// shift, the box the particles stay in, and the frame's own estimate when recovering.
pub(super) struct Prediction {
    pub(super) step: f64,
    pub(super) reach: f64,
    pub(super) shift: [f64; 2],
    pub(super) bounds: ([f64; 2], [f64; 2]),
    pub(super) guess: Option<Guess>,
}

impl Prediction {
    /// Moves `p` by its draw: along the line with the Gaussian step, or to a uniform point of
    /// the disc (radius ∝ √u), then into the box.
    pub(super) fn apply(&self, p: [f64; 2], draw: Draw) -> [f64; 2] {
        let (lo, hi) = self.bounds;
        let moved = match draw {
            Draw::Line([dx, dy]) => [
                p[0] + self.shift[0] + self.step * dx,
                p[1] + self.shift[1] + self.step * dy,
            ],
            Draw::Disc([u, v]) => {
                let r = self.reach * u.sqrt();
                let angle = std::f64::consts::TAU * v;
                [p[0] + r * angle.cos(), p[1] + r * angle.sin()]
            }
            Draw::Guess(d) => self.guess.map_or(p, |g| g.point(d)),
        };
        [moved[0].clamp(lo[0], hi[0]), moved[1].clamp(lo[1], hi[1])]
    }
}

/// Each of the `n` particles' draws into `draws`, in the order of the serial filter: the share
/// `recovery` of the particles is drawn about the frame's own estimate (none drawn for it when
/// 0); of the others, the share `velocity_share` takes the line and a Gaussian step, the
/// others a point of the disc (the line's share is precise, the others keep the filter from
/// losing a pose that leaves the line). Each block's end is stored in `drawn` once its draws
/// are written.
pub(super) fn draw_blocks(
    rng: &mut ChaCha8Rng,
    (velocity_share, recovery): (f64, f64),
    draws: &Disjoint<'_, Draw>,
    n: usize,
    drawn: &AtomicUsize,
) {
    // Everything published also when a draw panics, so no chunk waits for ever (the panic
    // reaches the caller, which does not use the outputs).
    struct Publish<'a>(&'a AtomicUsize);
    impl Drop for Publish<'_> {
        fn drop(&mut self) {
            self.0.store(usize::MAX, Ordering::Release);
        }
    }
    let _publish = Publish(drawn);
    for start in (0..n).step_by(BLOCK) {
        let end = (start + BLOCK).min(n);
        // SAFETY: not yet published, so no other chunk reads these draws.
        for draw in unsafe { draws.range(start..end) } {
            *draw = if recovery > 0.0 && rng.random::<f64>() < recovery {
                let dx: f64 = rng.sample(StandardNormal);
                let dy: f64 = rng.sample(StandardNormal);
                Draw::Guess([dx, dy])
            } else if rng.random::<f64>() < velocity_share {
                let dx: f64 = rng.sample(StandardNormal);
                let dy: f64 = rng.sample(StandardNormal);
                Draw::Line([dx, dy])
            } else {
                let u = rng.random::<f64>();
                Draw::Disc([u, rng.random::<f64>()])
            };
        }
        drawn.store(end, Ordering::Release);
    }
}

/// Waits until the draws up to `end` are published (on one thread they always are).
pub(super) fn wait_for(drawn: &AtomicUsize, end: usize) {
    let start = std::time::Instant::now();
    while drawn.load(Ordering::Acquire) < end {
        match start.elapsed() < WAITED_AT_MOST {
            true => std::hint::spin_loop(),
            false => std::thread::yield_now(),
        }
    }
}
