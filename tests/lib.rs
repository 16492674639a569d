//! Shared helpers for the integration tests (paths to ../shared and built binaries).
