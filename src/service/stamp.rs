//! Time stamps and ids of the records the service keeps.

/// Current time, RFC 3339 UTC with microsecond precision.
pub fn now_rfc3339() -> String {
    let now = time::OffsetDateTime::now_utc();
    let now = now
        .replace_nanosecond(now.nanosecond() / 1_000 * 1_000)
        .unwrap_or(now);
    now.format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_else(|_| "1970-01-01T00:00:00Z".into())
}

/// A new opaque id with a one-letter kind prefix (`s_…`, `c_…`). UUIDv7:
/// ids sort in creation order, which lists use to break ties of equal
/// timestamps.
pub fn new_id(prefix: &str) -> String {
    format!("{prefix}_{}", uuid::Uuid::now_v7().simple())
}
