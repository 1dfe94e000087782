//! Cumulative cubic B-spline on SE(3) with uniform knots (Lovegrove et al. 2013; Sommer et al. 2020).
//!
//! Pose at time t in segment i (u in [0,1)):
//!   T(u) = C[i-1] · exp(B1(u) Ω1) · exp(B2(u) Ω2) · exp(B3(u) Ω3),  Ωj = log(C[i+j-2]^-1 C[i+j-1])
//! with the cumulative basis B1 = (5+3u-3u²+u³)/6, B2 = (1+3u+3u²-2u³)/6, B3 = u³/6.
//! Knot k (time t0 + k·dt) is the start of segment k. Control poses are solved so that the curve
//! passes through the given poses at the knots ("interpolation mode"); the two outer control
//! poses continue the end segments geodesically, so constant-twist motion is reproduced exactly.

use crate::se3::Se3;
use glam::{DMat4, DVec3};
use rayon::prelude::*;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SplineError {
    #[error("need at least 2 poses to fit a trajectory, got {0}")]
    TooFewPoses(usize),
    #[error("{0} times but {1} poses")]
    LengthMismatch(usize, usize),
    #[error("time at index {index} ({t}) is not after the previous one ({prev}); times must be strictly increasing")]
    NotIncreasing { index: usize, prev: f64, t: f64 },
    #[error("time {t} us is outside the trajectory's range [{min}, {max}] us; no extrapolation")]
    OutOfRange { t: f64, min: f64, max: f64 },
    #[error(
        "a knot interval that fine needs {segments} segments (max {max}); is it in microseconds?"
    )]
    TooManyKnots { segments: f64, max: usize },
    #[error("knot interval {0} us must be positive and finite")]
    BadKnotInterval(f64),
    #[error("the interpolating control poses did not converge (residual {0:.3e}); the poses change too fast between samples (rotation near 180 degrees per sample?)")]
    NotConverged(f64),
}

/// Iterations of the control-pose solve; the error shrinks by ~3x per sweep (Jacobi on the
/// [1 4 1]/6 system), so 200 sweeps are far more than double precision needs.
const MAX_SWEEPS: usize = 200;
/// A knot interval this much finer than the data is a unit mistake, not a wish.
const MAX_SEGMENTS: usize = 10_000_000;
const CONVERGED: f64 = 1e-14;
const ACCEPTABLE: f64 = 1e-9;

#[derive(Clone, Debug)]
pub struct SplineSe3 {
    t0: f64,
    dt: f64,
    /// Control poses C[-1] .. C[n+1] (stored shifted by one).
    ctrl: Vec<Se3>,
    /// d[k] = log(ctrl[k]^-1 ctrl[k+1]) as (omega, v).
    d: Vec<(DVec3, DVec3)>,
}

fn basis(u: f64) -> [f64; 3] {
    let (u2, u3) = (u * u, u * u * u);
    [
        (5.0 + 3.0 * u - 3.0 * u2 + u3) / 6.0,
        (1.0 + 3.0 * u + 3.0 * u2 - 2.0 * u3) / 6.0,
        u3 / 6.0,
    ]
}

fn basis_dot(u: f64) -> [f64; 3] {
    let u2 = u * u;
    [
        (3.0 - 6.0 * u + 3.0 * u2) / 6.0,
        (3.0 + 6.0 * u - 6.0 * u2) / 6.0,
        3.0 * u2 / 6.0,
    ]
}

fn delta(a: &Se3, b: &Se3) -> (DVec3, DVec3) {
    a.inverse().mul(b).log()
}

fn scaled(tw: (DVec3, DVec3), s: f64) -> Se3 {
    Se3::exp(tw.0 * s, tw.1 * s)
}

/// Geodesic interpolation a·exp(s log(a^-1 b)).
fn geodesic(a: &Se3, b: &Se3, s: f64) -> Se3 {
    a.mul(&scaled(delta(a, b), s))
}

