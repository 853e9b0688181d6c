//! `fsrl serve`: a model driving a robot over zenoh (ROS 2 topics and a queryable); arguments
//! into one `serve::run`. The ROS 2 arguments are shared with `fsrl sim --as-robot`
//! (`cmd_robot.rs`).

use std::path::PathBuf;

use anyhow::Context;
use serve::{Clock, Distro, PeopleFormat, Ros2Style, Topics, Trigger};

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
    /// The laser scan (sensor_msgs/LaserScan): read by `fsrl serve --scan`, published by
    /// `fsrl sim --as-robot` among walls.
    #[arg(long, default_value = "scan")]
    pub scan_topic: String,
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
        let [odom, goal, people, cmd_vel, scan] = [
            &self.odom_topic,
            &self.goal_topic,
            &self.people_topic,
            &self.cmd_vel_topic,
            &self.scan_topic,
        ]
        .map(|t| t.clone());
        Topics {
            odom,
            goal,
            people,
            cmd_vel,
            scan,
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
    #[arg(long, allow_negative_numbers = true)]
    pub period_s: Option<f64>,
    /// Zero command when odometry or people are older than this many periods.
    #[arg(long, default_value_t = serve::control::DEFAULT_STALE_PERIODS, allow_negative_numbers = true)]
    pub stale_periods: f64,
    /// Largest linear speed sent, m/s [default: no limit but the model's actions].
    #[arg(long, allow_negative_numbers = true)]
    pub max_speed_mps: Option<f64>,
    /// Largest turn rate sent, rad/s [default: no limit but the model's actions].
    #[arg(long, allow_negative_numbers = true)]
    pub max_turn_rate_radps: Option<f64>,
    /// Most people in one message (or query); more: refused, a zero command.
    #[arg(long, default_value_t = serve::control::DEFAULT_MAX_PEOPLE)]
    pub max_people: usize,
    /// Longest a decision may take, in seconds; a slower one is dropped for a zero command
    /// [default: half the period].
    #[arg(long, allow_negative_numbers = true)]
    pub decision_budget_s: Option<f64>,
    /// Stamps are the simulator's (or a bag's) clock, not this computer's: people and goal
    /// stamps are checked against the odometry's only (ROS' use_sim_time).
    #[arg(long)]
    pub use_sim_time: bool,
    /// How far a stamp may be from the clock it is checked against, in seconds.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub stamp_tolerance_s: f64,
    /// Whether people react to the robot [default: as in the model's trained setting].
    #[arg(long)]
    pub robot_visible: Option<bool>,
    /// Decide with depth-2 planning over the K best first steps (beyond the paper: safer and
    /// faster in docs/REPRODUCTION.md Experiment 21, about 1 + K times the decision's work;
    /// 0: the paper's one-step lookahead) [default: the model's own `train.planning_top_k`].
    #[arg(long, value_name = "K")]
    pub planning_top_k: Option<usize>,
    /// With --planning-top-k, try the M best one-step actions as second steps (0: every
    /// action; fewer cost less) [default: the model's own `train.planning_breadth`].
    #[arg(long, value_name = "M")]
    pub planning_breadth: Option<usize>,
    /// Threads one decision's network work is split over (the decision is the same; worth it
    /// with --planning-top-k) [default: every core, at most 4].
    #[arg(long)]
    pub threads: Option<usize>,
    /// Static obstacles in the odometry frame: a TOML file of `[[obstacles]]` tables in the
    /// scene format (kind polygon, wall or boundary; vertices [[x, y], ...] in metres), checked
    /// before anything starts. Every decision plans among them. Not with --scan.
    #[arg(long, value_name = "FILE")]
    pub map: Option<PathBuf>,
    /// See the walls through a laser scan (--scan-topic): each decision plans among the walls
    /// the latest scan shows (people's returns dropped); no fresh, well-formed scan: a zero
    /// command. Not with --map.
    #[arg(long)]
    pub scan: bool,
    /// With --scan: the sensor's place in the robot's base frame, x ahead, metres.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub scan_x_m: f64,
    /// With --scan: the sensor's place in the robot's base frame, y to the left, metres.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub scan_y_m: f64,
    /// With --scan: the sensor's yaw in the robot's base frame, counter-clockwise.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub scan_yaw_rad: f64,
    /// With --scan: consecutive returns at most this far apart are one wall.
    #[arg(long, default_value_t = serve::scan::DEFAULT_MAX_GAP_M, allow_negative_numbers = true)]
    pub scan_max_gap_m: f64,
    /// With --scan: each wall the scan shows is simplified within this many metres.
    #[arg(long, default_value_t = serve::scan::DEFAULT_TOLERANCE_M, allow_negative_numbers = true)]
    pub scan_tolerance_m: f64,
    /// With --scan: a wall seen on both sides of a person, its returns at most this far apart,
    /// runs on straight behind the person (0: never).
    #[arg(long, default_value_t = serve::scan::DEFAULT_SHADOW_GAP_M, allow_negative_numbers = true)]
    pub scan_shadow_gap_m: f64,
    /// With --scan: returns within a tracked person's radius plus this are the person's.
    #[arg(long, default_value_t = serve::scan::DEFAULT_PEOPLE_MARGIN_M, allow_negative_numbers = true)]
    pub scan_people_margin_m: f64,
    /// With --scan: a scan with a larger fraction of NaN ranges is refused (a zero command).
    #[arg(long, default_value_t = sim::scan::DEFAULT_MAX_NAN_FRACTION, allow_negative_numbers = true)]
    pub scan_max_nan_fraction: f64,
    #[command(flatten)]
    pub ros: RosArgs,
}

