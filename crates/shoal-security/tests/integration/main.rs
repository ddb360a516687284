//! Integration tests of shoal-security, built as one test binary.
//!
//! Where tests go:
//! - `attack_corpus`: the generated attack corpus (signed envelopes and acoustic frames)
//!   interleaved with legitimate traffic; every attack refused, every legitimate message
//!   accepted, refusals counted by reason.

// A panic is how a test fails; helpers outside #[test] functions may unwrap too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod attack_corpus;
