//! Lens distortion: pinhole radial-tangential (OpenCV `k1, k2, p1, p2[, k3]`) and equidistant
//! fisheye (OpenCV `cv::fisheye`, `k1..k4`), with an iterative inverse and the per-pixel
//! rectification map used to undistort event coordinates once at load time.

use rayon::prelude::*;
use thiserror::Error;

/// Newton iterations before a point is declared outside the invertible part of the lens.
const MAX_ITERS: usize = 50;
/// Residual (normalised image units) at which the inverse is converged; 1e-12 of a focal length
/// is far below 1e-3 px for any real focal length.
const TOL: f64 = 1e-12;

#[derive(Debug, Error, PartialEq)]
pub enum DistortionError {
    #[error("distortion model {0:?} is unknown; use \"radtan\" (k1, k2, p1, p2[, k3]) or \"equidistant\" (k1, k2, k3, k4)")]
    UnknownModel(String),
    #[error("distortion model {model} takes {expected} coefficients, got {got}")]
    CoeffCount {
        model: &'static str,
        expected: &'static str,
        got: usize,
    },
    #[error("distortion coefficient {index} is {value}; every coefficient must be finite")]
    NonFinite { index: usize, value: f64 },
    #[error("intrinsics fx, fy, cx, cy must be finite with fx, fy > 0, got {0:?}")]
    BadIntrinsics([f64; 4]),
}

/// A lens model acting on normalised image coordinates (x/z, y/z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Distortion {
    RadTan {
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
        k3: f64,
    },
    Equidistant {
        k: [f64; 4],
    },
}

impl Distortion {
    /// Builds a model from its name and OpenCV-ordered coefficients.
    pub fn new(model: &str, coeffs: &[f64]) -> Result<Self, DistortionError> {
        if let Some((index, &value)) = coeffs.iter().enumerate().find(|(_, c)| !c.is_finite()) {
            return Err(DistortionError::NonFinite { index, value });
        }
        match model {
            "radtan" => match *coeffs {
                [k1, k2, p1, p2] => Ok(Self::RadTan {
                    k1,
                    k2,
                    p1,
                    p2,
                    k3: 0.0,
                }),
                [k1, k2, p1, p2, k3] => Ok(Self::RadTan { k1, k2, p1, p2, k3 }),
                _ => Err(DistortionError::CoeffCount {
                    model: "radtan",
                    expected: "4 or 5",
                    got: coeffs.len(),
                }),
            },
            "equidistant" => match *coeffs {
                [k1, k2, k3, k4] => Ok(Self::Equidistant {
                    k: [k1, k2, k3, k4],
                }),
                _ => Err(DistortionError::CoeffCount {
                    model: "equidistant",
                    expected: "4",
                    got: coeffs.len(),
                }),
            },
            other => Err(DistortionError::UnknownModel(other.to_string())),
        }
    }

    /// Distorts an ideal normalised point (the forward lens model, as in OpenCV).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        match *self {
            Self::RadTan { k1, k2, p1, p2, k3 } => {
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                (
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
                )
            }
            Self::Equidistant { k } => {
                let r = (x * x + y * y).sqrt();
                if r < 1e-15 {
                    return (x, y);
                }
                let theta = r.atan();
                let t2 = theta * theta;
                let theta_d = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))));
                let s = theta_d / r;
                (x * s, y * s)
            }
        }
    }

    /// Inverts the lens model by Newton's method; `None` where it does not converge (outside
    /// the part of the image the model maps one-to-one).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        if !(xd.is_finite() && yd.is_finite()) {
            return None;
        }
        match *self {
            Self::RadTan { k1, k2, p1, p2, k3 } => {
                let (mut x, mut y) = (xd, yd);
                for _ in 0..MAX_ITERS {
                    let (fx, fy) = self.distort(x, y);
                    let (ex, ey) = (fx - xd, fy - yd);
                    if ex.abs() < TOL && ey.abs() < TOL {
                        return Some((x, y));
                    }
                    let r2 = x * x + y * y;
                    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                    let dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
                    let (drdx, drdy) = (2.0 * x * dradial_dr2, 2.0 * y * dradial_dr2);
                    let j00 = radial + x * drdx + 2.0 * p1 * y + 6.0 * p2 * x;
                    let j01 = x * drdy + 2.0 * p1 * x + 2.0 * p2 * y;
                    let j10 = y * drdx + 2.0 * p1 * x + 2.0 * p2 * y;
                    let j11 = radial + y * drdy + 6.0 * p1 * y + 2.0 * p2 * x;
                    let det = j00 * j11 - j01 * j10;
                    if !det.is_finite() || det.abs() < 1e-12 {
                        return None;
                    }
                    x -= (j11 * ex - j01 * ey) / det;
                    y -= (j00 * ey - j10 * ex) / det;
                }
                None
            }
            Self::Equidistant { k } => {
                let theta_d = (xd * xd + yd * yd).sqrt();
                if theta_d < 1e-15 {
                    return Some((xd, yd));
                }
                let mut theta = theta_d.min(std::f64::consts::FRAC_PI_2 - 1e-6);
                for _ in 0..MAX_ITERS {
                    let t2 = theta * theta;
                    let f = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
                        - theta_d;
                    if f.abs() < TOL {
                        // Behind or at the image plane's horizon there is no pinhole point.
                        if !(0.0..std::f64::consts::FRAC_PI_2).contains(&theta) {
                            return None;
                        }
                        let s = theta.tan() / theta_d;
                        return Some((xd * s, yd * s));
                    }
                    let df = 1.0
                        + t2 * (3.0 * k[0]
                            + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + 9.0 * k[3] * t2)));
                    if !df.is_finite() || df.abs() < 1e-12 {
                        return None;
                    }
                    theta -= f / df;
                }
                None
            }
        }
    }
}

