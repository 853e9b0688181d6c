//! The replay memory: a ring of featurised transitions with their value-target ingredients.

use rand::seq::index;
use rand::Rng;

use policy::FEATURE_DIM;

/// Transitions of a fixed shape (`humans` rows of 13 features per state), oldest overwritten
/// first once `capacity` is reached. Equality compares the stored transitions, not the cached
/// targets (a cache of the target network's values).
#[derive(Debug, Clone)]
pub struct Replay {
    capacity: usize,
    humans: usize,
    len: usize,
    next: usize,
    states: Vec<f32>,
    next_states: Vec<f32>,
    rewards: Vec<f32>,
    /// 0 at the end of an episode, else γ^{dt·v_pref}.
    discounts: Vec<f32>,
    /// Discounted Monte-Carlo return from the state (imitation targets).
    returns: Vec<f32>,
    /// Cached V-learning target y = r + discount·V_target(s'), valid while the target network
    /// is unchanged (not checkpointed: recomputed from the target network).
    targets: Vec<f32>,
}

/// One transition to store.
pub struct Transition<'a> {
    pub state: &'a [f32],
    pub next_state: &'a [f32],
    pub reward: f32,
    pub discount: f32,
    pub mc_return: f32,
}

impl PartialEq for Replay {
    fn eq(&self, o: &Self) -> bool {
        self.capacity == o.capacity
            && self.humans == o.humans
            && self.len == o.len
            && self.next == o.next
            && self.states == o.states
            && self.next_states == o.next_states
            && self.rewards == o.rewards
            && self.discounts == o.discounts
            && self.returns == o.returns
    }
}

/// The raw columns of a memory (borrowed for saving, owned for restoring).
#[derive(Debug, Clone, PartialEq)]
pub struct Columns<T> {
    pub states: T,
    pub next_states: T,
    pub rewards: T,
    pub discounts: T,
    pub returns: T,
    /// Next write position of the ring.
    pub next: usize,
}

/// A sampled batch, contiguous and ready for the network.
#[derive(Debug, Default, Clone)]
pub struct Batch {
    pub states: Vec<f32>,
    pub next_states: Vec<f32>,
    pub rewards: Vec<f32>,
    pub discounts: Vec<f32>,
    pub returns: Vec<f32>,
    pub targets: Vec<f32>,
}

