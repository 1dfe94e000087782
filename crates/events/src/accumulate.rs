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

/// Events per block of the counting loop: their count indices are computed first (a loop
/// that vectorises), then scattered (the part that cannot).
const BLOCK: usize = 1024;

/// Calls `visit` with the count indices `2 * pixel + (p < 0)` of each block of events. Each
/// block's coordinates are checked while its indices are computed, so every index passed to
/// `visit` is below `2 * width * height`. On failure returns the index of the first event
/// outside the sensor (what `visit` accumulated is then partial and must be dropped).
fn for_each_block(ev: &EventSlice, mut visit: impl FnMut(&[u32])) -> Result<(), usize> {
    let (x, y, p) = ev.parts();
    let Sensor {
        width: w,
        height: h,
    } = ev.sensor();
    let mut idx = [0u32; BLOCK];
    for (b, ((xb, yb), pb)) in x
        .chunks(BLOCK)
        .zip(y.chunks(BLOCK))
        .zip(p.chunks(BLOCK))
        .enumerate()
    {
        let mut inside = true;
        for (((k, &xi), &yi), &pi) in idx.iter_mut().zip(xb).zip(yb).zip(pb) {
            let (xi, yi) = (u32::from(xi), u32::from(yi));
            inside &= (xi < w) & (yi < h);
            // Fits u32: Sensor::new caps the sensor below 2^31 pixels.
            *k = 2 * (yi.wrapping_mul(w).wrapping_add(xi)) + u32::from(pi < 0);
        }
        if !inside {
            let i = xb
                .iter()
                .zip(yb)
                .position(|(&a, &b)| u32::from(a) >= w || u32::from(b) >= h);
            return Err(b * BLOCK + i.unwrap_or(0));
        }
        visit(&idx[..xb.len()]);
    }
    Ok(())
}

/// Adds the events' counts into `counts` (length `2 * pixels`, interleaved polarities).
fn count_into(counts: &mut [u32], ev: &EventSlice) -> Result<(), usize> {
    assert_eq!(counts.len(), 2 * ev.sensor().pixels());
    for_each_block(ev, |idx| {
        for &k in idx {
            // SAFETY: for_each_block passes only k < 2 * pixels = counts.len().
            unsafe { *counts.get_unchecked_mut(k as usize) += 1 };
        }
    })
}

/// Marks the pixels of the events in `mask` (length `pixels`): a quarter of the memory of
/// the counts, so a mask alone is cheaper than counting.
fn mask_into(mask: &mut [bool], ev: &EventSlice) -> Result<(), usize> {
    assert_eq!(mask.len(), ev.sensor().pixels());
    for_each_block(ev, |idx| {
        for &k in idx {
            // SAFETY: for_each_block passes only k < 2 * pixels, so k / 2 < mask.len().
            unsafe { *mask.get_unchecked_mut((k >> 1) as usize) = true };
        }
    })
}

/// Accumulates per-pixel values of `len` elements: on one thread for short windows, else one
/// chunk of events per thread into its own image, merged element-wise with `merge` (integer or
/// boolean, so the result does not depend on the split).
fn accumulate_parallel<T: Copy + Default + Send + Sync>(
    ev: &EventSlice,
    len: usize,
    fill: impl Fn(&mut [T], &EventSlice) -> Result<(), usize> + Sync,
    merge: impl Fn(&mut T, T) + Sync,
) -> Result<Vec<T>, EventError> {
    if ev.len() > u32::MAX as usize {
        return Err(EventError::TooManyEvents { len: ev.len() });
    }
    let threads = rayon::current_num_threads();
    if threads == 1 || ev.len() < PAR_MIN_EVENTS {
        let mut out = vec![T::default(); len];
        fill(&mut out, ev).map_err(|i| ev.outside_error(i))?;
        return Ok(out);
    }
    let chunk = ev.len().div_ceil(threads);
    let mut partials = (0..threads)
        .into_par_iter()
        .map(|c| {
            let mut out = vec![T::default(); len];
            let start = (c * chunk).min(ev.len());
            let part = ev.range(start, (start + chunk).min(ev.len()));
            fill(&mut out, &part).map_err(|i| start + i)?;
            Ok(out)
        })
        .collect::<Vec<Result<Vec<T>, usize>>>()
        .into_iter()
        // The first chunk's error is the first bad event of the window.
        .collect::<Result<Vec<_>, usize>>()
        .map_err(|i| ev.outside_error(i))?;
    let mut out = partials.swap_remove(0);
    out.par_chunks_mut(1 << 14).enumerate().for_each(|(ci, o)| {
        let (off, n) = (ci << 14, o.len());
        for part in &partials {
            for (a, &b) in o.iter_mut().zip(&part[off..off + n]) {
                merge(a, b);
            }
        }
    });
    Ok(out)
}

