//! The one error type of the event core. Messages are one line, say what and where, and end
//! with the fix; the Python layer prefixes them with the file or argument name.

use thiserror::Error;

#[derive(Debug, Error, PartialEq)]
pub enum EventError {
    #[error(
        "arrays have different lengths (x: {x}, y: {y}, t: {t}, p: {p}); give one value per event"
    )]
    LengthMismatch {
        x: usize,
        y: usize,
        t: usize,
        p: usize,
    },
    #[error("timestamps not sorted at index {index} (t={t} < {prev}); sort them first")]
    NotSorted { index: usize, t: i64, prev: i64 },
    #[error("{axis} outside the sensor at index {index} ({axis}={value} >= {dim} {limit}); pass the right sensor size or crop the events")]
    OutsideSensor {
        axis: &'static str,
        dim: &'static str,
        index: usize,
        value: i64,
        limit: u32,
    },
    #[error("{axis} negative at index {index} ({axis}={value}); pixel coordinates start at 0")]
    Negative {
        axis: &'static str,
        index: usize,
        value: i64,
    },
    #[error("polarity {value} at index {index}; polarities must be -1/+1 or 0/1")]
    Polarity { index: usize, value: i64 },
    #[error("polarity mixes the 0/1 and -1/+1 encodings (0 and -1 both present, index {index}); use one encoding")]
    MixedPolarity { index: usize },
    #[error("{name} is not finite at index {index} ({name}={value}); remove or repair that event")]
    NotFinite {
        name: &'static str,
        index: usize,
        value: f64,
    },
    #[error("{name} is not an integer at index {index} ({name}={value}); {name} must hold whole numbers")]
    NotInteger {
        name: &'static str,
        index: usize,
        value: f64,
    },
    #[error(
        "{name} out of range at index {index} ({name}={value}); it does not fit a 64-bit integer"
    )]
    OutOfRange {
        name: &'static str,
        index: usize,
        value: f64,
    },
    #[error("sensor size {width}x{height} is invalid; width and height must be 1..=65536, area below 2^31 pixels")]
    BadSensor { width: u64, height: u64 },
    #[error("event range [{start}, {stop}) is outside the stream of {len} events; use 0 <= start <= stop <= {len}")]
    BadRange { start: i64, stop: i64, len: usize },
    #[error(
        "window of {len} events is too large to count in 32 bits; split it into smaller windows"
    )]
    TooManyEvents { len: usize },
    #[error("{name} map has {len} values for a {width}x{height} sensor; give a scalar or one value per pixel")]
    ContrastShape {
        name: &'static str,
        len: usize,
        width: u32,
        height: u32,
    },
    #[error("{name} is not finite at pixel {index} ({value}); contrast thresholds must be finite")]
    ContrastNotFinite {
        name: &'static str,
        index: usize,
        value: f32,
    },
    #[error("unknown Bayer pattern '{0}'; use RGGB, BGGR, GRBG, GBRG or mono")]
    BadPattern(String),
    #[error("unknown sampling mode '{0}'; use bilinear or nearest")]
    BadMode(String),
    #[error("{name} must be at least 1 (got {value})")]
    NotPositive { name: &'static str, value: i64 },
    #[error("sub-window bounds must be non-decreasing indices within the stream (bound {index} = {value}, stream of {len} events); build them with split_equal_count")]
    BadBounds {
        index: usize,
        value: i64,
        len: usize,
    },
    #[error("centres hold {len} values, expected 2 per centre (n*2) or 2 per centre and sub-window (n*{windows}*2)")]
    CentresShape { len: usize, windows: usize },
}
