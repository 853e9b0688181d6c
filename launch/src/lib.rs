//! `launch`: a training run as the processes see it. [`config`] is the run's one typed
//! configuration file (`FileConfig`: `[run]`, `[sim]`, `[train]`, `[transport]`, `[learner]`,
//! `[actor]`, `[evaluator]`; unknown keys refused, every problem reported at once), and
//! [`local`] runs a distributed training on one machine: a learner, actors and an evaluator as
//! child processes of the fsrl executable, watched over zenoh like any other tool would, then the
//! run's final evaluation (`lab::evaluation`).

pub mod config;
pub mod local;
