//! `actor`: placeholder, filled by its issue.
