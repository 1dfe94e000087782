//! Validation at the boundary (lengths, sorted time, sensor bounds, polarity), safe casts from
//! other dtypes, and index windows (by time, by count, equal-count splits).

use std::borrow::Cow;
use std::ops::Range;

use rayon::prelude::*;

use crate::error::EventError;

/// Sensor size in pixels. Coordinates are u16, so each side is at most 65536; the area stays
/// below 2^31 pixels so that per-polarity count indices fit u32.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sensor {
    pub width: u32,
    pub height: u32,
}

impl Sensor {
    pub fn new(width: u64, height: u64) -> Result<Self, EventError> {
        let ok = |v: u64| (1..=65536).contains(&v);
        if !ok(width) || !ok(height) || width * height >= 1 << 31 {
            return Err(EventError::BadSensor { width, height });
        }
        Ok(Self {
            width: width as u32,
            height: height as u32,
        })
    }

    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// Events of one sensor (equal-length x, y, p). Coordinates are checked by every pass
/// before it indexes with them: the counting loop checks each block as it computes the block's
/// pixel indices (no extra pass over memory), other passes call [`EventSlice::check_inside`].
/// Polarity is read as `p < 0` → negative, so any i8 is safe.
#[derive(Clone, Copy, Debug)]
pub struct EventSlice<'a> {
    x: &'a [u16],
    y: &'a [u16],
    p: &'a [i8],
    sensor: Sensor,
}

impl<'a> EventSlice<'a> {
    /// Checks equal lengths.
    pub fn new(
        x: &'a [u16],
        y: &'a [u16],
        p: &'a [i8],
        sensor: Sensor,
    ) -> Result<Self, EventError> {
        if x.len() != y.len() || x.len() != p.len() {
            return Err(EventError::LengthMismatch {
                x: x.len(),
                y: y.len(),
                t: x.len(),
                p: p.len(),
            });
        }
        Ok(Self { x, y, p, sensor })
    }

    /// Checks that every coordinate lies inside the sensor (first bad x, then first bad y).
    pub fn check_inside(&self) -> Result<(), EventError> {
        check_below(self.x, "x", "width", self.sensor.width)?;
        check_below(self.y, "y", "height", self.sensor.height)
    }

