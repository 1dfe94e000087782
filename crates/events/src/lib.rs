//! The event core: validated event streams (x, y: u16; t: i64 µs; p: ±1), windows by time and
//! count, equal-count splits, event single integrals (ESI), counts and masks, the Bayer split,
//! patch extraction and voxel grids. Validation happens once at the boundary; the hot loops
//! then index without checks and run in parallel with rayon where it pays.

mod accumulate;
mod columns;
mod error;
mod patches;
mod stream;
mod voxel;

pub use accumulate::{event_mask, polarity_counts, Bayer, Contrast, PolarityCounts, Threshold};
pub use columns::Events;
pub use error::EventError;
pub use patches::{check_bounds, extract_patches, Patches, Sampling};
pub use stream::{
    check_range, check_sorted, coords_to_u16, float_to_i64, polarity_from_i64, polarity_to_pm1,
    split_equal_count, validate, window_by_count, window_by_time, EventSlice, Sensor,
};
pub use voxel::voxel_grid;