impl SplineSe3 {
    /// Fit to poses at strictly increasing `times` (µs). Uniformly spaced input with no
    /// `knot_dt` is interpolated at its own times; otherwise the poses are first resampled
    /// geodesically at uniform knots of spacing `knot_dt` (default: the median spacing,
    /// adjusted so that the last knot lands on the last time).
    pub fn fit(
        times: &[f64],
        poses: &[Se3],
        knot_dt: Option<f64>,
    ) -> Result<SplineSe3, SplineError> {
        if times.len() != poses.len() {
            return Err(SplineError::LengthMismatch(times.len(), poses.len()));
        }
        if poses.len() < 2 {
            return Err(SplineError::TooFewPoses(poses.len()));
        }
        for i in 1..times.len() {
            if times[i].partial_cmp(&times[i - 1]) != Some(std::cmp::Ordering::Greater) {
                return Err(SplineError::NotIncreasing {
                    index: i,
                    prev: times[i - 1],
                    t: times[i],
                });
            }
        }
        if let Some(k) = knot_dt {
            if !(k.is_finite() && k > 0.0) {
                return Err(SplineError::BadKnotInterval(k));
            }
        }
        let gaps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
        let uniform = gaps.iter().all(|&g| g == gaps[0]);
        let (t0, span) = (times[0], times[times.len() - 1] - times[0]);
        if uniform && knot_dt.is_none() {
            return Self::interpolate(t0, gaps[0], poses);
        }
        let wanted = knot_dt.unwrap_or_else(|| {
            let mut g = gaps.clone();
            g.sort_by(f64::total_cmp);
            g[g.len() / 2]
        });
        let segments = (span / wanted).round();
        if segments > MAX_SEGMENTS as f64 {
            return Err(SplineError::TooManyKnots {
                segments,
                max: MAX_SEGMENTS,
            });
        }
        let n = (segments as usize).max(1);
        let dt = span / n as f64;
        let mut j = 0;
        let resampled: Vec<Se3> = (0..=n)
            .map(|k| {
                let t = if k == n {
                    times[times.len() - 1]
                } else {
                    t0 + k as f64 * dt
                };
                while j + 2 < times.len() && times[j + 1] <= t {
                    j += 1;
                }
                let s = ((t - times[j]) / (times[j + 1] - times[j])).clamp(0.0, 1.0);
                geodesic(&poses[j], &poses[j + 1], s)
            })
            .collect();
        Self::interpolate(t0, dt, &resampled)
    }

    /// Control poses such that the spline passes through `samples[k]` at t0 + k·dt.
    pub fn interpolate(t0: f64, dt: f64, samples: &[Se3]) -> Result<SplineSe3, SplineError> {
        if samples.len() < 2 {
            return Err(SplineError::TooFewPoses(samples.len()));
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(SplineError::BadKnotInterval(dt));
        }
        let n = samples.len() - 1;
        let mut ctrl = Vec::with_capacity(n + 3);
        ctrl.push(Se3::IDENTITY);
        ctrl.extend_from_slice(samples);
        ctrl.push(Se3::IDENTITY);
        let mut residual = f64::INFINITY;
        for _ in 0..MAX_SWEEPS {
            Self::extend_ends(&mut ctrl);
            // Jacobi sweep: every control pose is corrected by its knot's residual at once.
            let corrections: Vec<(DVec3, DVec3)> = (0..=n)
                .map(|k| {
                    let s = Self::knot_value(&ctrl, k);
                    delta(&s, &samples[k])
                })
                .collect();
            residual = corrections
                .iter()
                .map(|(w, v)| w.length().max(v.length()))
                .fold(0.0, f64::max);
            if residual < CONVERGED {
                break;
            }
            for (k, c) in corrections.iter().enumerate() {
                ctrl[k + 1] = ctrl[k + 1].mul(&Se3::exp(c.0, c.1));
            }
        }
        // NaN residuals (degenerate input) fail too.
        if residual.is_nan() || residual >= ACCEPTABLE {
            return Err(SplineError::NotConverged(residual));
        }
        Self::extend_ends(&mut ctrl);
        let d = ctrl.windows(2).map(|w| delta(&w[0], &w[1])).collect();
        Ok(SplineSe3 { t0, dt, ctrl, d })
    }

    fn extend_ends(ctrl: &mut [Se3]) {
        let m = ctrl.len();
        ctrl[0] = geodesic(&ctrl[1], &ctrl[2], -1.0);
        ctrl[m - 1] = geodesic(&ctrl[m - 2], &ctrl[m - 3], -1.0);
    }

    /// Spline value at knot k: C[k-1] exp(5/6 Ω1) exp(1/6 Ω2).
    fn knot_value(ctrl: &[Se3], k: usize) -> Se3 {
        let (a, b, c) = (&ctrl[k], &ctrl[k + 1], &ctrl[k + 2]);
        a.mul(&scaled(delta(a, b), 5.0 / 6.0))
            .mul(&scaled(delta(b, c), 1.0 / 6.0))
    }

    pub fn t_min(&self) -> f64 {
        self.t0
    }

    pub fn t_max(&self) -> f64 {
        self.t0 + self.segments() as f64 * self.dt
    }

    pub fn knot_interval(&self) -> f64 {
        self.dt
    }

    fn segments(&self) -> usize {
        self.ctrl.len() - 3
    }

    /// Segment index and local parameter u in [0,1] for time t, or an out-of-range error.
    fn locate(&self, t: f64) -> Result<(usize, f64), SplineError> {
        let (lo, hi) = (self.t_min(), self.t_max());
        if !(t >= lo && t <= hi) {
            return Err(SplineError::OutOfRange {
                t,
                min: lo,
                max: hi,
            });
        }
        let s = (t - self.t0) / self.dt;
        let i = (s.floor() as usize).min(self.segments() - 1);
        Ok((i, (s - i as f64).clamp(0.0, 1.0)))
    }