    /// The error for event `index`, known to lie outside the sensor.
    pub(crate) fn outside_error(&self, index: usize) -> EventError {
        let (x, y) = (self.x[index], self.y[index]);
        let (axis, dim, value, limit) = if u32::from(x) >= self.sensor.width {
            ("x", "width", x, self.sensor.width)
        } else {
            ("y", "height", y, self.sensor.height)
        };
        EventError::OutsideSensor {
            axis,
            dim,
            index,
            value: i64::from(value),
            limit,
        }
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    pub fn sensor(&self) -> Sensor {
        self.sensor
    }

    /// Sub-range `[start, stop)`.
    pub fn range(&self, start: usize, stop: usize) -> Self {
        Self {
            x: &self.x[start..stop],
            y: &self.y[start..stop],
            p: &self.p[start..stop],
            sensor: self.sensor,
        }
    }

    pub(crate) fn parts(&self) -> (&'a [u16], &'a [u16], &'a [i8]) {
        (self.x, self.y, self.p)
    }
}

/// Elements per parallel task in the validation scans.
const SCAN_CHUNK: usize = 1 << 16;

/// Scans of fewer elements run on the calling thread: waking rayon's workers costs more than
/// they save there, and on a CPU Vulkan adapter those workers compete with the renderer's for
/// the same cores (a training step validates windows of ~10^5 events while it renders).
const PAR_MIN_SCAN: usize = 1 << 20;

/// First index where `bad` holds. Each chunk is first tested with a branch-free OR (which
/// vectorises); only a failing chunk is searched element by element.
pub(crate) fn first_index<T: Sync>(v: &[T], bad: impl Fn(&T) -> bool + Sync) -> Option<usize> {
    first_in_chunks(v.len(), |r| {
        let c = &v[r];
        let any = c.iter().fold(false, |acc, a| acc | bad(a));
        any.then(|| c.iter().position(&bad)).flatten()
    })
}

/// The least index that `find` reports in the chunks of `SCAN_CHUNK` indices of `0..len` (it
/// gets a chunk's range and returns an offset inside it): on the calling thread below
/// `PAR_MIN_SCAN`, else on rayon's workers.
fn first_in_chunks(
    len: usize,
    find: impl Fn(Range<usize>) -> Option<usize> + Sync,
) -> Option<usize> {
    let in_chunk = |start: usize| find(start..(start + SCAN_CHUNK).min(len)).map(|i| start + i);
    if len < PAR_MIN_SCAN {
        return (0..len).step_by(SCAN_CHUNK).find_map(in_chunk);
    }
    (0..len.div_ceil(SCAN_CHUNK))
        .into_par_iter()
        .filter_map(|c| in_chunk(c * SCAN_CHUNK))
        .min()
}

fn check_below(
    v: &[u16],
    axis: &'static str,
    dim: &'static str,
    limit: u32,
) -> Result<(), EventError> {
    let Some(index) = first_index(v, |&a| u32::from(a) >= limit) else {
        return Ok(());
    };
    Err(EventError::OutsideSensor {
        axis,
        dim,
        index,
        value: i64::from(v[index]),
        limit,
    })
}

/// Full validation of a stream in canonical dtypes: lengths, sensor bounds, sorted time and
/// polarity values (±1 or 0/1). Returns the polarity mapped to ±1 when it used 0/1.
pub fn validate<'a>(
    x: &[u16],
    y: &[u16],
    t: &[i64],
    p: &'a [i8],
    sensor: Sensor,
) -> Result<Cow<'a, [i8]>, EventError> {
    if x.len() != y.len() || x.len() != t.len() || x.len() != p.len() {
        return Err(EventError::LengthMismatch {
            x: x.len(),
            y: y.len(),
            t: t.len(),
            p: p.len(),
        });
    }
    check_below(x, "x", "width", sensor.width)?;
    check_below(y, "y", "height", sensor.height)?;
    check_sorted(t)?;
    polarity_to_pm1(p)
}

/// First index where time decreases, as an error.
pub fn check_sorted(t: &[i64]) -> Result<(), EventError> {
    let Some((next, prev)) = t.get(1..).zip(t.get(..t.len().saturating_sub(1))) else {
        return Ok(());
    };
    // Pairs (t[i+1], t[i]) compared chunk by chunk, as in `first_index`.
    let bad = first_in_chunks(next.len(), |r| {
        let (a, b) = (&next[r.clone()], &prev[r]);
        let any = a.iter().zip(b).fold(false, |acc, (x, y)| acc | (x < y));
        any.then(|| a.iter().zip(b).position(|(x, y)| x < y))
            .flatten()
    });
    match bad {
        None => Ok(()),
        Some(i) => Err(EventError::NotSorted {
            index: i + 1,
            t: t[i + 1],
            prev: t[i],
        }),
    }
}

/// How a stream encodes polarity.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Encoding {
    PlusMinus,
    ZeroOne,
}

/// Checks that polarities are all in {-1, +1} or all in {0, 1}; anything else, or a mix of 0
/// and -1, is an error at its first index.
fn polarity_encoding<T: Copy + Into<i64> + Sync>(p: &[T]) -> Result<Encoding, EventError> {
    if let Some(index) = first_index(p, |&v| !matches!(v.into(), -1..=1)) {
        return Err(EventError::Polarity {
            index,
            value: p[index].into(),
        });
    }
    let first_zero = first_index(p, |&v| v.into() == 0);
    let first_neg = first_index(p, |&v| v.into() == -1);
    match (first_zero, first_neg) {
        (Some(z), Some(n)) => Err(EventError::MixedPolarity { index: z.max(n) }),
        (Some(_), None) => Ok(Encoding::ZeroOne),
        (None, _) => Ok(Encoding::PlusMinus),
    }
}

fn to_pm1(v: i64, enc: Encoding) -> i8 {
    match (enc, v) {
        (Encoding::ZeroOne, 0) => -1,
        (Encoding::ZeroOne, _) => 1,
        (Encoding::PlusMinus, v) => v as i8,
    }
}

