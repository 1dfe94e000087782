//! Patch extraction: for n centres and m sub-windows, the ESI of each sub-window sampled on a
//! side×side grid around the centre (bilinear between pixel centres, or nearest pixel).

use rayon::prelude::*;

use crate::accumulate::{polarity_counts, Contrast};
use crate::error::EventError;
use crate::stream::{EventSlice, Sensor};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sampling {
    Bilinear,
    Nearest,
}

impl Sampling {
    pub fn parse(name: &str) -> Result<Self, EventError> {
        match name {
            "bilinear" => Ok(Sampling::Bilinear),
            "nearest" => Ok(Sampling::Nearest),
            _ => Err(EventError::BadMode(name.to_string())),
        }
    }
}

/// Patch values (n, m, side, side) and validity flags of the same shape.
pub struct Patches {
    pub values: Vec<f32>,
    pub valid: Vec<bool>,
}

/// Checks that `bounds` are non-decreasing indices into a stream of `len` events.
pub fn check_bounds(bounds: &[i64], len: usize) -> Result<(), EventError> {
    let bad = |index: usize| EventError::BadBounds {
        index,
        value: bounds[index],
        len,
    };
    if bounds.is_empty() {
        return Err(EventError::NotPositive {
            name: "len(bounds)",
            value: 0,
        });
    }
    for (i, &b) in bounds.iter().enumerate() {
        if b < 0 || b as u64 > len as u64 || (i > 0 && b < bounds[i - 1]) {
            return Err(bad(i));
        }
    }
    Ok(())
}

/// Samples `image` at pixel coordinates (sx, sy); None outside the sensor. Bilinear weights
/// sit on pixel centres (j + 0.5, i + 0.5); neighbours past the border repeat the edge pixel.
#[inline]
fn sample(image: &[f32], sensor: Sensor, sx: f64, sy: f64, mode: Sampling) -> Option<f32> {
    let (w, h) = (f64::from(sensor.width), f64::from(sensor.height));
    // Written so that NaN centres fall outside.
    if !(sx >= 0.0 && sx < w && sy >= 0.0 && sy < h) {
        return None;
    }
    let wi = sensor.width as usize;
    let at = |i: usize, j: usize| f64::from(image[i * wi + j]);
    Some(match mode {
        Sampling::Nearest => at(sy as usize, sx as usize) as f32,
        Sampling::Bilinear => {
            let (u, v) = (sx - 0.5, sy - 0.5);
            let (fu, fv) = (u.floor(), v.floor());
            let (ax, ay) = (u - fu, v - fv);
            let clamp = |k: f64, n: u32| k.clamp(0.0, f64::from(n - 1)) as usize;
            let (j0, j1) = (clamp(fu, sensor.width), clamp(fu + 1.0, sensor.width));
            let (i0, i1) = (clamp(fv, sensor.height), clamp(fv + 1.0, sensor.height));
            let top = (1.0 - ax) * at(i0, j0) + ax * at(i0, j1);
            let bottom = (1.0 - ax) * at(i1, j0) + ax * at(i1, j1);
            ((1.0 - ay) * top + ay * bottom) as f32
        }
    })
}

/// Extracts patches. `bounds` (m+1 indices into `ev`, see `split_equal_count`) define the
/// sub-windows; `centres` holds (x, y) per centre (n*2 values, the same for every sub-window)
/// (`per_window` false) or per centre and sub-window (n*m*2, row-major (n, m, 2)) for
/// centres that move.
/// Sample (a, b) of a patch lies at centre + (b - (side-1)/2, a - (side-1)/2).
pub fn extract_patches(
    ev: &EventSlice,
    bounds: &[i64],
    centres: &[f32],
    per_window: bool,
    side: usize,
    contrast: &Contrast,
    mode: Sampling,
) -> Result<Patches, EventError> {
    check_bounds(bounds, ev.len())?;
    contrast.check(ev.sensor())?;
    if side == 0 {
        return Err(EventError::NotPositive {
            name: "side",
            value: 0,
        });
    }
    let m = bounds.len() - 1;
    let per_centre = if per_window { 2 * m } else { 2 };
    if !centres.chunks_exact(per_centre).remainder().is_empty() {
        return Err(EventError::CentresShape {
            len: centres.len(),
            windows: m,
        });
    }
    let n = centres.len() / per_centre;
    let images: Vec<Vec<f32>> = bounds
        .windows(2)
        .map(|b| Ok(polarity_counts(&ev.range(b[0] as usize, b[1] as usize))?.esi(contrast)))
        .collect::<Result<_, EventError>>()?;
    let ss = side * side;
    let half = (side as f64 - 1.0) / 2.0;
    let mut values = vec![0f32; n * m * ss];
    let mut valid = vec![false; n * m * ss];
    values
        .par_chunks_mut(m * ss)
        .zip(valid.par_chunks_mut(m * ss))
        .enumerate()
        .for_each(|(c, (vals, oks))| {
            for (k, image) in images.iter().enumerate() {
                let ci = if per_window { 2 * (c * m + k) } else { 2 * c };
                let (cx, cy) = (f64::from(centres[ci]), f64::from(centres[ci + 1]));
                for a in 0..side {
                    for b in 0..side {
                        let o = k * ss + a * side + b;
                        let (sx, sy) = (cx + (b as f64 - half), cy + (a as f64 - half));
                        if let Some(v) = sample(image, ev.sensor(), sx, sy, mode) {
                            vals[o] = v;
                            oks[o] = true;
                        }
                    }
                }
            }
        });
    Ok(Patches { values, valid })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accumulate::Threshold;

    #[test]
    fn bilinear_sample_interpolates_between_pixel_centres() {
        let sensor = Sensor::new(2, 1).unwrap();
        let img = [0.0f32, 1.0];
        assert_eq!(
            sample(&img, sensor, 0.5, 0.5, Sampling::Bilinear),
            Some(0.0)
        );
        assert_eq!(
            sample(&img, sensor, 1.0, 0.5, Sampling::Bilinear),
            Some(0.5)
        );
        assert_eq!(
            sample(&img, sensor, 1.9, 0.2, Sampling::Bilinear),
            Some(1.0)
        );
        assert_eq!(sample(&img, sensor, 2.0, 0.5, Sampling::Bilinear), None);
        assert_eq!(sample(&img, sensor, f64::NAN, 0.5, Sampling::Nearest), None);
    }

    #[test]
    fn patch_of_single_event_is_centred() {
        let sensor = Sensor::new(5, 5).unwrap();
        let ev = EventSlice::new(&[2], &[2], &[1], sensor).unwrap();
        let c = Contrast {
            pos: Threshold::Scalar(1.0),
            neg: Threshold::Scalar(1.0),
        };
        let p =
            extract_patches(&ev, &[0, 1], &[2.5, 2.5], false, 3, &c, Sampling::Nearest).unwrap();
        assert_eq!(p.values, vec![0., 0., 0., 0., 1., 0., 0., 0., 0.]);
        assert!(p.valid.iter().all(|&v| v));
        let p =
            extract_patches(&ev, &[0, 1], &[0.2, 0.2], false, 3, &c, Sampling::Nearest).unwrap();
        assert_eq!(
            p.valid,
            vec![false, false, false, false, true, true, false, true, true]
        );
    }
}
