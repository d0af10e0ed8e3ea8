//! The constant-velocity motion model (issue 17): a least-squares line through the last
//! measured estimates of a motion, shared by the three temporal methods.

/// The last estimates of a motion and the line through them.
#[derive(Debug, Clone, Default)]
pub struct VelocityLine {
    /// How many estimates the line is fitted through; below 2 there is no line (the motion
    /// model is constant position).
    frames: usize,
    /// (time, pose), oldest first.
    history: Vec<(f64, [f64; 2])>,
}

impl VelocityLine {
    /// A line through the last `frames` estimates.
    pub fn new(frames: usize) -> Self {
        Self {
            frames,
            history: Vec::new(),
        }
    }

    /// Keeps `pose` measured at `time`; `restart` forgets the earlier ones first (the motion
    /// broke off, as when a frame dropped the past).
    pub fn remember(&mut self, time: f64, pose: Option<[f64; 2]>, restart: bool) {
        if restart {
            self.history.clear();
        }
        if let (Some(pose), true) = (pose, self.frames >= 2) {
            self.history.push((time, pose));
        }
        if self.history.len() > self.frames {
            self.history.drain(..self.history.len() - self.frames);
        }
    }

    /// Feeds a temporal tracker's frame at `time`: its estimate joins the line when more than
    /// `past_weight` of the frame's own features are in the chosen group (a frame the past
    /// outweighs, as in an occlusion burst, would bend the line); a frame that did not combine
    /// the past restarts the line.
    pub fn feed(
        &mut self,
        time: f64,
        pose: Option<[f64; 2]>,
        own_features: usize,
        past_weight: f64,
        past_joined: bool,
    ) {
        let measured = pose.filter(|_| own_features as f64 > past_weight);
        self.remember(time, measured, !past_joined);
    }

    /// The line's velocity (mm/s); `None` without two estimates at distinct times.
    pub fn velocity(&self) -> Option<[f64; 2]> {
        line(&self.history).map(|(_, _, slope)| slope)
    }

    /// How far the line moves in `interval` seconds (nothing without a line).
    pub fn shift(&self, interval: f64) -> [f64; 2] {
        self.velocity()
            .map_or([0.0; 2], |v| v.map(|v| v * interval))
    }

    /// The line's pose at `time`; `None` as for [`VelocityLine::velocity`].
    pub fn predict(&self, time: f64) -> Option<[f64; 2]> {
        extrapolate(&self.history, time)
    }
}

/// The pose at `time` on the least-squares line through `history` (time, pose); `None` with
/// fewer than two distinct times.
fn extrapolate(history: &[(f64, [f64; 2])], time: f64) -> Option<[f64; 2]> {
    let (mean_t, mean, slope) = line(history)?;
    Some([0, 1].map(|d| mean[d] + slope[d] * (time - mean_t)))
}

/// Mean time, mean pose and slope of the least-squares line through `history`.
fn line(history: &[(f64, [f64; 2])]) -> Option<(f64, [f64; 2], [f64; 2])> {
    if history.len() < 2 {
        return None;
    }
    let n = history.len() as f64;
    let mean_t = history.iter().map(|h| h.0).sum::<f64>() / n;
    let var_t: f64 = history.iter().map(|h| (h.0 - mean_t).powi(2)).sum();
    if !(var_t.is_finite() && var_t > 0.0) {
        return None;
    }
    let mean = [0, 1].map(|d| history.iter().map(|h| h.1[d]).sum::<f64>() / n);
    let slope = [0, 1].map(|d| {
        history
            .iter()
            .map(|h| (h.0 - mean_t) * (h.1[d] - mean[d]))
            .sum::<f64>()
            / var_t
    });
    Some((mean_t, mean, slope))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extrapolation_follows_the_least_squares_line() {
        let h = [(0.0, [0.0, 1.0]), (1.0, [1.0, 1.0]), (2.0, [2.0, 1.0])];
        assert_eq!(extrapolate(&h, 3.0), Some([3.0, 1.0]));
        // Noise on the middle point: the line through the three, not the last two.
        let h = [(0.0, [0.0, 0.0]), (1.0, [1.3, 0.0]), (2.0, [2.0, 0.0])];
        let p = extrapolate(&h, 3.0).unwrap();
        assert!((p[0] - (1.1 + 1.0 * 2.0)).abs() < 1e-12, "{p:?}");
        assert!((line(&h).unwrap().2[0] - 1.0).abs() < 1e-12);
        assert!(extrapolate(&h[..1], 3.0).is_none());
        assert!(extrapolate(&[(1.0, [0.0, 0.0]), (1.0, [1.0, 0.0])], 2.0).is_none());
    }

    #[test]
    fn the_line_keeps_the_last_frames_and_restarts() {
        let mut line = VelocityLine::new(2);
        line.remember(0.0, Some([0.0, 0.0]), false);
        assert_eq!(line.velocity(), None);
        assert_eq!(line.shift(1.0), [0.0; 2]);
        line.remember(1.0, Some([5.0, 0.0]), false);
        line.remember(2.0, Some([6.0, 1.0]), false);
        // Only the last two: velocity (1, 1).
        assert_eq!(line.velocity(), Some([1.0, 1.0]));
        assert_eq!(line.predict(4.0), Some([8.0, 3.0]));
        assert_eq!(line.shift(0.5), [0.5, 0.5]);
        line.remember(3.0, None, false);
        assert_eq!(line.velocity(), Some([1.0, 1.0]));
        line.remember(3.0, Some([0.0, 0.0]), true);
        assert_eq!(line.velocity(), None);
        // Fewer than two frames: never a line.
        let mut still = VelocityLine::new(1);
        still.remember(0.0, Some([0.0, 0.0]), false);
        still.remember(1.0, Some([1.0, 0.0]), false);
        assert_eq!(still.velocity(), None);
    }

    #[test]
    fn only_frames_whose_own_features_outweigh_the_past_feed_the_line() {
        let mut line = VelocityLine::new(3);
        line.feed(0.0, Some([0.0, 0.0]), 8, 4.0, false);
        line.feed(1.0, Some([1.0, 0.0]), 5, 4.0, true);
        // Four features beside a past worth four: left out, the line stays.
        line.feed(2.0, Some([9.0, 9.0]), 4, 4.0, true);
        assert_eq!(line.predict(2.0), Some([2.0, 0.0]));
        // A frame that dropped the past restarts the line with its own estimate.
        line.feed(3.0, Some([5.0, 5.0]), 6, 4.0, false);
        assert_eq!(line.velocity(), None);
        line.feed(4.0, Some([6.0, 5.0]), 6, 4.0, true);
        assert_eq!(line.velocity(), Some([1.0, 0.0]));
    }
}
