//! The seam between the ROS 2 proxy's logic and the middleware its vehicle runs: samples of
//! the vehicle's topics come in through an [`Inbox`], goals go out through [`Goals`], over
//! DDS (Shoal's own participant) or rmw_zenoh ([`super::rmw_zenoh`]). The link task sees
//! the same decoded, validated samples and the same rejections either way, so mapping,
//! counters, loss detection and goals do not depend on the middleware.

use futures::StreamExt;
use shoal_dds::{CdrError, ReadError, SampleMeta, Subscription, WriteError, Writer};
use shoal_model::{Validated, ValidationError};

use super::msgs::{BatteryState, Log, NavSatFix, Odometry, PoseStamped};

/// Which of the vehicle's topics a sample came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Topic {
    Fix,
    Odom,
    Battery,
    Rosout,
}

/// A sample that decoded and passed its wire checks.
#[derive(Debug)]
pub(crate) enum Sample {
    Fix(Validated<NavSatFix>),
    // Boxed: an odometry sample is five times the size of the others.
    Odom(Box<Validated<Odometry>>),
    Battery(Validated<BatteryState>),
    Log(Validated<Log>),
}

/// Why a sample was dropped before the link saw it.
#[derive(Debug, thiserror::Error)]
pub(crate) enum Rejection {
    /// The payload did not decode as the topic's type.
    #[error("malformed: {0}")]
    Malformed(String),
    /// It decoded but failed its wire checks.
    #[error("invalid: {0}")]
    Invalid(String),
    /// rmw_zenoh: the key names another type or type hash than the topic's.
    #[cfg_attr(not(feature = "rmw-zenoh"), allow(dead_code))]
    #[error("wrong type: {0}")]
    WrongType(String),
    /// rmw_zenoh: no attachment, or not the one the design document specifies.
    #[cfg_attr(not(feature = "rmw-zenoh"), allow(dead_code))]
    #[error("bad attachment: {0}")]
    BadAttachment(String),
}

/// What an [`Inbox`] hands the link.
pub(crate) type Received = (Topic, Result<Sample, Rejection>);

/// Samples from the vehicle's topics.
pub(crate) enum Inbox {
    // Boxed: the DDS readers are several times the size of the Zenoh inbox.
    Dds(Box<DdsInbox>),
    #[cfg(feature = "rmw-zenoh")]
    Zenoh(super::rmw_zenoh::ZenohInbox),
}

impl Inbox {
    /// The next sample or rejection; `None` once no topic can deliver any more.
    pub(crate) async fn next(&mut self) -> Option<Received> {
        match self {
            Self::Dds(d) => d.next().await,
            #[cfg(feature = "rmw-zenoh")]
            Self::Zenoh(z) => z.next().await,
        }
    }
}

/// The vehicle's topics as DDS readers on Shoal's participant.
pub(crate) struct DdsInbox {
    pub(crate) fix: Subscription<NavSatFix>,
    pub(crate) odom: Subscription<Odometry>,
    pub(crate) battery: Subscription<BatteryState>,
    pub(crate) rosout: Option<Subscription<Log>>,
}

impl DdsInbox {
    async fn next(&mut self) -> Option<Received> {
        // Each branch is a stream's `next`, which is cancel-safe: a sample is never lost
        // when another branch wins.
        tokio::select! {
            Some(s) = self.fix.next() => Some((Topic::Fix, dds(s).map(Sample::Fix))),
            Some(s) = self.odom.next() => Some((Topic::Odom, dds(s).map(|o| Sample::Odom(Box::new(o))))),
            Some(s) = self.battery.next() => Some((Topic::Battery, dds(s).map(Sample::Battery))),
            Some(s) = next_or_pending(self.rosout.as_mut()) => {
                Some((Topic::Rosout, dds(s).map(Sample::Log)))
            }
            else => None,
        }
    }
}

fn dds<T>(s: Result<(T, SampleMeta), ReadError>) -> Result<T, Rejection> {
    match s {
        Ok((v, _)) => Ok(v),
        Err(ReadError::Malformed { detail, .. }) => Err(Rejection::Malformed(detail)),
        Err(e) => Err(Rejection::Invalid(e.to_string())),
    }
}

/// The next item of an optional stream; pending for ever when there is none.
async fn next_or_pending<S: futures::Stream + Unpin>(s: Option<&mut S>) -> Option<S::Item> {
    match s {
        Some(s) => s.next().await,
        None => std::future::pending().await,
    }
}

/// Why a goal could not be published.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GoalError {
    /// The DDS writer refused it.
    #[error(transparent)]
    Dds(#[from] WriteError<PoseStamped>),
    /// The goal fails its own wire checks (a non-finite coordinate).
    #[error("invalid goal: {0}")]
    Invalid(#[from] ValidationError),
    /// It does not serialise as CDR.
    #[error(transparent)]
    Encode(#[from] CdrError),
    /// The Zenoh publisher refused it.
    #[cfg(feature = "rmw-zenoh")]
    #[error("rmw_zenoh publication failed: {source}")]
    Zenoh {
        /// Zenoh's error.
        source: zenoh::Error,
    },
}

/// Where goals go.
#[derive(Debug)]
pub(crate) enum Goals {
    Dds(Writer<PoseStamped>),
    #[cfg(feature = "rmw-zenoh")]
    Zenoh(super::rmw_zenoh::ZenohGoals),
}

impl Goals {
    /// How many of the vehicle's subscriptions the goal topic reaches now: DDS's matched
    /// readers, or the subscriptions rmw_zenoh's liveliness tokens announce on the goal
    /// topic with its type and type hash.
    pub(crate) fn subscribers(&self) -> usize {
        match self {
            Self::Dds(w) => usize::try_from(w.matched_readers()).unwrap_or(0),
            #[cfg(feature = "rmw-zenoh")]
            Self::Zenoh(z) => z.subscribers(),
        }
    }

    /// Publishes a goal.
    pub(crate) async fn publish(&self, goal: PoseStamped) -> Result<(), GoalError> {
        match self {
            Self::Dds(w) => Ok(w.write(goal).await?),
            #[cfg(feature = "rmw-zenoh")]
            Self::Zenoh(z) => z.publish(&goal).await,
        }
    }
}