/// Counts events per pixel and polarity (coordinates outside the sensor are an error naming
/// the first one).
pub fn polarity_counts(ev: &EventSlice) -> Result<PolarityCounts, EventError> {
    let sensor = ev.sensor();
    let counts = accumulate_parallel(ev, 2 * sensor.pixels(), count_into, |a, b| *a += b)?;
    Ok(PolarityCounts { counts, sensor })
}

/// True where at least one event fired (row-major H×W), without counting.
pub fn event_mask(ev: &EventSlice) -> Result<Vec<bool>, EventError> {
    accumulate_parallel(ev, ev.sensor().pixels(), mask_into, |a, b| *a |= b)
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
            Threshold::Map(m) => match crate::stream::first_index(m, |v| !v.is_finite()) {
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

/// Pixels per parallel task when turning counts into images.
const PIXEL_CHUNK: usize = 1 << 13;

impl PolarityCounts {
    /// `f(pixel, n_pos, n_neg)` for every pixel, in parallel chunks of plain loops (which the
    /// compiler vectorises when `f` ignores the pixel index).
    fn per_pixel<T: Copy + Default + Send>(
        &self,
        f: impl Fn(usize, u32, u32) -> T + Sync,
    ) -> Vec<T> {
        let mut out = vec![T::default(); self.sensor.pixels()];
        out.par_chunks_mut(PIXEL_CHUNK)
            .zip(self.counts.par_chunks(2 * PIXEL_CHUNK))
            .enumerate()
            .for_each(|(ci, (o, n))| {
                for (i, (o, n)) in o.iter_mut().zip(n.chunks_exact(2)).enumerate() {
                    *o = f(ci * PIXEL_CHUNK + i, n[0], n[1]);
                }
            });
        out
    }

    /// ESI per pixel: `C+ * n+ - C- * n-`, evaluated in f64 and rounded once to f32.
    /// The contrast must have passed [`Contrast::check`] for this sensor.
    pub fn esi(&self, c: &Contrast) -> Vec<f32> {
        let esi =
            |cp: f64, cn: f64, np: u32, nn: u32| (cp * f64::from(np) - cn * f64::from(nn)) as f32;
        match (c.pos, c.neg) {
            (Threshold::Scalar(a), Threshold::Scalar(b)) => {
                let (a, b) = (f64::from(a), f64::from(b));
                self.per_pixel(|_, np, nn| esi(a, b, np, nn))
            }
            _ => self.per_pixel(|pix, np, nn| esi(c.pos.at(pix), c.neg.at(pix), np, nn)),
        }
    }

    /// Events per pixel, both polarities.
    pub fn total(&self) -> Vec<u32> {
        self.per_pixel(|_, np, nn| np + nn)
    }

    /// True where at least one event fired.
    pub fn mask(&self) -> Vec<bool> {
        self.per_pixel(|_, np, nn| (np | nn) != 0)
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
        // Large enough for several reduction chunks of the interleaved counts.
        let sensor = Sensor::new(211, 97).unwrap();
        let n = 3 * PAR_MIN_EVENTS + 11;
        let x: Vec<u16> = (0..n).map(|i| (i * 7919 % 211) as u16).collect();
        let y: Vec<u16> = (0..n).map(|i| (i * 104729 % 97) as u16).collect();
        let p: Vec<i8> = (0..n).map(|i| if i % 3 == 0 { -1 } else { 1 }).collect();
        let ev = EventSlice::new(&x, &y, &p, sensor).unwrap();
        let mut seq = vec![0u32; 2 * sensor.pixels()];
        count_into(&mut seq, &ev).unwrap();
        let counts = polarity_counts(&ev).unwrap();
        assert_eq!(counts.counts, seq);
        assert_eq!(event_mask(&ev).unwrap(), counts.mask());
    }

    #[test]
    fn counting_reports_the_first_event_outside_the_sensor() {
        let sensor = Sensor::new(4, 3).unwrap();
        let n = 3 * PAR_MIN_EVENTS;
        let mut x = vec![1u16; n];
        let mut y = vec![1u16; n];
        x[n - 5] = 4;
        y[PAR_MIN_EVENTS + 7] = 3;
        let p = vec![1i8; n];
        let err = polarity_counts(&EventSlice::new(&x, &y, &p, sensor).unwrap()).err();
        assert!(matches!(
            err,
            Some(EventError::OutsideSensor { axis: "y", value: 3, index, .. }) if index == PAR_MIN_EVENTS + 7
        ));
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
