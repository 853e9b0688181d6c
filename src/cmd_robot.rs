//! `fsrl sim --as-robot`: the robot stand-in for `fsrl serve`; arguments into one
//! `serve::standin::run`, one JSON line per episode on stdout.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;

use crate::cmd_serve::RosArgs;

/// `fsrl sim --as-robot` and its own arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct AsRobotArgs {
    /// Play as a robot for `fsrl serve` over zenoh (one of --settings, --episodes from
    /// --seed-start); one JSON line per episode.
    #[arg(long)]
    pub as_robot: bool,
    /// With --as-robot: play this model's world (its simulator config, as `fsrl eval`) and count
    /// the steps where a command is not its in-process decision on what the messages convey.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// With --as-robot: ask the queryable fsrl/serve/NAME/act instead of using topics.
    #[arg(long, value_name = "NAME")]
    pub via_queryable: Option<String>,
    #[command(flatten)]
    pub ros: RosArgs,
}

pub fn as_robot(
    a: &AsRobotArgs,
    sim: sim::SimConfig,
    settings: &[String],
    seeds: std::ops::Range<u64>,
) -> anyhow::Result<()> {
    let [setting] = settings else {
        anyhow::bail!("--as-robot plays one setting: --settings NAME")
    };
    let model = match &a.model {
        Some(p) => Some(
            learner::model::load_policy(p)
                .with_context(|| format!("cannot load {}", p.display()))?
                .0,
        ),
        None => None,
    };
    let link = match &a.via_queryable {
        Some(name) => serve::standin::Link::Queryable { name: name.clone() },
        None => serve::standin::Link::Topics {
            style: a.ros.style(),
            topics: a.ros.topics(),
            people: a.ros.people_format,
        },
    };
    let opts = serve::standin::RobotOptions {
        setting: setting.parse().map_err(|e| anyhow::anyhow!("{e}"))?,
        seeds,
        sim: model.as_ref().map_or(sim, |m| m.method_sim()),
        link,
        wait_for_server: Duration::from_secs(60),
        reply_timeout: Duration::from_secs(10),
        zenoh: a.ros.zenoh(),
    };
    let reference = model
        .as_ref()
        .map(|model| serve::standin::Reference { model });
    serve::standin::run(&opts, reference, |r| println!("{}", r.json_line()))?;
    Ok(())
}
