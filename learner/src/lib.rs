//! `learner`: placeholder, filled by its issue.
