//! Per-pixel accumulation: polarity counts (one pass, integer, parallel), and from them the
//! event single integral (ESI), event counts, event masks and the Bayer-channel split.
//!
//! Counting in u32 and applying the contrast thresholds per pixel afterwards makes every
//! result exact and independent of thread count and event order (a 10 M-event flood of one
//! pixel is one multiplication, not 10 M float additions).

use rayon::prelude::*;

use crate::error::EventError;
use crate::stream::{EventSlice, Sensor};

/// Windows shorter than this are counted on one thread (partial images would cost more).
const PAR_MIN_EVENTS: usize = 1 << 17;

/// Per-pixel `[positive, negative]` event counts, interleaved: `counts[2*pix + (p < 0)]`.
pub struct PolarityCounts {
    pub counts: Vec<u32>,
    pub sensor: Sensor,
}

fn count_into(counts: &mut [u32], ev: &EventSlice) {
    let (x, y, p) = ev.parts();
    let w = ev.sensor().width as usize;
    debug_assert_eq!(counts.len(), 2 * ev.sensor().pixels());
    for ((&xi, &yi), &pi) in x.iter().zip(y).zip(p) {
        let k = 2 * (yi as usize * w + xi as usize) + usize::from(pi < 0);
        // SAFETY: EventSlice guarantees x < width and y < height, so k < 2 * width * height.
        unsafe { *counts.get_unchecked_mut(k) += 1 };
    }
}

/// Counts events per pixel and polarity. Large windows are split into one chunk per thread,
/// each counted into its own image, then summed (integers: the order does not matter).
pub fn polarity_counts(ev: &EventSlice) -> Result<PolarityCounts, EventError> {
    if ev.len() > u32::MAX as usize {
        return Err(EventError::TooManyEvents { len: ev.len() });
    }
    let sensor = ev.sensor();
    let len = 2 * sensor.pixels();
    let threads = rayon::current_num_threads();
    if threads == 1 || ev.len() < PAR_MIN_EVENTS {
        let mut counts = vec![0u32; len];
        count_into(&mut counts, ev);
        return Ok(PolarityCounts { counts, sensor });
    }
    let chunk = ev.len().div_ceil(threads);
    let mut partials: Vec<Vec<u32>> = (0..threads)
        .into_par_iter()
        .map(|c| {
            let mut counts = vec![0u32; len];
            let start = (c * chunk).min(ev.len());
            count_into(&mut counts, &ev.range(start, (start + chunk).min(ev.len())));
            counts
        })
        .collect();
    let mut counts = partials.swap_remove(0);
    counts
        .par_chunks_mut(1 << 14)
        .enumerate()
        .for_each(|(ci, out)| {
            let off = ci << 14;
            for part in &partials {
                for (o, &v) in out.iter_mut().zip(&part[off..off + len]) {
                    *o += v;
                }
            }
        });
    Ok(PolarityCounts { counts, sensor })
}

/// A contrast threshold: one value for the sensor or one per pixel (row-major H×W).
#[derive(Clone, Copy, Debug)]
pub enum Threshold<'a> {
    Scalar(f32),
    Map(&'a [f32]),
}

impl Threshold<'_> {
    /// Checks the map size and that every value is finite.
    pub fn check(&self, name: &'static str, sensor: Sensor) -> Result<(), EventError> {
        let bad = |index: usize, value: f32| EventError::ContrastNotFinite { name, index, value };
        match *self {
            Threshold::Scalar(v) if !v.is_finite() => Err(bad(0, v)),
            Threshold::Scalar(_) => Ok(()),
            Threshold::Map(m) if m.len() != sensor.pixels() => Err(EventError::ContrastShape {
                name,
                len: m.len(),
                width: sensor.width,
                height: sensor.height,
            }),
            Threshold::Map(m) => match m.par_iter().position_first(|v| !v.is_finite()) {
                Some(i) => Err(bad(i, m[i])),
                None => Ok(()),
            },
        }
    }

    #[inline]
    fn at(&self, pix: usize) -> f64 {
        match *self {
            Threshold::Scalar(v) => f64::from(v),
            Threshold::Map(m) => f64::from(m[pix]),
        }
    }
}

/// Positive and negative contrast thresholds C+ and C-.
#[derive(Clone, Copy, Debug)]
pub struct Contrast<'a> {
    pub pos: Threshold<'a>,
    pub neg: Threshold<'a>,
}

impl Contrast<'_> {
    pub fn check(&self, sensor: Sensor) -> Result<(), EventError> {
        self.pos.check("c_pos", sensor)?;
        self.neg.check("c_neg", sensor)
    }
}

impl PolarityCounts {
    /// ESI per pixel: `C+ * n+ - C- * n-`, evaluated in f64 and rounded once to f32.
    /// The contrast must have passed [`Contrast::check`] for this sensor.
    pub fn esi(&self, c: &Contrast) -> Vec<f32> {
        self.counts
            .par_chunks(2)
            .enumerate()
            .map(|(pix, n)| {
                (c.pos.at(pix) * f64::from(n[0]) - c.neg.at(pix) * f64::from(n[1])) as f32
            })
            .collect()
    }