/// Polarities as ±1: a {-1,+1} stream is returned as is (borrowed), a {0,1} one mapped.
pub fn polarity_to_pm1(p: &[i8]) -> Result<Cow<'_, [i8]>, EventError> {
    Ok(match polarity_encoding(p)? {
        Encoding::PlusMinus => Cow::Borrowed(p),
        enc => Cow::Owned(p.par_iter().map(|&v| to_pm1(v.into(), enc)).collect()),
    })
}

/// Polarities given as i64 (any integer input), checked and mapped to ±1 as i8.
pub fn polarity_from_i64(p: &[i64]) -> Result<Vec<i8>, EventError> {
    let enc = polarity_encoding(p)?;
    Ok(p.par_iter().map(|&v| to_pm1(v, enc)).collect())
}

/// Casts float values to i64, refusing NaN/inf, fractions and values beyond i64.
pub fn float_to_i64(v: &[f64], name: &'static str) -> Result<Vec<i64>, EventError> {
    let bad = first_index(v, |&a| {
        !a.is_finite() || a.fract() != 0.0 || !(-9.2e18..=9.2e18).contains(&a)
    });
    if let Some(index) = bad {
        let value = v[index];
        return Err(if !value.is_finite() {
            EventError::NotFinite { name, index, value }
        } else if value.fract() != 0.0 {
            EventError::NotInteger { name, index, value }
        } else {
            EventError::OutOfRange { name, index, value }
        });
    }
    Ok(v.par_iter().map(|&a| a as i64).collect())
}

/// Casts i64 coordinates to u16, checking `0 <= v < limit`.
pub fn coords_to_u16(
    v: &[i64],
    axis: &'static str,
    dim: &'static str,
    limit: u32,
) -> Result<Vec<u16>, EventError> {
    if let Some(index) = first_index(v, |&a| a < 0 || a >= i64::from(limit)) {
        let value = v[index];
        return Err(if value < 0 {
            EventError::Negative { axis, index, value }
        } else {
            EventError::OutsideSensor {
                axis,
                dim,
                index,
                value,
                limit,
            }
        });
    }
    Ok(v.par_iter().map(|&a| a as u16).collect())
}

/// Checks `0 <= start <= stop <= len`.
pub fn check_range(start: i64, stop: i64, len: usize) -> Result<(usize, usize), EventError> {
    if start < 0 || stop < start || stop as u64 > len as u64 {
        return Err(EventError::BadRange { start, stop, len });
    }
    Ok((start as usize, stop as usize))
}

/// Index range `[i0, i1)` of the events with `t0 <= t < t1` (binary search on sorted `t`).
/// An inverted window (`t1 < t0`) is empty.
pub fn window_by_time(t: &[i64], t0: i64, t1: i64) -> (usize, usize) {
    let i0 = t.partition_point(|&v| v < t0);
    let i1 = t.partition_point(|&v| v < t1).max(i0);
    (i0, i1)
}

/// Index range of `count` events from `start`, clipped to the stream.
pub fn window_by_count(len: usize, start: i64, count: i64) -> Result<(usize, usize), EventError> {
    if count < 0 {
        return Err(EventError::NotPositive {
            name: "count",
            value: count,
        });
    }
    let s = start.clamp(0, len as i64) as usize;
    let e = (s as u64).saturating_add(count as u64).min(len as u64) as usize;
    Ok((s, e))
}

