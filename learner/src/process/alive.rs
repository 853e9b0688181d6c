//! Who is alive, from the liveliness watcher's events: the actors by id (at most
//! [`MAX_ACTORS`] ids, however many instances each declares) and the evaluators (as many).
//! One tracker for every phase of the learner (warm start, training, the linger at the end),
//! so a flood of tokens is capped wherever it comes.

use std::collections::{BTreeMap, BTreeSet, HashSet};

use proto::Role;
use transport::{AliveEvent, Heartbeat};

use super::{warn_sometimes, MAX_ACTORS};

/// The processes alive that the learner keeps state for.
#[derive(Debug, Default)]
pub(super) struct Members {
    /// The actors alive: id → the instances (liveliness tokens) alive under it. Counted and
    /// capped by id ([`MAX_ACTORS`]); the watcher keeps at most
    /// [`transport::MAX_INSTANCES_PER_SENDER`] instances of an id (the newest), so a flood of
    /// tokens under one id neither fills the table nor crowds out other actors.
    pub(super) actors: AliveActors,
    /// The evaluators alive (at most [`MAX_ACTORS`]).
    pub(super) evaluators: HashSet<proto::Member>,
}

impl Members {
    /// Nobody the run's end waits for is alive.
    pub(super) fn nobody(&self) -> bool {
        self.actors.is_empty() && self.evaluators.is_empty()
    }

    /// Tracks who is alive, with the log lines (at most [`MAX_ACTORS`] actor ids and as many
    /// evaluators; a refusal is counted and logged at powers of two). It needs nothing of the
    /// learner but these sets, so the warm start drains liveliness with it too (a flood of
    /// tokens then cannot fill the watcher's bounded queue while nothing reads it).
    pub(super) fn track(&mut self, status: &Heartbeat, ev: AliveEvent) -> Membership {
        let (actors, evaluators) = (&mut self.actors, &mut self.evaluators);
        match ev {
            AliveEvent::Joined(m) if m.sender.role == Role::Actor => {
                let index = m.sender.index;
                match actors.join(index, m.instance, MAX_ACTORS) {
                    Joined::Refused => {
                        warn_sometimes(
                            status,
                            "alive",
                            actors.refused,
                            format_args!("ignoring actor {m}: {MAX_ACTORS} actor ids are alive"),
                        );
                        Membership::Unchanged
                    }
                    Joined::Known => Membership::Unchanged,
                    joined => {
                        tracing::info!(actor = %m, "actor joined");
                        Membership::ActorJoined {
                            index,
                            new_id: joined == Joined::NewId,
                        }
                    }
                }
            }
            AliveEvent::Left(m) if m.sender.role == Role::Actor => {
                let index = m.sender.index;
                match actors.leave(index, m.instance) {
                    Left::Unknown => Membership::Unchanged,
                    Left::Instance => {
                        tracing::warn!(actor = %m, "actor left");
                        Membership::Unchanged
                    }
                    Left::LastInstance => {
                        tracing::warn!(actor = %m, "actor left");
                        Membership::ActorGone(index)
                    }
                }
            }
            AliveEvent::Joined(m) if m.sender.role == Role::Evaluator => {
                if evaluators.len() < MAX_ACTORS {
                    evaluators.insert(m);
                }
                Membership::Unchanged
            }
            AliveEvent::Left(m) if m.sender.role == Role::Evaluator => {
                evaluators.remove(&m);
                Membership::Unchanged
            }
            _ => Membership::Unchanged,
        }
    }
}

/// What a liveliness event changed (see [`Members::track`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Membership {
    Unchanged,
    /// An instance of actor `index` joined (`new_id`: the id's first).
    ActorJoined {
        index: u32,
        new_id: bool,
    },
    /// The last instance of actor `index` left.
    ActorGone(u32),
}

/// The actors alive, by id: each id with the liveliness instances alive under it. At most `cap`
/// ids are admitted, however many instances an id declares (a flood of tokens under one id
/// takes one place, so the actors that join after it are still admitted).
#[derive(Debug, Default)]
pub(super) struct AliveActors {
    ids: BTreeMap<u32, BTreeSet<u64>>,
    /// Joins refused because `cap` ids were alive.
    pub(super) refused: u64,
}

/// What a liveliness token's arrival changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Joined {
    /// The id's first instance.
    NewId,
    /// Another instance of an id alive already.
    NewInstance,
    /// An instance already known.
    Known,
    /// A new id while `cap` ids were alive.
    Refused,
}

/// What a liveliness token's departure changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Left {
    /// The id's last instance: the id is gone.
    LastInstance,
    /// One of several instances.
    Instance,
    Unknown,
}

impl AliveActors {
    pub(super) fn join(&mut self, id: u32, instance: u64, cap: usize) -> Joined {
        let new_id = !self.ids.contains_key(&id);
        if new_id && self.ids.len() >= cap {
            self.refused += 1;
            return Joined::Refused;
        }
        if !self.ids.entry(id).or_default().insert(instance) {
            Joined::Known
        } else if new_id {
            Joined::NewId
        } else {
            Joined::NewInstance
        }
    }

    pub(super) fn leave(&mut self, id: u32, instance: u64) -> Left {
        let Some(instances) = self.ids.get_mut(&id) else {
            return Left::Unknown;
        };
        if !instances.remove(&instance) {
            return Left::Unknown;
        }
        if instances.is_empty() {
            self.ids.remove(&id);
            Left::LastInstance
        } else {
            Left::Instance
        }
    }

    pub(super) fn len(&self) -> usize {
        self.ids.len()
    }

    pub(super) fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// The ids alive, ascending.
    pub(super) fn ids(&self) -> impl Iterator<Item = u32> + '_ {
        self.ids.keys().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 35, item 1: the cap counts actor ids, not liveliness tokens, so one id's flood of
    /// instances (under its own credentials) leaves room for every other actor.
    #[test]
    fn a_flood_of_one_ids_instances_takes_one_place() {
        let mut alive = AliveActors::default();
        assert_eq!(alive.join(0, 1, 3), Joined::NewId);
        for instance in 2..5000 {
            assert_eq!(alive.join(0, instance, 3), Joined::NewInstance);
        }
        assert_eq!(alive.join(0, 7, 3), Joined::Known);
        assert_eq!(alive.len(), 1);
        assert_eq!(alive.join(1, 1, 3), Joined::NewId);
        assert_eq!(alive.join(2, 1, 3), Joined::NewId);
        assert_eq!(alive.join(3, 1, 3), Joined::Refused);
        assert_eq!(alive.refused, 1);
        assert_eq!(alive.ids().collect::<Vec<_>>(), [0, 1, 2]);
        // Id 0 stays until its last instance leaves; then id 3 gets the place.
        assert_eq!(alive.leave(0, 1), Left::Instance);
        assert_eq!(alive.leave(0, 1), Left::Unknown);
        for instance in 2..4999 {
            assert_eq!(alive.leave(0, instance), Left::Instance);
        }
        assert_eq!(alive.leave(0, 4999), Left::LastInstance);
        assert_eq!(alive.leave(9, 1), Left::Unknown);
        assert_eq!(alive.join(3, 1, 3), Joined::NewId);
        assert!(!alive.is_empty());
    }
}