    fn factors(&self, i: usize, u: f64) -> [Se3; 3] {
        let b = basis(u);
        [0, 1, 2].map(|j| scaled(self.d[i + j], b[j]))
    }

    /// Camera-to-world pose at time t (µs).
    pub fn pose(&self, t: f64) -> Result<Se3, SplineError> {
        let (i, u) = self.locate(t)?;
        let a = self.factors(i, u);
        Ok(self.ctrl[i].mul(&a[0]).mul(&a[1]).mul(&a[2]))
    }

    /// Body-frame velocity at time t: (angular rad/s, linear m/s) with T^-1 dT/dt = [ω^ v; 0 0].
    pub fn velocity(&self, t: f64) -> Result<(DVec3, DVec3), SplineError> {
        let (i, u) = self.locate(t)?;
        let a = self.factors(i, u);
        let bd = basis_dot(u);
        let per_second = 1e6 / self.dt;
        let (mut w, mut v) = (DVec3::ZERO, DVec3::ZERO);
        for j in 0..3 {
            // ξ <- Ad_{A_j^-1} ξ + Ḃ_j Ω_j
            let (w2, v2) = a[j].inverse().adjoint(w, v);
            let (dw, dv) = self.d[i + j];
            w = w2 + dw * (bd[j] * per_second);
            v = v2 + dv * (bd[j] * per_second);
        }
        Ok((w, v))
    }

    /// Poses at many times as column-major 4x4 matrices (parallel for large batches).
    pub fn poses(&self, times: &[f64]) -> Result<Vec<DMat4>, SplineError> {
        times
            .par_iter()
            .with_min_len(4096)
            .map(|&t| self.pose(t).map(|p| p.to_mat4()))
            .collect()
    }

    /// Body velocities at many times.
    pub fn velocities(&self, times: &[f64]) -> Result<Vec<(DVec3, DVec3)>, SplineError> {
        times
            .par_iter()
            .with_min_len(4096)
            .map(|&t| self.velocity(t))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn twist_motion(t: f64) -> Se3 {
        let base = Se3::exp(DVec3::new(0.1, 0.2, -0.3), DVec3::new(1.0, 0.0, 2.0));
        base.mul(&Se3::exp(
            DVec3::new(0.8, -0.3, 1.1) * t,
            DVec3::new(0.5, 1.5, -0.2) * t,
        ))
    }

    fn max_err(a: &Se3, b: &Se3) -> f64 {
        let (ma, mb) = (a.to_mat4(), b.to_mat4());
        (0..4)
            .map(|c| (ma.col(c) - mb.col(c)).abs().max_element())
            .fold(0.0, f64::max)
    }

    #[test]
    fn constant_twist_motion_is_reproduced_between_knots() {
        let times: Vec<f64> = (0..11).map(|k| 1000.0 + 1e5 * k as f64).collect();
        let poses: Vec<Se3> = times
            .iter()
            .map(|&t| twist_motion((t - 1000.0) * 1e-6))
            .collect();
        let s = SplineSe3::fit(&times, &poses, None).unwrap();
        for k in 0..=1000 {
            let t = 1000.0 + 1e3 * k as f64;
            let e = max_err(&s.pose(t).unwrap(), &twist_motion((t - 1000.0) * 1e-6));
            assert!(e < 1e-12, "t={t} err={e}");
        }
    }

    #[test]
    fn body_velocity_of_constant_twist_is_the_twist() {
        let times: Vec<f64> = (0..6).map(|k| 2e5 * k as f64).collect();
        let poses: Vec<Se3> = times.iter().map(|&t| twist_motion(t * 1e-6)).collect();
        let s = SplineSe3::fit(&times, &poses, None).unwrap();
        let (w, v) = s.velocity(333_333.0).unwrap();
        assert!((w - DVec3::new(0.8, -0.3, 1.1)).length() < 1e-10);
        assert!((v - DVec3::new(0.5, 1.5, -0.2)).length() < 1e-10);
    }

    #[test]
    fn querying_outside_the_range_is_an_error() {
        let times = [0.0, 10.0, 20.0];
        let s = SplineSe3::fit(&times, &[Se3::IDENTITY; 3], None).unwrap();
        assert!(s.pose(20.0).is_ok());
        assert!(matches!(s.pose(20.5), Err(SplineError::OutOfRange { .. })));
        assert!(matches!(s.pose(-1.0), Err(SplineError::OutOfRange { .. })));
        assert!(matches!(
            s.pose(f64::NAN),
            Err(SplineError::OutOfRange { .. })
        ));
    }

    #[test]
    fn non_increasing_times_name_the_index() {
        let e = SplineSe3::fit(&[0.0, 5.0, 5.0], &[Se3::IDENTITY; 3], None).unwrap_err();
        assert_eq!(
            e,
            SplineError::NotIncreasing {
                index: 2,
                prev: 5.0,
                t: 5.0
            }
        );
    }
}
