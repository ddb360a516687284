//! Who a certificate speaks for: the station or one vehicle, named as in the data model.

use std::fmt;

use shoal_model::{MAX_ID_LEN, MAX_VEHICLE_ID_LEN, is_identifier};

/// Prefix of the subject-alternative-name URI of every Shoal identity certificate.
pub const URN_PREFIX: &str = "urn:shoal:";

/// The part an identity plays in the swarm.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Role {
    /// The Command and Control Station (its middleware core, CDT and console).
    Station,
    /// One vehicle (its DDS proxy and VDT).
    Vehicle,
}

impl Role {
    /// The role's name as written in certificates.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Station => "station",
            Self::Vehicle => "vehicle",
        }
    }

    /// Parses `station` or `vehicle`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "station" => Some(Self::Station),
            "vehicle" => Some(Self::Vehicle),
            _ => None,
        }
    }

    /// Longest name this role allows: vehicle ids follow the data model's `vehicle_id` rule.
    fn max_name_len(self) -> usize {
        match self {
            Self::Station => MAX_ID_LEN,
            Self::Vehicle => MAX_VEHICLE_ID_LEN,
        }
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// An authenticated name: a role plus the station name or vehicle id.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Identity {
    role: Role,
    name: String,
}

/// Why a string is not a valid identity.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum IdentityError {
    /// The name breaks the identifier rule (1..=32 or 64 characters of `[A-Za-z0-9_.-]`).
    #[error(
        "{role} name {name:?} is not an identifier (1 to {max} characters of A-Z a-z 0-9 _ . -)"
    )]
    BadName {
        /// The role the name was meant for.
        role: Role,
        /// The rejected name.
        name: String,
        /// The longest allowed name.
        max: usize,
    },
    /// The URI is not `urn:shoal:<station|vehicle>:<name>`.
    #[error(
        "{0:?} is not a Shoal identity URI (urn:shoal:station:<name> or urn:shoal:vehicle:<id>)"
    )]
    BadUri(String),
}

impl Identity {
    /// An identity after checking that `name` is a valid identifier for `role`.
    pub fn new(role: Role, name: &str) -> Result<Self, IdentityError> {
        let max = role.max_name_len();
        if !is_identifier(name, max) {
            return Err(IdentityError::BadName {
                role,
                name: name.to_owned(),
                max,
            });
        }
        Ok(Self {
            role,
            name: name.to_owned(),
        })
    }

    /// A vehicle identity; `id` is the data model's `vehicle_id`.
    pub fn vehicle(id: &str) -> Result<Self, IdentityError> {
        Self::new(Role::Vehicle, id)
    }

    /// A station identity.
    pub fn station(name: &str) -> Result<Self, IdentityError> {
        Self::new(Role::Station, name)
    }

    /// The role.
    pub fn role(&self) -> Role {
        self.role
    }

    /// The station name or vehicle id.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The vehicle id when this is a vehicle.
    pub fn vehicle_id(&self) -> Option<&str> {
        (self.role == Role::Vehicle).then_some(self.name.as_str())
    }

    /// The certificate SAN URI, e.g. `urn:shoal:vehicle:auv-1`.
    pub fn uri(&self) -> String {
        format!("{URN_PREFIX}{}:{}", self.role, self.name)
    }

    /// Parses a SAN URI written by [`Identity::uri`].
    pub fn from_uri(uri: &str) -> Result<Self, IdentityError> {
        let bad = || IdentityError::BadUri(uri.to_owned());
        let rest = uri.strip_prefix(URN_PREFIX).ok_or_else(bad)?;
        let (role, name) = rest.split_once(':').ok_or_else(bad)?;
        let role = Role::parse(role).ok_or_else(bad)?;
        Self::new(role, name)
    }
}

impl fmt::Display for Identity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.role, self.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uri_round_trips() {
        let v = Identity::vehicle("auv-1").unwrap();
        assert_eq!(v.uri(), "urn:shoal:vehicle:auv-1");
        assert_eq!(Identity::from_uri(&v.uri()).unwrap(), v);
        let s = Identity::station("ccs").unwrap();
        assert_eq!(Identity::from_uri("urn:shoal:station:ccs").unwrap(), s);
        assert_eq!(s.vehicle_id(), None);
        assert_eq!(v.vehicle_id(), Some("auv-1"));
    }

    #[test]
    fn bad_names_and_uris_are_refused() {
        assert!(Identity::vehicle("").is_err());
        assert!(Identity::vehicle("a/b").is_err());
        assert!(Identity::vehicle(&"x".repeat(33)).is_err());
        assert!(Identity::station(&"x".repeat(64)).is_ok());
        for uri in [
            "urn:shoal:robot:x",
            "urn:other:vehicle:x",
            "urn:shoal:vehicle",
            "urn:shoal:vehicle:a:b",
        ] {
            assert!(Identity::from_uri(uri).is_err(), "{uri}");
        }
    }
}
