//! Learner → actor messages: [`Ack`] (at-least-once delivery) and [`Control`] (ε, run phase,
//! flow-control credits).

use serde::{Deserialize, Serialize};

use crate::columns::check_max;
use crate::error::ValidationError;
use crate::header::{Body, MessageKind};

/// Most episode indices in one acknowledgement.
pub const MAX_ACKED_EPISODES: usize = 65_536;
/// Most credit grants in one control message.
pub const MAX_CREDIT_GRANTS: usize = 4096;

/// Episodes of one actor that the learner has accepted (stored durably). The actor keeps every
/// unacknowledged episode and re-sends it after a learner restart; the learner deduplicates on
/// (actor, episode). `acked_below` is also the next episode the learner expects from the actor:
/// an actor whose outbox starts past it (episodes an earlier learner acknowledged that this
/// one's store does not hold: an older checkpoint restored, the log moved aside) reports them
/// lost and numbers its episodes from there again.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ack {
    /// Actor index the acknowledgement is for.
    pub actor: u32,
    /// Every episode index `< acked_below` is acknowledged (cumulative).
    pub acked_below: u64,
    /// Further acknowledged episode indices `>= acked_below` (out-of-order arrivals).
    pub episodes: Vec<u64>,
    /// Which learner sent it: its liveliness instance (`Member::instance`, new at every start).
    /// An actor takes acknowledgements only from the learner alive now, so a stale learner of
    /// the same run cannot move it. 0 in messages of senders that predate the field.
    #[serde(default)]
    pub learner: u64,
}

impl Ack {
    /// Whether episode `episode` is acknowledged.
    pub fn covers(&self, episode: u64) -> bool {
        episode < self.acked_below || self.episodes.contains(&episode)
    }
}

impl Body for Ack {
    const KIND: MessageKind = MessageKind::Ack;

    fn validate(&self) -> Result<(), ValidationError> {
        check_max(
            "episodes",
            self.episodes.len() as u64,
            MAX_ACKED_EPISODES as u64,
        )
    }
}

/// Phase of the run, decided by the learner.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RunPhase {
    /// Imitation warm start: actors run the ORCA demonstrator.
    Imitation,
    /// Reinforcement learning with the broadcast weights and `epsilon`.
    Training,
    /// Actors stop starting episodes until the phase changes.
    Paused,
    /// The run is over; actors finish and exit.
    Finished,
}

/// Cumulative episode budget of one actor: it may have published at most `episode_budget`
/// episodes in total (idempotent, so a lost or repeated grant is harmless).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CreditGrant {
    /// Actor index.
    pub actor: u32,
    /// Total episodes the actor may have published so far.
    pub episode_budget: u64,
}

/// Run-wide control state, learner → actors (latest value: a late actor gets it at once).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Control {
    /// Run phase.
    pub phase: RunPhase,
    /// Exploration rate ε for new episodes, in [0, 1].
    pub epsilon: f32,
    /// Flow-control credits, one grant per actor (actors without a grant wait).
    pub credits: Vec<CreditGrant>,
    /// With [`RunPhase::Finished`]: the RL episodes the run's final weights were trained on.
    /// Their version (this message's header) is not enough to know them by: in the adaptive
    /// mode a version is a round of updates, and the last episodes may be taken after the last
    /// round, so the final weights can repeat the version of earlier weights that carried fewer
    /// episodes. Absent from older learners.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub final_rl_episodes: Option<u64>,
}

impl Control {
    /// The episode budget granted to `actor`, if any.
    pub fn budget_for(&self, actor: u32) -> Option<u64> {
        self.credits
            .iter()
            .find(|c| c.actor == actor)
            .map(|c| c.episode_budget)
    }
}

impl Body for Control {
    const KIND: MessageKind = MessageKind::Control;

    fn validate(&self) -> Result<(), ValidationError> {
        if !(self.epsilon.is_finite() && (0.0..=1.0).contains(&self.epsilon)) {
            return Err(ValidationError::InvalidField {
                field: "epsilon",
                reason: format!("{} is not in [0, 1]", self.epsilon),
            });
        }
        check_max(
            "credits",
            self.credits.len() as u64,
            MAX_CREDIT_GRANTS as u64,
        )
    }
}
