//! `evaluator`: placeholder, filled by its issue.
