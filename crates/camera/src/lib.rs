//! Camera trajectories: rigid motions in f64 and the cumulative cubic B-spline on SE(3).

pub mod distortion;
pub mod se3;
pub mod spline;

pub use distortion::{Distortion, DistortionError};
pub use se3::Se3;
pub use spline::{SplineError, SplineSe3};