/// Pinhole intrinsics `[fx, fy, cx, cy]`, checked.
fn check_k(k: [f64; 4]) -> Result<[f64; 4], DistortionError> {
    if k.iter().all(|v| v.is_finite()) && k[0] > 0.0 && k[1] > 0.0 {
        Ok(k)
    } else {
        Err(DistortionError::BadIntrinsics(k))
    }
}

/// Undistorts pixel points `(u, v)` (distorted image, intrinsics `k = [fx, fy, cx, cy]`) to
/// pixel points of the ideal pinhole camera with the same `k`; NaN where the inverse fails.
pub fn undistort_pixels(
    d: &Distortion,
    k: [f64; 4],
    points: &[[f64; 2]],
) -> Result<Vec<[f64; 2]>, DistortionError> {
    let [fx, fy, cx, cy] = check_k(k)?;
    Ok(points
        .par_iter()
        .map(|&[u, v]| match d.undistort((u - cx) / fx, (v - cy) / fy) {
            Some((x, y)) => [x * fx + cx, y * fy + cy],
            None => [f64::NAN, f64::NAN],
        })
        .collect())
}

/// The rectification map of a `width` x `height` sensor: for pixel (row i, column j), row-major,
/// the undistorted position of its centre `(j + 0.5, i + 0.5)`; NaN where the inverse fails.
pub fn rectification_map(
    d: &Distortion,
    k: [f64; 4],
    width: usize,
    height: usize,
) -> Result<Vec<[f64; 2]>, DistortionError> {
    let centres: Vec<[f64; 2]> = (0..height)
        .flat_map(|i| (0..width).map(move |j| [j as f64 + 0.5, i as f64 + 0.5]))
        .collect();
    undistort_pixels(d, k, &centres)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_recovers_points_for_both_models() {
        let models = [
            Distortion::new("radtan", &[-0.28, 0.07, 1e-3, -2e-3, 0.01]).unwrap(),
            Distortion::new("equidistant", &[-0.01, 0.02, -0.005, 0.001]).unwrap(),
        ];
        for d in models {
            for i in -10..=10 {
                for j in -10..=10 {
                    let (x, y) = (0.06 * j as f64, 0.05 * i as f64);
                    let (xd, yd) = d.distort(x, y);
                    let (xu, yu) = d.undistort(xd, yd).unwrap();
                    assert!(
                        (xu - x).abs() < 1e-10 && (yu - y).abs() < 1e-10,
                        "{d:?} {x} {y}"
                    );
                }
            }
        }
    }

    #[test]
    fn bad_coefficients_are_rejected() {
        assert!(matches!(
            Distortion::new("radtan", &[0.1, f64::NAN, 0.0, 0.0]),
            Err(DistortionError::NonFinite { index: 1, .. })
        ));
        assert!(matches!(
            Distortion::new("equidistant", &[0.1]),
            Err(DistortionError::CoeffCount { .. })
        ));
        assert!(matches!(
            Distortion::new("kannala", &[0.1]),
            Err(DistortionError::UnknownModel(_))
        ));
    }

    #[test]
    fn zero_distortion_map_is_the_pixel_grid() {
        let d = Distortion::new("radtan", &[0.0; 4]).unwrap();
        let map = rectification_map(&d, [50.0, 50.0, 8.0, 6.0], 16, 12).unwrap();
        assert_eq!(map[12 * 16 - 1], [15.5, 11.5]);
        assert_eq!(map[17], [1.5, 1.5]);
    }
}