impl Replay {
    pub fn new(capacity: usize, humans: usize) -> Self {
        Self {
            capacity,
            humans,
            len: 0,
            next: 0,
            states: Vec::new(),
            next_states: Vec::new(),
            rewards: Vec::new(),
            discounts: Vec::new(),
            returns: Vec::new(),
            targets: Vec::new(),
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    pub fn capacity(&self) -> usize {
        self.capacity
    }
    pub fn humans(&self) -> usize {
        self.humans
    }
    fn row(&self) -> usize {
        self.humans * FEATURE_DIM
    }

    /// Stores `t` and returns its slot.
    pub fn push(&mut self, t: Transition<'_>) -> usize {
        let row = self.row();
        debug_assert_eq!(t.state.len(), row);
        debug_assert_eq!(t.next_state.len(), row);
        if self.len < self.capacity {
            self.states.extend_from_slice(t.state);
            self.next_states.extend_from_slice(t.next_state);
            self.rewards.push(t.reward);
            self.discounts.push(t.discount);
            self.returns.push(t.mc_return);
            self.targets.push(0.0);
            self.len += 1;
        } else {
            let i = self.next;
            self.states[i * row..(i + 1) * row].copy_from_slice(t.state);
            self.next_states[i * row..(i + 1) * row].copy_from_slice(t.next_state);
            self.rewards[i] = t.reward;
            self.discounts[i] = t.discount;
            self.returns[i] = t.mc_return;
            self.targets[i] = 0.0;
        }
        let slot = self.next;
        self.next = (self.next + 1) % self.capacity;
        slot
    }

    /// Next states, rewards and discounts of slots `range` (for recomputing targets).
    pub fn target_inputs(&self, range: std::ops::Range<usize>) -> (&[f32], &[f32], &[f32]) {
        let row = self.row();
        (
            &self.next_states[range.start * row..range.end * row],
            &self.rewards[range.clone()],
            &self.discounts[range],
        )
    }

    /// Overwrites the cached targets of slots `start..start + y.len()`.
    pub fn set_targets(&mut self, start: usize, y: &[f32]) {
        self.targets[start..start + y.len()].copy_from_slice(y);
    }

    /// Copies the transitions `indices` into `out`.
    pub fn gather(&self, indices: impl IntoIterator<Item = usize>, out: &mut Batch) {
        let row = self.row();
        out.states.clear();
        out.next_states.clear();
        out.rewards.clear();
        out.discounts.clear();
        out.returns.clear();
        out.targets.clear();
        for i in indices {
            out.states
                .extend_from_slice(&self.states[i * row..(i + 1) * row]);
            out.next_states
                .extend_from_slice(&self.next_states[i * row..(i + 1) * row]);
            out.rewards.push(self.rewards[i]);
            out.discounts.push(self.discounts[i]);
            out.returns.push(self.returns[i]);
            out.targets.push(self.targets[i]);
        }
    }

    /// `size` distinct transitions chosen uniformly (fewer if the memory holds fewer).
    pub fn sample<R: Rng>(&self, rng: &mut R, size: usize, out: &mut Batch) {
        let size = size.min(self.len);
        self.gather(index::sample(rng, self.len, size), out);
    }

    /// The raw columns, for checkpoints.
    pub fn columns(&self) -> Columns<&[f32]> {
        Columns {
            states: &self.states,
            next_states: &self.next_states,
            rewards: &self.rewards,
            discounts: &self.discounts,
            returns: &self.returns,
            next: self.next,
        }
    }

    /// Rebuilds a memory from [`Replay::columns`]; `None` if the columns do not fit together.
    pub fn from_columns(capacity: usize, humans: usize, c: Columns<Vec<f32>>) -> Option<Self> {
        let Columns {
            states,
            next_states,
            rewards,
            discounts,
            returns,
            next,
        } = c;
        let len = rewards.len();
        let row = humans * FEATURE_DIM;
        let fits = len <= capacity
            && capacity > 0
            && states.len() == len * row
            && next_states.len() == len * row
            && discounts.len() == len
            && returns.len() == len
            && next < capacity
            && (len == capacity || next == len % capacity);
        fits.then_some(Self {
            targets: vec![0.0; len],
            capacity,
            humans,
            len,
            next,
            states,
            next_states,
            rewards,
            discounts,
            returns,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn t(v: f32, humans: usize) -> (Vec<f32>, Vec<f32>) {
        (
            vec![v; humans * FEATURE_DIM],
            vec![v + 0.5; humans * FEATURE_DIM],
        )
    }

    #[test]
    fn ring_overwrites_the_oldest() {
        let mut r = Replay::new(3, 2);
        for k in 0..5 {
            let (s, n) = t(k as f32, 2);
            r.push(Transition {
                state: &s,
                next_state: &n,
                reward: k as f32,
                discount: 0.9,
                mc_return: 1.0,
            });
        }
        assert_eq!(r.len(), 3);
        let mut b = Batch::default();
        r.gather(0..3, &mut b);
        // Slots hold 3, 4, 2 (0 and 1 were overwritten).
        assert_eq!(b.rewards, vec![3.0, 4.0, 2.0]);
        assert_eq!(b.states[0], 3.0);
        assert_eq!(b.next_states[2 * FEATURE_DIM], 4.5);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        r.sample(&mut rng, 10, &mut b);
        let mut got = b.rewards.clone();
        got.sort_by(f32::total_cmp);
        assert_eq!(got, vec![2.0, 3.0, 4.0], "distinct samples");
        let c = r.columns();
        let owned = Columns {
            states: c.states.to_vec(),
            next_states: c.next_states.to_vec(),
            rewards: c.rewards.to_vec(),
            discounts: c.discounts.to_vec(),
            returns: c.returns.to_vec(),
            next: c.next,
        };
        assert_eq!(Replay::from_columns(3, 2, owned.clone()).unwrap(), r);
        let mut bad = owned;
        bad.states.pop();
        assert!(Replay::from_columns(3, 2, bad).is_none());
    }
}
