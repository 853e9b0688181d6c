//! `serve`: a trained policy driving a robot, and a simulated robot to drive.
//!
//! - [`msg`]: the ROS 2 messages (odometry, goal, velocity command, three people formats) and
//!   their CDR bytes (`cdr-encoding`, with the encapsulation header);
//! - [`ros2`]: ROS 2 topics as zenoh keys, for `zenoh-bridge-ros2dds` and for `rmw_zenoh`
//!   (type names and hashes per distro, the 33-byte attachment, liveliness tokens);
//! - [`people`]: tracked people from `people_msgs/People`, `spencer_tracking_msgs/TrackedPersons`
//!   or `pedsim_msgs/AgentStates`;
//! - [`scan`]: walls from a `sensor_msgs/LaserScan` (`fsrl serve --scan`), the same way a map's
//!   are used (`fsrl serve --map`);
//! - [`served`]: [`served::ServedPolicy`], a model file's policy deciding from an observed state
//!   through the evaluator's own lookahead (same state, same action as `fsrl eval`);
//! - [`control`]: the loop's logic without IO: staleness, goal and frame checks, stamps against
//!   the clock and each other, the people cap, the decision budget, limits, the reason for
//!   every zero command, counting of undecodable and refused input;
//! - [`node`]: `fsrl serve` on zenoh ([`node::run`], in named phases): latest-value slots
//!   for the inputs taken all at once, the loop that takes its deadline first, the start-up's
//!   timing of the decision budget, the command publisher (congestion control `Drop`, a final
//!   zero command whatever ends the loop), liveliness;
//! - [`queries`]: the queryable `fsrl/serve/<name>/act` (MessagePack, `proto::serve`) behind
//!   bounded queues, answered and refused on threads of their own, never on zenoh's;
//! - [`standin`]: `fsrl sim --as-robot` ([`standin::run`]).
//!
//! Depends on `sim`, `policy`, `learner` (model files), `proto` and `transport` (zenoh
//! settings); opens its own zenoh session, as ROS 2 traffic is not fsrl's typed messages.

pub mod control;
#[doc(hidden)]
pub mod fixtures;
pub mod msg;
pub mod node;
pub mod people;
pub mod queries;
pub mod ros2;
pub mod scan;
pub mod served;
pub mod standin;

pub use control::Clock;
pub use node::{run, Inbox, ServeError, ServeOptions, Stopper, Topics, Trigger};
pub use people::PeopleFormat;
pub use ros2::{Distro, Ros2Style};
