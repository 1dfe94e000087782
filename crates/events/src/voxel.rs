//! Voxel grid: events spread over B temporal bins with bilinear weights in normalised time,
//! the event representation used for visualisation (E2VID style).

use crate::error::EventError;
use crate::stream::EventSlice;

/// (B, H, W) grid. An event at time t adds `p * max(0, 1 - |tn - b|)` to bin b, where
/// `tn = (B-1) (t - t_first) / (t_last - t_first)` over the window (0 when they are equal).
/// Time is made relative to the window's first event in i64 before any float arithmetic, so
/// absolute offsets do not change the result. Accumulates in f64 in event order on one thread:
/// deterministic, and voxel grids serve visualisation, not the training loop.
pub fn voxel_grid(ev: &EventSlice, t: &[i64], bins: usize) -> Result<Vec<f32>, EventError> {
    if bins == 0 {
        return Err(EventError::NotPositive {
            name: "bins",
            value: 0,
        });
    }
    ev.check_inside()?;
    let pixels = ev.sensor().pixels();
    let mut grid = vec![0f64; bins * pixels];
    if let (Some(&first), Some(&last)) = (t.first(), t.last()) {
        // i128: the span of two arbitrary i64 timestamps can exceed i64.
        let rel = |t: i64| (i128::from(t) - i128::from(first)) as f64;
        let span = rel(last);
        let scale = if span > 0.0 {
            (bins - 1) as f64 / span
        } else {
            0.0
        };
        let (x, y, p) = ev.parts();
        let w = ev.sensor().width as usize;
        for (((&xi, &yi), &pi), &ti) in x.iter().zip(y).zip(p).zip(t) {
            let tn = rel(ti) * scale;
            let b0 = (tn.floor() as usize).min(bins - 1);
            let frac = tn - b0 as f64;
            let pol = if pi < 0 { -1.0 } else { 1.0 };
            let pix = yi as usize * w + xi as usize;
            grid[b0 * pixels + pix] += pol * (1.0 - frac);
            if frac > 0.0 && b0 + 1 < bins {
                grid[(b0 + 1) * pixels + pix] += pol * frac;
            }
        }
    }
    Ok(grid.into_iter().map(|v| v as f32).collect())
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
