//! Voxel grid: events spread over B temporal bins with bilinear weights in normalised time,
//! the event representation used for visualisation (E2VID style).

use rayon::prelude::*;

use crate::error::EventError;
use crate::stream::EventSlice;

/// (B, H, W) grid. An event at time t adds `p * max(0, 1 - |tn - b|)` to bin b, where
/// `tn = (B-1) (t - t_first) / (t_last - t_first)` over the window (0 when they are equal).
/// Time is made relative to the window's first event in i64 before any float arithmetic, so
/// absolute offsets do not change the result.
///
/// Events are sorted, so those with `floor(tn) = s` form one segment that touches only bins s
/// and s+1: each segment accumulates (in f64, in event order) into its own two planes, on its
/// own thread, and bin b is then `segment b's lower plane + segment b-1's upper plane`. The
/// working set per segment stays two planes, and the result does not depend on thread count.
pub fn voxel_grid(ev: &EventSlice, t: &[i64], bins: usize) -> Result<Vec<f32>, EventError> {
    if bins == 0 {
        return Err(EventError::NotPositive {
            name: "bins",
            value: 0,
        });
    }
    ev.check_inside()?;
    let pixels = ev.sensor().pixels();
    let mut out = vec![0f32; bins * pixels];
    let (Some(&first), Some(&last)) = (t.first(), t.last()) else {
        return Ok(out);
    };
    // Sorted, so t - first >= 0: as u64 it cannot overflow even where i64 would (fast, unlike
    // an i128 conversion).
    let rel = |t: i64| t.wrapping_sub(first) as u64 as f64;
    let span = rel(last);
    let scale = if span > 0.0 {
        (bins - 1) as f64 / span
    } else {
        0.0
    };
    let bin_of = |tn: f64| (tn.floor() as usize).min(bins - 1);
    let (x, y, p) = ev.parts();
    let w = ev.sensor().width as usize;
    let segments: Vec<(Vec<f64>, Vec<f64>)> = (0..bins)
        .into_par_iter()
        .map(|s| {
            let start = t.partition_point(|&ti| bin_of(rel(ti) * scale) < s);
            let stop = t.partition_point(|&ti| bin_of(rel(ti) * scale) <= s);
            let (mut lo, mut hi) = (vec![0f64; pixels], vec![0f64; pixels]);
            for i in start..stop {
                let tn = rel(t[i]) * scale;
                let frac = tn - s as f64;
                let pol = if p[i] < 0 { -1.0 } else { 1.0 };
                let pix = y[i] as usize * w + x[i] as usize;
                lo[pix] += pol * (1.0 - frac);
                if frac > 0.0 && s + 1 < bins {
                    hi[pix] += pol * frac;
                }
            }
            (lo, hi)
        })
        .collect();
    out.par_chunks_mut(pixels)
        .enumerate()
        .for_each(|(b, plane)| {
            let lo = &segments[b].0;
            match b.checked_sub(1) {
                Some(prev) => {
                    let hi = &segments[prev].1;
                    for ((o, &a), &c) in plane.iter_mut().zip(lo).zip(hi) {
                        *o = (c + a) as f32;
                    }
                }
                None => plane.iter_mut().zip(lo).for_each(|(o, &a)| *o = a as f32),
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stream::Sensor;

    #[test]
    fn voxel_grid_splits_between_neighbouring_bins() {
        let sensor = Sensor::new(1, 1).unwrap();
        let ev = EventSlice::new(&[0, 0, 0], &[0, 0, 0], &[1, -1, 1], sensor).unwrap();
        let grid = voxel_grid(&ev, &[10, 15, 30], 3).unwrap();
        // tn = 0, 0.5, 2.
        assert_eq!(grid, vec![0.5, -0.5, 1.0]);
        let single = voxel_grid(&ev.range(0, 1), &[10], 3).unwrap();
        assert_eq!(single, vec![1.0, 0.0, 0.0]);
    }
}
