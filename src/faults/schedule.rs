//! Which frames a fault strikes.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// The frames (of `n_frames`) a fault strikes: inside `window` (first and last frame, inclusive;
/// `None` = all), in bursts of `burst` frames, so that about `share` of the window is struck.
///
/// Each frame not inside a burst starts one with probability q = s / (b(1 − s) + s) (s the share,
/// b the burst length): a frame then starts b struck frames with probability q, or stays clean,
/// so the struck share is q·b / (q·b + 1 − q) = s. One draw per clean frame, in frame order.
pub fn active_frames(
    n_frames: usize,
    share: f64,
    window: Option<[usize; 2]>,
    burst: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<bool> {
    let mut active = vec![false; n_frames];
    let [first, last] = window.unwrap_or([0, usize::MAX]);
    let last = last.min(n_frames.saturating_sub(1));
    if n_frames == 0 || first > last || share <= 0.0 {
        return active;
    }
    let b = burst.max(1) as f64;
    let start = share / (b * (1.0 - share) + share);
    let mut i = first;
    while i <= last {
        if rng.random::<f64>() < start {
            let end = (i + burst.max(1) - 1).min(last);
            active[i..=end].iter_mut().for_each(|a| *a = true);
            i = end + 1;
        } else {
            i += 1;
        }
    }
    active
}
