//! Small helpers shared by the modules: dates, randomness.

use time::OffsetDateTime;

/// A time in ms since the Unix epoch as a whole-second UTC date-time (X.509 has seconds).
pub(crate) fn datetime(ms: i64) -> OffsetDateTime {
    OffsetDateTime::from_unix_timestamp(ms.div_euclid(1000)).unwrap_or(if ms < 0 {
        OffsetDateTime::UNIX_EPOCH
    } else {
        // Past year 9999: clamp to the largest date the time crate represents.
        OffsetDateTime::new_utc(time::Date::MAX, time::Time::MIDNIGHT)
    })
}

/// RFC 3339 UTC text of a time in ms, e.g. `2026-05-01T12:00:00Z`, for messages.
pub(crate) fn rfc3339(ms: i64) -> String {
    let t = datetime(ms);
    format!(
        "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}Z",
        t.year(),
        u8::from(t.month()),
        t.day(),
        t.hour(),
        t.minute(),
        t.second()
    )
}

/// Fills `buf` from the operating system's random source.
pub(crate) fn random(buf: &mut [u8]) -> Result<(), RandomError> {
    getrandom::fill(buf).map_err(|e| RandomError(e.to_string()))
}

/// The operating system's random source failed (no entropy can be had).
#[derive(Debug, Clone, thiserror::Error)]
#[error("the operating system's random source failed: {0}")]
pub struct RandomError(String);

#[cfg(test)]
mod tests {
    use super::*;

    /// Serials are written and read with the `hex` crate: lower case out, either case in
    /// (a revocation list edited by hand), garbage refused.
    #[test]
    fn hex_round_trips_and_rejects_garbage() {
        assert_eq!(hex::encode([0, 0xab, 0x10]), "00ab10");
        assert_eq!(hex::decode("00AB10").unwrap(), vec![0, 0xab, 0x10]);
        assert!(hex::decode("abc").is_err());
        assert!(hex::decode("zz").is_err());
        assert!(hex::decode("é1").is_err());
    }

    #[test]
    fn dates_format_as_rfc3339() {
        assert_eq!(rfc3339(0), "1970-01-01T00:00:00Z");
        assert_eq!(rfc3339(1_767_225_600_999), "2026-01-01T00:00:00Z");
        // Out-of-range inputs clamp instead of panicking.
        let _ = rfc3339(i64::MAX);
        let _ = rfc3339(i64::MIN);
    }
}
