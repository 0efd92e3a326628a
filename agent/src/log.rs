//! One line per event on stderr: `2026-11-21T10:15:02.123Z WARN message`. Unbuffered, so a
//! line is out before the process can die, and a supervisor (systemd, a robot cell's process
//! manager) timestamps and stores it as it likes.

use std::fmt::Arguments;
use std::io::Write;
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

/// How serious a log line is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
#[repr(u8)]
pub enum Level {
    /// What the agent is doing.
    Info,
    /// Something went wrong and was handled (an input dropped, a queue full).
    Warn,
    /// The agent cannot go on as asked.
    Error,
}

/// Lines below this level are not written (a [`Level`] as `u8`).
static MIN_LEVEL: AtomicU8 = AtomicU8::new(Level::Info as u8);

/// Writes lines at `level` and above only, for the whole process; returns the level before.
/// A library that runs the lifecycle for its caller (reading a recording back from Python)
/// keeps its progress lines to itself this way, and its warnings still show.
pub fn set_min_level(level: Level) -> Level {
    match MIN_LEVEL.swap(level as u8, Ordering::Relaxed) {
        0 => Level::Info,
        1 => Level::Warn,
        _ => Level::Error,
    }
}

/// Writes one line at `level`, timestamped.
pub fn line(level: Level, args: Arguments<'_>) {
    if (level as u8) < MIN_LEVEL.load(Ordering::Relaxed) {
        return;
    }
    let name = match level {
        Level::Info => "INFO ",
        Level::Warn => "WARN ",
        Level::Error => "ERROR",
    };
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "{} {name} {args}", utc_now());
}

/// ISO 8601 UTC with milliseconds, from the civil-from-days algorithm (H. Hinnant).
fn utc_now() -> String {
    let d = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default();
    let secs = d.as_secs() as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}.{:03}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60,
        d.subsec_millis()
    )
}

/// Logs a line at [`log::Level::Info`](crate::log::Level::Info), `format!`-style.
#[macro_export]
macro_rules! info {
    ($($t:tt)*) => { $crate::log::line($crate::log::Level::Info, format_args!($($t)*)) };
}

/// Logs a line at [`log::Level::Warn`](crate::log::Level::Warn), `format!`-style.
#[macro_export]
macro_rules! warn {
    ($($t:tt)*) => { $crate::log::line($crate::log::Level::Warn, format_args!($($t)*)) };
}

/// Logs a line at [`log::Level::Error`](crate::log::Level::Error), `format!`-style.
#[macro_export]
macro_rules! error {
    ($($t:tt)*) => { $crate::log::line($crate::log::Level::Error, format_args!($($t)*)) };
}
