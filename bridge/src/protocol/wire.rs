//! The wire format's fixed numbers.

/// Bumped on every incompatible change; requests with another `v` get `version_mismatch`.
pub const PROTOCOL_VERSION: u16 = 1;

/// Largest request payload the engine decodes (64 MiB, e.g. a `step_batch` of 1M
/// two-dimensional actions is 16 MiB).
pub const MAX_REQUEST_BYTES: usize = 64 << 20;

/// Length of a session's secret token.
pub const TOKEN_BYTES: usize = 16;
