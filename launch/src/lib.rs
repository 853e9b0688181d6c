//! `launch`: starting training runs, and the rules they are started by. [`config`] is the run's
//! one typed configuration file (`FileConfig`: `[run]`, `[sim]`, `[train]`, `[transport]`,
//! `[learner]`, `[actor]`, `[evaluator]`; unknown keys refused, every problem reported at once)
//! and the one place that decides a run's snapshot rule and replay ratio (`select_rule`,
//! `replay_ratio`). [`local`] runs a distributed training on one machine: a learner, actors and
//! an evaluator as child processes of the fsrl executable, watched over zenoh like any other
//! tool would. [`single`] runs one in this process (`trainer::run`, drawn by [`progress`]).
//! Both end with the run's final evaluation (`lab::evaluation`). [`reproduce`] runs the paper's
//! grid (`lab::grid`'s plan) as child processes: `fsrl train`, `export-model`, `eval`.

pub mod config;
pub mod local;
pub mod progress;
pub mod reproduce;
pub mod single;