/// `m + 1` boundaries splitting `[i0, i1)` into `m` sub-windows whose event counts differ by
/// at most one (`b_k = i0 + floor(k * n / m)`).
pub fn split_equal_count(i0: usize, i1: usize, m: usize) -> Result<Vec<i64>, EventError> {
    if m == 0 {
        return Err(EventError::NotPositive {
            name: "m",
            value: 0,
        });
    }
    let n = (i1 - i0) as u128;
    Ok((0..=m)
        .map(|k| (i0 as u128 + k as u128 * n / m as u128) as i64)
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sensor() -> Sensor {
        Sensor::new(4, 3).unwrap()
    }

    #[test]
    fn validate_reports_first_unsorted_index() {
        let e = validate(&[0, 1, 2], &[0, 0, 0], &[5, 7, 6], &[1, 1, 1], sensor()).unwrap_err();
        assert_eq!(
            e,
            EventError::NotSorted {
                index: 2,
                t: 6,
                prev: 7
            }
        );
        assert!(e.to_string().contains("index 2 (t=6 < 7)"));
    }

    /// Below and above PAR_MIN_SCAN (on the calling thread and on rayon's workers), with bad
    /// elements planted in two chunks: the scans report the first one.
    #[test]
    fn scans_report_the_first_bad_index_at_any_length() {
        for len in [PAR_MIN_SCAN - 1, PAR_MIN_SCAN + 5 * SCAN_CHUNK] {
            let first = len - 3 * SCAN_CHUNK + 7;
            let mut x = vec![0u16; len];
            x[first] = 4;
            x[len - 2] = 9;
            assert_eq!(first_index(&x, |&v| v >= 4), Some(first));
            let mut t: Vec<i64> = (0..len as i64).collect();
            t[first] = -1;
            t[len - 2] = -1;
            assert_eq!(
                check_sorted(&t),
                Err(EventError::NotSorted {
                    index: first,
                    t: -1,
                    prev: first as i64 - 1
                })
            );
        }
    }

    #[test]
    fn validate_reports_coordinates_outside_sensor() {
        let e = validate(&[0, 4], &[0, 0], &[0, 1], &[1, 1], sensor()).unwrap_err();
        assert!(matches!(
            e,
            EventError::OutsideSensor {
                axis: "x",
                index: 1,
                value: 4,
                ..
            }
        ));
        let e = validate(&[0, 0], &[3, 0], &[0, 1], &[1, 1], sensor()).unwrap_err();
        assert!(matches!(
            e,
            EventError::OutsideSensor {
                axis: "y",
                index: 0,
                ..
            }
        ));
    }

    #[test]
    fn polarity_zero_one_maps_to_minus_plus_one() {
        assert_eq!(
            polarity_to_pm1(&[0i8, 1, 0]).unwrap().as_ref(),
            &[-1, 1, -1]
        );
        assert!(matches!(
            polarity_to_pm1(&[1i8, -1]).unwrap(),
            Cow::Borrowed(_)
        ));
        assert_eq!(
            polarity_from_i64(&[1, 3]).unwrap_err(),
            EventError::Polarity { index: 1, value: 3 }
        );
        assert_eq!(
            polarity_to_pm1(&[0i8, -1]).unwrap_err(),
            EventError::MixedPolarity { index: 1 }
        );
    }

    #[test]
    fn float_casts_refuse_nan_and_fractions() {
        assert_eq!(float_to_i64(&[1.0, 2.0], "x").unwrap(), vec![1, 2]);
        assert!(matches!(
            float_to_i64(&[1.0, f64::NAN], "x"),
            Err(EventError::NotFinite { index: 1, .. })
        ));
        assert!(matches!(
            float_to_i64(&[1.5], "x"),
            Err(EventError::NotInteger { index: 0, .. })
        ));
        assert!(matches!(
            coords_to_u16(&[0, -1], "y", "height", 3),
            Err(EventError::Negative { index: 1, .. })
        ));
    }

    #[test]
    fn windows_by_time_are_half_open() {
        let t = [1, 2, 2, 5, 9];
        assert_eq!(window_by_time(&t, 2, 5), (1, 3));
        assert_eq!(window_by_time(&t, 0, 100), (0, 5));
        assert_eq!(window_by_time(&t, 6, 3), (4, 4));
        assert_eq!(window_by_count(5, 3, 10).unwrap(), (3, 5));
    }

    #[test]
    fn equal_count_split_differs_by_at_most_one() {
        let b = split_equal_count(3, 13, 3).unwrap();
        assert_eq!(b, vec![3, 6, 9, 13]);
        let sizes: Vec<i64> = b.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(sizes.iter().max().unwrap() - sizes.iter().min().unwrap() <= 1);
        assert_eq!(split_equal_count(0, 0, 2).unwrap(), vec![0, 0, 0]);
    }
}
