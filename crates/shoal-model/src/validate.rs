//! Validation errors shared by every model type.

use std::fmt;

/// Why a datum was rejected; `reason()` is a stable short code used for counting.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ValidationError {
    /// A floating-point field held NaN or an infinity.
    #[error("{field} is not a finite number")]
    NotFinite {
        /// Field name as in `idl/shoal.idl`.
        field: &'static str,
    },
    /// A numeric field lay outside its documented range.
    #[error("{field} = {value} is outside [{min}, {max}]")]
    OutOfRange {
        /// Field name as in `idl/shoal.idl`.
        field: &'static str,
        /// The value received.
        value: f64,
        /// Smallest valid value.
        min: f64,
        /// Largest valid value.
        max: f64,
    },
    /// An identifier or text field broke its format rule.
    #[error("{field} is invalid: {rule}")]
    BadText {
        /// Field name as in `idl/shoal.idl`.
        field: &'static str,
        /// The rule that was broken.
        rule: &'static str,
    },
    /// A field combination makes no sense (e.g. a survey with two corners).
    #[error("{field}: {rule}")]
    Inconsistent {
        /// Field name as in `idl/shoal.idl`.
        field: &'static str,
        /// The rule that was broken.
        rule: &'static str,
    },
}

impl ValidationError {
    /// Stable reason code for metrics and logs, e.g. `out_of_range:latitude_deg`.
    pub fn reason(&self) -> Reason {
        match self {
            Self::NotFinite { field } => Reason::new("not_finite", field),
            Self::OutOfRange { field, .. } => Reason::new("out_of_range", field),
            Self::BadText { field, .. } => Reason::new("bad_text", field),
            Self::Inconsistent { field, .. } => Reason::new("inconsistent", field),
        }
    }
}

/// A (kind, field) pair identifying why something was rejected; cheap to copy and hash.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Reason {
    /// What went wrong (`not_finite`, `out_of_range`, ...).
    pub kind: &'static str,
    /// Which field, or `-` when the whole datum is at fault.
    pub field: &'static str,
}

impl Reason {
    /// A reason code from its parts.
    pub const fn new(kind: &'static str, field: &'static str) -> Self {
        Self { kind, field }
    }
}

impl fmt::Display for Reason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.kind, self.field)
    }
}

/// Every model type checks its own fields against the ranges documented in `idl/shoal.idl`.
pub trait Validate {
    /// Ok when every field is in range; otherwise the first violation found.
    fn validate(&self) -> Result<(), ValidationError>;
}

/// A datum that passed [`Validate`]: whoever holds one need not check it again.
///
/// The Publish/Subscribe Manager hands received samples over as `Validated<T>`, so the
/// station core neither validates twice nor can forget to.
#[derive(Debug, Clone, PartialEq)]
pub struct Validated<T>(T);

impl<T: Validate> Validated<T> {
    /// Validates `value`; on failure the value comes back beside the error.
    pub fn new(value: T) -> Result<Self, (ValidationError, T)> {
        match value.validate() {
            Ok(()) => Ok(Self(value)),
            Err(e) => Err((e, value)),
        }
    }
}

impl<T> Validated<T> {
    /// The datum itself.
    pub fn into_inner(self) -> T {
        self.0
    }
}

impl<T> std::ops::Deref for Validated<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}

impl<T> AsRef<T> for Validated<T> {
    fn as_ref(&self) -> &T {
        &self.0
    }
}

pub(crate) fn finite_in(
    field: &'static str,
    value: f64,
    min: f64,
    max: f64,
) -> Result<(), ValidationError> {
    if !value.is_finite() {
        return Err(ValidationError::NotFinite { field });
    }
    if value < min || value > max {
        return Err(ValidationError::OutOfRange {
            field,
            value,
            min,
            max,
        });
    }
    Ok(())
}

/// Like [`finite_in`] but also accepts the documented "not known" sentinel `-1`.
pub(crate) fn optional_in(
    field: &'static str,
    value: f64,
    min: f64,
    max: f64,
) -> Result<(), ValidationError> {
    if value == crate::UNKNOWN {
        return Ok(());
    }
    finite_in(field, value, min, max)
}

/// Identifiers: 1..=`max` characters of `[A-Za-z0-9_.-]`, so they are safe in
/// topic keys, SQL, IRIs and file names alike.
pub(crate) fn identifier(
    field: &'static str,
    value: &str,
    max: usize,
) -> Result<(), ValidationError> {
    if value.is_empty() {
        return Err(ValidationError::BadText {
            field,
            rule: "must not be empty",
        });
    }
    if value.len() > max {
        return Err(ValidationError::BadText {
            field,
            rule: "too long",
        });
    }
    if !value
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'))
    {
        return Err(ValidationError::BadText {
            field,
            rule: "only letters, digits, '_', '-' and '.' are allowed",
        });
    }
    Ok(())
}

/// True when `value` is a well-formed identifier of at most `max` bytes (the rule of
/// every `*_id` field), e.g. to decide whether a rejected datum's id can be trusted.
pub fn is_identifier(value: &str, max: usize) -> bool {
    identifier("id", value, max).is_ok()
}

/// Like [`identifier`] but the empty string ("none") is allowed.
pub(crate) fn optional_identifier(
    field: &'static str,
    value: &str,
    max: usize,
) -> Result<(), ValidationError> {
    if value.is_empty() {
        Ok(())
    } else {
        identifier(field, value, max)
    }
}

/// Free text: bounded length, no control characters other than tab.
pub(crate) fn text(field: &'static str, value: &str, max: usize) -> Result<(), ValidationError> {
    if value.len() > max {
        return Err(ValidationError::BadText {
            field,
            rule: "too long",
        });
    }
    if value.chars().any(|c| c.is_control() && c != '\t') {
        return Err(ValidationError::BadText {
            field,
            rule: "control characters are not allowed",
        });
    }
    Ok(())
}

/// Timestamps: milliseconds since the Unix epoch, between 2000-01-01 and 2100-01-01.
pub(crate) fn timestamp(field: &'static str, value: i64) -> Result<(), ValidationError> {
    if !(crate::MIN_TIMESTAMP_MS..=crate::MAX_TIMESTAMP_MS).contains(&value) {
        #[allow(clippy::cast_precision_loss)]
        return Err(ValidationError::OutOfRange {
            field,
            value: value as f64,
            min: crate::MIN_TIMESTAMP_MS as f64,
            max: crate::MAX_TIMESTAMP_MS as f64,
        });
    }
    Ok(())
}