/// The map of `--map FILE`, every problem named with the file, line and obstacle.
fn read_map(path: &std::path::Path) -> anyhow::Result<sim::map::StaticMap> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("--map {}: cannot read it", path.display()))?;
    sim::scene_map::parse_toml_map(&text)
        .map_err(|e| anyhow::anyhow!("--map {}: {e}", path.display()))
}

pub fn run(a: ServeArgs) -> anyhow::Result<()> {
    // The map first: a bad file is refused before anything is opened or loaded.
    let map = a.map.as_deref().map(read_map).transpose()?;
    let scan = a.scan.then_some(serve::scan::ScanOptions {
        x_m: a.scan_x_m,
        y_m: a.scan_y_m,
        yaw_rad: a.scan_yaw_rad,
        max_gap_m: a.scan_max_gap_m,
        tolerance_m: a.scan_tolerance_m,
        shadow_gap_m: a.scan_shadow_gap_m,
        people_margin_m: a.scan_people_margin_m,
        max_nan_fraction: a.scan_max_nan_fraction,
    });
    let opts = serve::ServeOptions {
        map,
        scan,
        style: a.ros.style(),
        topics: a.ros.topics(),
        zenoh: a.ros.zenoh(),
        name: a.name,
        people_format: a.ros.people_format,
        trigger: if a.trigger == "odometry" {
            Trigger::Odometry
        } else {
            Trigger::Timer
        },
        period_s: a.period_s,
        stale_periods: a.stale_periods,
        limits: serve::served::Limits {
            max_speed_mps: a.max_speed_mps,
            max_turn_rate_radps: a.max_turn_rate_radps,
        },
        clock: if a.use_sim_time {
            Clock::Odometry
        } else {
            Clock::System
        },
        stamp_tolerance_s: a.stamp_tolerance_s,
        max_people: a.max_people,
        decision_budget_s: a.decision_budget_s,
        robot_visible: a.robot_visible,
        planning_top_k: a.planning_top_k,
        planning_breadth: a.planning_breadth,
        threads: a.threads.unwrap_or_else(|| {
            std::thread::available_parallelism()
                .map_or(1, |n| n.get())
                .min(4)
        }),
        ..serve::ServeOptions::new(a.model)
    };
    // Every bad number in one line, before anything is opened, loaded or installed.
    opts.check()?;
    let inbox = serve::Inbox::new();
    let stop = inbox.stopper();
    ctrlc::set_handler(move || stop.stop()).context("installing the Ctrl-C/SIGTERM handler")?;
    // The line tests and scripts wait for: everything is declared, commands flow from now on.
    serve::run(&opts, inbox, || println!("ready"))?;
    Ok(())
}
