//! Integration tests of shoal-security, built as one test binary.
//!
//! Where tests go:
//! - `attack_corpus`: the generated attack corpus on acoustic frames, interleaved with
//!   legitimate traffic; every attack refused, every legitimate frame accepted, refusals
//!   counted by reason. (IP links run DDS Security; their corpus is `tests/security/`.)

// A panic is how a test fails; helpers outside #[test] functions may unwrap too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod attack_corpus;
