//! The six Shoal topics as one enum, and a decoded sample of any of them.

use shoal_dds::{CdrError, TopicType};
use shoal_model::{
    EnvironmentObservation, Event, StateVector, TaskAssignment, TaskStatus, Validate,
    ValidationError, VehicleAnnouncement,
};

/// One of the Shoal topics of `idl/shoal.idl`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Topic {
    /// `shoal/state_vector`.
    StateVector,
    /// `shoal/vehicle_announcement`.
    VehicleAnnouncement,
    /// `shoal/task_assignment`.
    TaskAssignment,
    /// `shoal/task_status`.
    TaskStatus,
    /// `shoal/event`.
    Event,
    /// `shoal/environment`.
    Environment,
}

impl Topic {
    /// Every topic, in the order of [`shoal_dds::ALL_TOPICS`].
    pub const ALL: [Topic; 6] = [
        Self::StateVector,
        Self::VehicleAnnouncement,
        Self::TaskAssignment,
        Self::TaskStatus,
        Self::Event,
        Self::Environment,
    ];

    /// The DDS topic name (also the MCAP channel's topic).
    pub fn name(self) -> &'static str {
        match self {
            Self::StateVector => StateVector::TOPIC,
            Self::VehicleAnnouncement => VehicleAnnouncement::TOPIC,
            Self::TaskAssignment => TaskAssignment::TOPIC,
            Self::TaskStatus => TaskStatus::TOPIC,
            Self::Event => Event::TOPIC,
            Self::Environment => EnvironmentObservation::TOPIC,
        }
    }

    /// The IDL type name (also the MCAP schema's name), e.g. `shoal::StateVector`.
    pub fn type_name(self) -> &'static str {
        match self {
            Self::StateVector => StateVector::TYPE_NAME,
            Self::VehicleAnnouncement => VehicleAnnouncement::TYPE_NAME,
            Self::TaskAssignment => TaskAssignment::TYPE_NAME,
            Self::TaskStatus => TaskStatus::TYPE_NAME,
            Self::Event => Event::TYPE_NAME,
            Self::Environment => EnvironmentObservation::TYPE_NAME,
        }
    }

    /// The topic of this DDS topic name, if it is a Shoal topic.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }

    /// Position in [`Topic::ALL`].
    pub(crate) fn index(self) -> usize {
        self as usize
    }
}

/// A decoded sample of any Shoal topic.
#[derive(Debug, Clone, PartialEq)]
pub enum Sample {
    /// A state vector.
    StateVector(StateVector),
    /// A vehicle announcement.
    VehicleAnnouncement(VehicleAnnouncement),
    /// A task assignment.
    TaskAssignment(TaskAssignment),
    /// A task status.
    TaskStatus(TaskStatus),
    /// An event.
    Event(Event),
    /// An environment observation.
    Environment(EnvironmentObservation),
}

impl Sample {
    /// The topic the sample travels on.
    pub fn topic(&self) -> Topic {
        match self {
            Self::StateVector(_) => Topic::StateVector,
            Self::VehicleAnnouncement(_) => Topic::VehicleAnnouncement,
            Self::TaskAssignment(_) => Topic::TaskAssignment,
            Self::TaskStatus(_) => Topic::TaskStatus,
            Self::Event(_) => Topic::Event,
            Self::Environment(_) => Topic::Environment,
        }
    }

    /// Decodes a recorded payload (encapsulation header + XCDR1 body) of `topic`.
    pub fn decode(topic: Topic, payload: &[u8]) -> Result<Self, CdrError> {
        use shoal_dds::from_cdr;
        Ok(match topic {
            Topic::StateVector => Self::StateVector(from_cdr(payload)?),
            Topic::VehicleAnnouncement => Self::VehicleAnnouncement(from_cdr(payload)?),
            Topic::TaskAssignment => Self::TaskAssignment(from_cdr(payload)?),
            Topic::TaskStatus => Self::TaskStatus(from_cdr(payload)?),
            Topic::Event => Self::Event(from_cdr(payload)?),
            Topic::Environment => Self::Environment(from_cdr(payload)?),
        })
    }

    /// The payload a recording holds for it: CDR_LE header and XCDR1 body, as on DDS.
    pub fn encode(&self) -> Result<Vec<u8>, CdrError> {
        use shoal_dds::to_cdr_le;
        match self {
            Self::StateVector(s) => to_cdr_le(s),
            Self::VehicleAnnouncement(s) => to_cdr_le(s),
            Self::TaskAssignment(s) => to_cdr_le(s),
            Self::TaskStatus(s) => to_cdr_le(s),
            Self::Event(s) => to_cdr_le(s),
            Self::Environment(s) => to_cdr_le(s),
        }
    }

    /// Checks the sample against the model's ranges and formats.
    pub fn validate(&self) -> Result<(), ValidationError> {
        match self {
            Self::StateVector(s) => s.validate(),
            Self::VehicleAnnouncement(s) => s.validate(),
            Self::TaskAssignment(s) => s.validate(),
            Self::TaskStatus(s) => s.validate(),
            Self::Event(s) => s.validate(),
            Self::Environment(s) => s.validate(),
        }
    }

    /// The vehicle that publishes this sample on a secure domain, or `None` when the
    /// station does (task assignments, and events that name no vehicle).
    pub fn publishing_vehicle(&self) -> Option<&str> {
        let id = match self {
            // The station assigns tasks; the vehicle_id is the addressee, not the sender.
            Self::TaskAssignment(_) => return None,
            Self::StateVector(s) => s.vehicle_id.as_str(),
            Self::VehicleAnnouncement(s) => s.vehicle_id.as_str(),
            Self::TaskStatus(s) => s.vehicle_id.as_str(),
            Self::Event(s) => s.vehicle_id.as_str(),
            Self::Environment(s) => s.vehicle_id.as_str(),
        };
        (!id.is_empty()).then_some(id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_match_the_dds_list_in_order() {
        for (topic, (name, type_name)) in Topic::ALL.iter().zip(shoal_dds::ALL_TOPICS) {
            assert_eq!(topic.name(), name);
            assert_eq!(topic.type_name(), type_name);
            assert_eq!(Topic::from_name(name), Some(*topic));
            assert_eq!(Topic::ALL[topic.index()], *topic);
        }
        assert_eq!(Topic::from_name("rt/chatter"), None);
    }
}
