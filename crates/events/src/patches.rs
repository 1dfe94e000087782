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

/// Where one row (or column) of patch samples falls: whether the coordinate lies on the
/// sensor, the nearest pixel, and the two bilinear neighbours with the weight of the second.
#[derive(Clone, Copy, Default)]
struct Tap {
    inside: bool,
    nearest: usize,
    lo: usize,
    hi: usize,
    frac: f64,
}

impl Tap {
    /// Sample coordinate `s` along an axis of `n` pixels. Bilinear weights sit on pixel centres
    /// (k + 0.5); neighbours past the border repeat the edge pixel. NaN falls outside.
    fn new(s: f64, n: u32) -> Self {
        if !(s >= 0.0 && s < f64::from(n)) {
            return Self::default();
        }
        let u = s - 0.5;
        let fu = u.floor();
        let clamp = |k: f64| k.clamp(0.0, f64::from(n - 1)) as usize;
        Self {
            inside: true,
            nearest: s as usize,
            lo: clamp(fu),
            hi: clamp(fu + 1.0),
            frac: u - fu,
        }
    }
}

/// Fills one side×side patch of `image` centred at (cx, cy): sample (a, b) at
/// (cx + b - half, cy + a - half). Samples off the sensor stay 0 and invalid.
#[allow(clippy::too_many_arguments)]
fn fill_patch(
    image: &[f32],
    sensor: Sensor,
    (cx, cy): (f64, f64),
    side: usize,
    mode: Sampling,
    cols: &mut [Tap],
    vals: &mut [f32],
    oks: &mut [bool],
) {
    let half = (side as f64 - 1.0) / 2.0;
    for (b, col) in cols.iter_mut().enumerate() {
        *col = Tap::new(cx + (b as f64 - half), sensor.width);
    }
    let w = sensor.width as usize;
    let at = |i: usize, j: usize| f64::from(image[i * w + j]);
    for a in 0..side {
        let row = Tap::new(cy + (a as f64 - half), sensor.height);
        if !row.inside {
            continue;
        }
        let out = a * side..(a + 1) * side;
        for ((col, v), ok) in cols.iter().zip(&mut vals[out.clone()]).zip(&mut oks[out]) {
            if !col.inside {
                continue;
            }
            *v = match mode {
                Sampling::Nearest => image[row.nearest * w + col.nearest],
                Sampling::Bilinear => {
                    let (ax, ay) = (col.frac, row.frac);
                    let top = (1.0 - ax) * at(row.lo, col.lo) + ax * at(row.lo, col.hi);
                    let bottom = (1.0 - ax) * at(row.hi, col.lo) + ax * at(row.hi, col.hi);
                    ((1.0 - ay) * top + ay * bottom) as f32
                }
            };
            *ok = true;
        }
    }
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
    let mut values = vec![0f32; n * m * ss];
    let mut valid = vec![false; n * m * ss];
    values
        .par_chunks_mut(m * ss)
        .zip(valid.par_chunks_mut(m * ss))
        .enumerate()
        .for_each(|(c, (vals, oks))| {
            let mut cols = vec![Tap::default(); side];
            for (k, image) in images.iter().enumerate() {
                let ci = if per_window { 2 * (c * m + k) } else { 2 * c };
                let centre = (f64::from(centres[ci]), f64::from(centres[ci + 1]));
                let out = k * ss..(k + 1) * ss;
                let (v, o) = (&mut vals[out.clone()], &mut oks[out]);
                fill_patch(image, ev.sensor(), centre, side, mode, &mut cols, v, o);
            }
        });
    Ok(Patches { values, valid })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accumulate::Threshold;

    #[test]
    fn bilinear_patch_interpolates_between_pixel_centres() {
        let sensor = Sensor::new(2, 1).unwrap();
        let img = [0.0f32, 1.0];
        let mut cols = [Tap::default(); 3];
        let (mut v, mut ok) = ([0f32; 9], [false; 9]);
        // Samples at x = 0.0, 1.0, 2.0 on row y = 0.5 (the middle row of the patch).
        fill_patch(
            &img,
            sensor,
            (1.0, 0.5),
            3,
            Sampling::Bilinear,
            &mut cols,
            &mut v,
            &mut ok,
        );
        assert_eq!(&v[3..6], &[0.0, 0.5, 0.0]);
        assert_eq!(
            ok,
            [false, false, false, true, true, false, false, false, false]
        );
        let (mut v, mut ok) = ([0f32; 9], [false; 9]);
        let nan = (f64::NAN, 0.5);
        fill_patch(
            &img,
            sensor,
            nan,
            3,
            Sampling::Nearest,
            &mut cols,
            &mut v,
            &mut ok,
        );
        assert_eq!((v, ok), ([0.0; 9], [false; 9]));
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
