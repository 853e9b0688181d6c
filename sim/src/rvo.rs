//! RVO2 v2.0.3 with static obstacles (issue 53).
