//! `fsrl serve`: a model driving a robot over zenoh (ROS 2 topics and a queryable); arguments
//! into one `serve::run`. The ROS 2 arguments are shared with `fsrl sim --as-robot`
//! (`cmd_robot.rs`).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use serve::{Distro, PeopleFormat, Ros2Style, Topics, Trigger};

/// How ROS 2 topics travel on zenoh and where zenoh connects (both ends).
#[derive(Debug, Clone, clap::Args)]
pub struct RosArgs {
    /// ROS 2 key style: `bridge` (zenoh-bridge-ros2dds: topic names) or `rmw-zenoh` (keys with
    /// type names and hashes, attachments, liveliness tokens).
    #[arg(long, default_value = "bridge", value_parser = ["bridge", "rmw-zenoh"])]
    pub ros2: String,
    /// With --ros2 bridge: the bridge's namespace (keys NAMESPACE/TOPIC).
    #[arg(long)]
    pub namespace: Option<String>,
    /// With --ros2 rmw-zenoh: the ROS domain id.
    #[arg(long, default_value_t = 0)]
    pub domain: u32,
    /// With --ros2 rmw-zenoh: humble or jazzy (type hashes in keys).
    #[arg(long, default_value = "jazzy")]
    pub distro: Distro,
    #[arg(long, default_value = "odom")]
    pub odom_topic: String,
    #[arg(long, default_value = "goal_pose")]
    pub goal_topic: String,
    #[arg(long, default_value = "people")]
    pub people_topic: String,
    #[arg(long, default_value = "cmd_vel")]
    pub cmd_vel_topic: String,
    /// People message: people (people_msgs/People), spencer (TrackedPersons), pedsim (AgentStates).
    #[arg(long, default_value = "people")]
    pub people_format: PeopleFormat,
    /// zenoh endpoints to listen on.
    #[arg(long, default_value = "tcp/127.0.0.1:0")]
    pub listen: Vec<String>,
    /// zenoh endpoints to connect to (a router, e.g. rmw_zenohd's tcp/127.0.0.1:7447).
    #[arg(long)]
    pub connect: Vec<String>,
}

impl RosArgs {
    pub fn style(&self) -> Ros2Style {
        match self.ros2.as_str() {
            "rmw-zenoh" => Ros2Style::RmwZenoh {
                domain: self.domain,
                distro: self.distro,
            },
            _ => Ros2Style::Bridge {
                namespace: self.namespace.clone(),
            },
        }
    }
    pub fn topics(&self) -> Topics {
        let [odom, goal, people, cmd_vel] = [
            &self.odom_topic,
            &self.goal_topic,
            &self.people_topic,
            &self.cmd_vel_topic,
        ]
        .map(|t| t.clone());
        Topics {
            odom,
            goal,
            people,
            cmd_vel,
        }
    }
    pub fn zenoh(&self) -> transport::ZenohConfig {
        transport::ZenohConfig::peer(self.listen.clone(), self.connect.clone())
    }
}

#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// Model file (.fsrlm) or checkpoint (.ckpt).
    pub model: PathBuf,
    /// Names the queryable fsrl/serve/NAME/act and the ROS 2 node.
    #[arg(long, default_value = "fsrl")]
    pub name: String,
    /// Decide every period (`timer`) or on each odometry once people of its stamp are in
    /// (`odometry`: a simulator in lockstep).
    #[arg(long, default_value = "timer", value_parser = ["timer", "odometry"])]
    pub trigger: String,
    /// Control period in seconds [default: the model's step].
    #[arg(long)]
    pub period_s: Option<f64>,
    /// Zero command when odometry or people are older than this many periods.
    #[arg(long, default_value_t = 2.0)]
    pub stale_periods: f64,
    #[arg(long, default_value_t = f64::INFINITY)]
    pub max_speed_mps: f64,
    #[arg(long, default_value_t = f64::INFINITY)]
    pub max_turn_rate_radps: f64,
    /// Whether people react to the robot [default: as in the model's trained setting].
    #[arg(long)]
    pub robot_visible: Option<bool>,
    #[command(flatten)]
    pub ros: RosArgs,
}

pub fn run(a: ServeArgs) -> anyhow::Result<()> {
    let period = a
        .period_s
        .map(Duration::try_from_secs_f64)
        .transpose()
        .context("--period-s")?;
    let opts = serve::ServeOptions {
        style: a.ros.style(),
        topics: a.ros.topics(),
        zenoh: a.ros.zenoh(),
        model: a.model,
        name: a.name,
        people_format: a.ros.people_format,
        trigger: if a.trigger == "odometry" {
            Trigger::Odometry
        } else {
            Trigger::Timer
        },
        period,
        stale_periods: a.stale_periods,
        limits: serve::served::Limits {
            max_speed_mps: a.max_speed_mps,
            max_turn_rate_radps: a.max_turn_rate_radps,
        },
        robot_visible: a.robot_visible,
    };
    let (tx, rx) = serve::node::channel();
    let stop = std::sync::Mutex::new(tx.clone());
    ctrlc::set_handler(move || {
        if let Ok(tx) = stop.lock() {
            let _ = tx.send(serve::node::Event::Shutdown);
        }
    })
    .context("installing the Ctrl-C/SIGTERM handler")?;
    // The line tests and scripts wait for: everything is declared, commands flow from now on.
    serve::run(&opts, (tx, rx), || println!("ready"))?;
    Ok(())
}
