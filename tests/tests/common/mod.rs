//! The harness moved to the `cangate-tests` library (`tests/src/lib.rs`);
//! this module re-exports it for the test files that still include it with
//! `mod common;` (new tests write `use cangate_tests::*;`).

pub use cangate_tests::*;