    /// Events per pixel, both polarities.
    pub fn total(&self) -> Vec<u32> {
        self.counts.par_chunks(2).map(|n| n[0] + n[1]).collect()
    }

    /// True where at least one event fired.
    pub fn mask(&self) -> Vec<bool> {
        self.counts.par_chunks(2).map(|n| n[0] + n[1] > 0).collect()
    }
}

/// Colour filter layouts: the channel (0=R, 1=G, 2=B) of each pixel of the 2×2 tile in
/// row-major order, or a single channel for monochrome sensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bayer {
    Mono,
    Tile([u8; 4]),
}

impl Bayer {
    pub fn parse(name: &str) -> Result<Self, EventError> {
        let tile = |s: &str| -> [u8; 4] {
            let mut out = [0u8; 4];
            for (o, c) in out.iter_mut().zip(s.bytes()) {
                *o = match c {
                    b'R' => 0,
                    b'G' => 1,
                    _ => 2,
                };
            }
            out
        };
        match name.to_ascii_uppercase().as_str() {
            "MONO" => Ok(Bayer::Mono),
            p @ ("RGGB" | "BGGR" | "GRBG" | "GBRG") => Ok(Bayer::Tile(tile(p))),
            _ => Err(EventError::BadPattern(name.to_string())),
        }
    }

    pub fn channels(&self) -> usize {
        match self {
            Bayer::Mono => 1,
            Bayer::Tile(_) => 3,
        }
    }

    /// Channel index of every pixel, row-major H×W.
    pub fn channel_map(&self, sensor: Sensor) -> Vec<u8> {
        let w = sensor.width as usize;
        (0..sensor.pixels())
            .into_par_iter()
            .map(|pix| match self {
                Bayer::Mono => 0,
                Bayer::Tile(t) => t[((pix / w) % 2) * 2 + (pix % w) % 2],
            })
            .collect()
    }

    /// Splits a per-pixel image into C×H×W planes: each pixel lands in its own channel only.
    pub fn split(&self, image: &[f32], sensor: Sensor) -> Vec<f32> {
        let map = self.channel_map(sensor);
        let pixels = sensor.pixels();
        let mut out = vec![0f32; self.channels() * pixels];
        out.par_chunks_mut(pixels)
            .enumerate()
            .for_each(|(c, plane)| {
                for ((o, &v), &ch) in plane.iter_mut().zip(image).zip(&map) {
                    if usize::from(ch) == c {
                        *o = v;
                    }
                }
            });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn esi_sums_contrast_times_polarity_per_pixel() {
        let sensor = Sensor::new(3, 2).unwrap();
        let (x, y, p) = ([0u16, 0, 2, 2, 1], [0u16, 0, 1, 1, 1], [1i8, 1, -1, 1, -1]);
        let ev = EventSlice::new(&x, &y, &p, sensor).unwrap();
        let counts = polarity_counts(&ev).unwrap();
        let c = Contrast {
            pos: Threshold::Scalar(0.5),
            neg: Threshold::Scalar(0.25),
        };
        assert_eq!(counts.esi(&c), vec![1.0, 0.0, 0.0, 0.0, -0.25, 0.25]);
        assert_eq!(counts.total(), vec![2, 0, 0, 0, 1, 2]);
        assert_eq!(counts.mask(), vec![true, false, false, false, true, true]);
    }

    #[test]
    fn parallel_counts_equal_sequential_counts() {
        let sensor = Sensor::new(7, 5).unwrap();
        let n = 3 * PAR_MIN_EVENTS + 11;
        let x: Vec<u16> = (0..n).map(|i| (i * 7919 % 7) as u16).collect();
        let y: Vec<u16> = (0..n).map(|i| (i * 104729 % 5) as u16).collect();
        let p: Vec<i8> = (0..n).map(|i| if i % 3 == 0 { -1 } else { 1 }).collect();
        let ev = EventSlice::new(&x, &y, &p, sensor).unwrap();
        let mut seq = vec![0u32; 2 * sensor.pixels()];
        count_into(&mut seq, &ev);
        assert_eq!(polarity_counts(&ev).unwrap().counts, seq);
    }

    #[test]
    fn bayer_maps_follow_the_pattern_name() {
        let sensor = Sensor::new(2, 2).unwrap();
        assert_eq!(
            Bayer::parse("RGGB").unwrap().channel_map(sensor),
            vec![0, 1, 1, 2]
        );
        assert_eq!(
            Bayer::parse("gbrg").unwrap().channel_map(sensor),
            vec![1, 2, 0, 1]
        );
        assert_eq!(
            Bayer::parse("mono").unwrap().channel_map(sensor),
            vec![0; 4]
        );
        assert!(Bayer::parse("RGB").is_err());
    }

    #[test]
    fn contrast_maps_are_checked() {
        let sensor = Sensor::new(2, 1).unwrap();
        assert!(Threshold::Map(&[1.0]).check("c_pos", sensor).is_err());
        assert!(Threshold::Map(&[1.0, f32::NAN])
            .check("c_pos", sensor)
            .is_err());
        assert!(Threshold::Scalar(0.2).check("c_pos", sensor).is_ok());
    }
}
