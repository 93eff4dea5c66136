//! Shared helpers for the kinetree test suite.
