//! Link metadata: how the station tells that a vehicle's data came acoustically. The type
//! lives in `shoal-model` (the station reads it too); the CDT writes it.

pub use shoal_model::LINK_EVENT_PREFIX as EVENT_ID_PREFIX;
pub use shoal_model::LinkStatus;
