//! The six Shoal topics: names, type names, keys and QoS profiles.

use serde::{Deserialize, Serialize, de::DeserializeOwned};
use shoal_model::{
    EnvironmentObservation, Event, StateVector, TaskAssignment, TaskStatus, Validate,
    VehicleAnnouncement,
};

use crate::qos::{Priority, QosProfile};

/// A model type that travels on a Shoal topic. Implemented for every type of `idl/shoal.idl`.
pub trait TopicType:
    Serialize + DeserializeOwned + Validate + Clone + Send + Sync + std::fmt::Debug + 'static
{
    /// DDS topic name.
    const TOPIC: &'static str;
    /// DDS type name, module-qualified as in the IDL.
    const TYPE_NAME: &'static str;
    /// QoS profile the topic uses.
    const PROFILE: QosProfile;
    /// Priority class used when the caller does not choose one.
    const DEFAULT_PRIORITY: Priority;
    /// The instance key type (the IDL's `@key` fields in order).
    type Key: std::fmt::Debug + Serialize;
    /// The instance key of this sample.
    fn key(&self) -> Self::Key;
    /// The names of the key fields, in order (empty for an unkeyed type). DDS computes
    /// each sample's instance from these fields of its serialised form.
    const KEY_FIELDS: &'static [&'static str] = &[];
    /// Whether the topic has a key (RTPS WITH_KEY endpoints). Foreign types without one,
    /// such as ROS 2 messages, set `false`: DDS implementations match only endpoints of the
    /// same keyedness (Cyclone DDS drops the others silently).
    const KEYED: bool = true;
    /// The vehicle this sample speaks for, which a subscriber checks against the vehicle
    /// whose partition it came in ("a vehicle publishes only its own data"); `None` for
    /// foreign types.
    fn owner_vehicle(&self) -> Option<&str> {
        None
    }
}

/// A Shoal topic keyed by one of its string fields and owned by the vehicle it names in
/// `vehicle_id` (subscribers check that owner against the publisher's partition).
macro_rules! string_keyed_topic {
    ($ty:ty, $topic:literal, $type_name:literal, $profile:ident, $priority:ident, $key:ident) => {
        impl TopicType for $ty {
            const TOPIC: &'static str = $topic;
            const TYPE_NAME: &'static str = $type_name;
            const PROFILE: QosProfile = QosProfile::$profile;
            const DEFAULT_PRIORITY: Priority = Priority::$priority;
            type Key = String;
            fn key(&self) -> String {
                self.$key.clone()
            }
            const KEY_FIELDS: &'static [&'static str] = &[stringify!($key)];
            fn owner_vehicle(&self) -> Option<&str> {
                Some(&self.vehicle_id)
            }
        }
    };
}

string_keyed_topic!(
    StateVector,
    "shoal/state_vector",
    "shoal::StateVector",
    State,
    Telemetry,
    vehicle_id
);
string_keyed_topic!(
    VehicleAnnouncement,
    "shoal/vehicle_announcement",
    "shoal::VehicleAnnouncement",
    Announcements,
    Control,
    vehicle_id
);
string_keyed_topic!(
    TaskAssignment,
    "shoal/task_assignment",
    "shoal::TaskAssignment",
    Tasks,
    Control,
    task_id
);
string_keyed_topic!(
    TaskStatus,
    "shoal/task_status",
    "shoal::TaskStatus",
    TaskStatus,
    Control,
    task_id
);
string_keyed_topic!(
    Event,
    "shoal/event",
    "shoal::Event",
    Events,
    Control,
    event_id
);

/// Key of an environment observation: (`vehicle_id`, `property`), in IDL order.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct ObservationKey {
    /// Vehicle that measured.
    pub vehicle_id: String,
    /// Property measured.
    pub property: String,
}

impl TopicType for EnvironmentObservation {
    const TOPIC: &'static str = "shoal/environment";
    const TYPE_NAME: &'static str = "shoal::EnvironmentObservation";
    const PROFILE: QosProfile = QosProfile::Environment;
    const DEFAULT_PRIORITY: Priority = Priority::Bulk;
    type Key = ObservationKey;
    const KEY_FIELDS: &'static [&'static str] = &["vehicle_id", "property"];
    fn key(&self) -> ObservationKey {
        ObservationKey {
            vehicle_id: self.vehicle_id.clone(),
            property: self.property.clone(),
        }
    }
    fn owner_vehicle(&self) -> Option<&str> {
        Some(&self.vehicle_id)
    }
}

/// Every topic's name and type name, for tools and documentation.
pub const ALL_TOPICS: [(&str, &str); 6] = [
    (StateVector::TOPIC, StateVector::TYPE_NAME),
    (VehicleAnnouncement::TOPIC, VehicleAnnouncement::TYPE_NAME),
    (TaskAssignment::TOPIC, TaskAssignment::TYPE_NAME),
    (TaskStatus::TOPIC, TaskStatus::TYPE_NAME),
    (Event::TOPIC, Event::TYPE_NAME),
    (
        EnvironmentObservation::TOPIC,
        EnvironmentObservation::TYPE_NAME,
    ),
];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::Shape;

    fn traced<T: TopicType>() -> Shape {
        Shape::of::<T>(T::TYPE_NAME, T::KEY_FIELDS)
            .unwrap_or_else(|e| unreachable!("{}: {e}", T::TYPE_NAME))
    }

    #[test]
    fn every_topic_type_has_a_layout_dds_can_carry_and_its_key_fields() {
        traced::<StateVector>();
        traced::<VehicleAnnouncement>();
        traced::<TaskAssignment>();
        traced::<TaskStatus>();
        traced::<Event>();
        traced::<EnvironmentObservation>();
    }

    #[test]
    fn a_task_cut_short_of_its_lease_is_refused_not_defaulted() {
        // The lease members default when absent from JSON; on the wire a @final struct's
        // members are all there, and a sample without them must not pass as "no lease".
        let mut a = TaskAssignment::new(
            "t-1",
            "",
            "auv-1",
            1_800_000_000_000,
            &shoal_model::Task::Surface,
        );
        a.lease_term = 2;
        a.lease_holder = "shore".into();
        let bytes = crate::to_cdr_le(&a).unwrap();
        assert_eq!(crate::from_cdr::<TaskAssignment>(&bytes).unwrap(), a);
        // Without the holder (4-byte length + "shore\0") and the term.
        let short = &bytes[..bytes.len() - 10 - 8];
        assert!(crate::from_cdr::<TaskAssignment>(short).is_err());
    }

    #[test]
    fn a_key_field_the_type_lacks_is_an_error() {
        assert!(Shape::of::<StateVector>("shoal::StateVector", &["nope"]).is_err());
    }
}
