//! The learner's window over the last 100 episodes it stored: outcomes, policy lags and losses,
//! for the live metrics and the training log's rates.

use std::collections::VecDeque;

use sim::Outcome;

/// The last [`Window::LEN`] stored episodes.
#[derive(Debug, Default)]
pub(super) struct Window {
    pub(super) outcomes: VecDeque<Outcome>,
    pub(super) lags: VecDeque<u64>,
    pub(super) losses: VecDeque<f32>,
}

impl Window {
    /// Episodes the window holds.
    pub(super) const LEN: usize = 100;

    pub(super) fn push(&mut self, o: Outcome, lag: u64, loss: f32) {
        if self.outcomes.len() == Self::LEN {
            self.outcomes.pop_front();
            self.lags.pop_front();
            self.losses.pop_front();
        }
        self.outcomes.push_back(o);
        self.lags.push_back(lag);
        self.losses.push_back(loss);
    }
    /// The `q` quantile of the window's policy lags (nearest rank; 0 without episodes).
    pub(super) fn lag_quantile(&self, q: f64) -> u64 {
        let mut lags: Vec<u64> = self.lags.iter().copied().collect();
        if lags.is_empty() {
            return 0;
        }
        lags.sort_unstable();
        let rank = ((q * lags.len() as f64).ceil() as usize).clamp(1, lags.len());
        lags[rank - 1]
    }
    pub(super) fn rate(&self, o: Outcome) -> f64 {
        if self.outcomes.is_empty() {
            return 0.0;
        }
        self.outcomes.iter().filter(|x| **x == o).count() as f64 / self.outcomes.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lag_quantile_is_the_nearest_rank() {
        let mut w = Window::default();
        assert_eq!(w.lag_quantile(0.95), 0);
        for lag in [3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 7] {
            w.push(Outcome::ReachGoal, lag, 0.0);
        }
        // 20 lags: the 19th smallest is 3, the largest 7.
        assert_eq!(w.lag_quantile(0.95), 3);
        assert_eq!(w.lag_quantile(1.0), 7);
        assert_eq!(w.lag_quantile(0.5), 1);
    }
}
