//! Timestamps (ms since the Unix epoch, as every topic carries them) as text.

use time::{OffsetDateTime, PrimitiveDateTime};

/// `2025-11-21T14:03:07.250Z`: UTC with milliseconds, proleptic Gregorian. It is both an
/// `xsd:dateTime` (the semantic model's literals) and ISO 8601 / RFC 3339 that spreadsheets
/// and GIS tools read without help (the console's exports).
///
/// Times beyond what the `time` crate represents (years ±9999) come out as its first or
/// last instant rather than failing: the model's own range (2000 to 2100) is far inside.
pub fn format_utc(ms: i64) -> String {
    let t = OffsetDateTime::from_unix_timestamp_nanos(i128::from(ms) * 1_000_000).unwrap_or_else(
        |_| {
            if ms < 0 {
                PrimitiveDateTime::MIN.assume_utc()
            } else {
                PrimitiveDateTime::MAX.assume_utc()
            }
        },
    );
    let year = t.year();
    // xsd:dateTime and ISO 8601 want at least four digits after a minus sign too.
    let sign = if year < 0 { "-" } else { "" };
    format!(
        "{sign}{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z",
        year.unsigned_abs(),
        u8::from(t.month()),
        t.day(),
        t.hour(),
        t.minute(),
        t.second(),
        t.millisecond()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timestamps_format_as_utc_with_milliseconds() {
        assert_eq!(format_utc(0), "1970-01-01T00:00:00.000Z");
        assert_eq!(format_utc(1_700_000_000_123), "2023-11-14T22:13:20.123Z");
        assert_eq!(format_utc(951_782_400_000), "2000-02-29T00:00:00.000Z");
        assert_eq!(format_utc(1_763_733_787_250), "2025-11-21T14:03:07.250Z");
        assert_eq!(format_utc(-1), "1969-12-31T23:59:59.999Z");
        assert_eq!(
            format_utc(crate::MAX_TIMESTAMP_MS),
            "2100-01-01T00:00:00.000Z"
        );
    }

    #[test]
    fn out_of_range_timestamps_clamp_instead_of_failing() {
        assert_eq!(format_utc(i64::MAX), "9999-12-31T23:59:59.999Z");
        assert_eq!(format_utc(i64::MIN), "-9999-01-01T00:00:00.000Z");
    }
}
