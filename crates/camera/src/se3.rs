//! Rigid motions SE(3) in f64: composition, exp/log with small-angle series, body twists.
//!
//! A twist is (omega, v): rotation vector and translational part, so that
//! `exp([omega^ v; 0 0])` is the 4x4 group element (the usual right-Jacobian-free form).

use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};

/// A rigid motion: rotation `q` (unit quaternion) then translation `t`: x -> q x + t.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se3 {
    pub q: DQuat,
    pub t: DVec3,
}

/// Below this rotation angle (rad) the exp/log coefficients use their Taylor series;
/// the closed forms lose digits to cancellation there.
const SMALL_ANGLE: f64 = 1e-4;

fn skew(w: DVec3) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(0.0, w.z, -w.y),
        DVec3::new(-w.z, 0.0, w.x),
        DVec3::new(w.y, -w.x, 0.0),
    )
}

/// Rotation vector -> unit quaternion, exact for small angles too.
fn so3_exp(w: DVec3) -> DQuat {
    let theta = w.length();
    let half = 0.5 * theta;
    // sin(theta/2)/theta, with its series near zero.
    let k = if theta < SMALL_ANGLE {
        0.5 - theta * theta / 48.0
    } else {
        half.sin() / theta
    };
    DQuat::from_xyzw(w.x * k, w.y * k, w.z * k, half.cos()).normalize()
}

/// Unit quaternion -> rotation vector in the ball of radius pi (atan2: no acos precision loss).
fn so3_log(q: DQuat) -> DVec3 {
    let q = if q.w < 0.0 { -q } else { q };
    let v = DVec3::new(q.x, q.y, q.z);
    let s = v.length();
    let theta = 2.0 * s.atan2(q.w);
    // theta / sin(theta/2) = theta / s, with its series near zero.
    let k = if s < 0.5 * SMALL_ANGLE {
        2.0 / q.w * (1.0 - s * s / (3.0 * q.w * q.w))
    } else {
        theta / s
    };
    v * k
}

/// Coefficients a = (1-cos)/theta^2 and b = (theta - sin)/theta^3 of the left Jacobian V.
fn v_coeffs(theta: f64) -> (f64, f64) {
    if theta < SMALL_ANGLE {
        let t2 = theta * theta;
        (0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
    } else {
        let t2 = theta * theta;
        (
            (1.0 - theta.cos()) / t2,
            (theta - theta.sin()) / (t2 * theta),
        )
    }
}

impl Se3 {
    pub const IDENTITY: Se3 = Se3 {
        q: DQuat::IDENTITY,
        t: DVec3::ZERO,
    };

    /// From a 4x4 matrix whose upper-left 3x3 is a rotation (validated by the caller).
    pub fn from_mat4(m: &DMat4) -> Se3 {
        let r = DMat3::from_cols(
            m.x_axis.truncate(),
            m.y_axis.truncate(),
            m.z_axis.truncate(),
        );
        Se3 {
            q: DQuat::from_mat3(&r).normalize(),
            t: m.w_axis.truncate(),
        }
    }

    pub fn to_mat4(&self) -> DMat4 {
        let r = DMat3::from_quat(self.q);
        DMat4::from_cols(
            r.x_axis.extend(0.0),
            r.y_axis.extend(0.0),
            r.z_axis.extend(0.0),
            DVec4::new(self.t.x, self.t.y, self.t.z, 1.0),
        )
    }

    pub fn inverse(&self) -> Se3 {
        let qi = self.q.conjugate();
        Se3 {
            q: qi,
            t: -(qi * self.t),
        }
    }

    /// self ∘ other (apply `other` first).
    pub fn mul(&self, other: &Se3) -> Se3 {
        Se3 {
            q: (self.q * other.q).normalize(),
            t: self.q * other.t + self.t,
        }
    }

    /// exp of the twist (omega, v).
    pub fn exp(omega: DVec3, v: DVec3) -> Se3 {
        let theta = omega.length();
        let (a, b) = v_coeffs(theta);
        let w = skew(omega);
        let vmat = DMat3::IDENTITY + w * a + (w * w) * b;
        Se3 {
            q: so3_exp(omega),
            t: vmat * v,
        }
    }

    /// log: the twist (omega, v) with |omega| <= pi.
    pub fn log(&self) -> (DVec3, DVec3) {
        let omega = so3_log(self.q);
        let theta = omega.length();
        let w = skew(omega);
        // V^-1 = I - W/2 + c W^2, c = (1 - theta sin / (2 (1 - cos))) / theta^2.
        let c = if theta < SMALL_ANGLE {
            1.0 / 12.0 + theta * theta / 720.0
        } else {
            let half = 0.5 * theta;
            (1.0 - half * half.cos() / half.sin()) / (theta * theta)
        };
        let vinv = DMat3::IDENTITY - w * 0.5 + (w * w) * c;
        (omega, vinv * self.t)
    }

    /// Adjoint action on a twist: Ad_T (omega, v) = (R omega, R v + t x R omega).
    pub fn adjoint(&self, omega: DVec3, v: DVec3) -> (DVec3, DVec3) {
        let ro = self.q * omega;
        (ro, self.q * v + self.t.cross(ro))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_log_round_trip_over_small_medium_and_large_angles() {
        for &theta in &[0.0, 1e-12, 1e-6, 1e-3, 0.5, 2.0, 3.1] {
            let axis = DVec3::new(0.3, -0.5, 0.8).normalize();
            let (w, v) = (axis * theta, DVec3::new(0.4, -1.2, 2.5));
            let (w2, v2) = Se3::exp(w, v).log();
            assert!((w2 - w).length() < 1e-12, "theta {theta}");
            assert!((v2 - v).length() < 1e-12, "theta {theta}");
        }
    }

    #[test]
    fn exp_matches_matrix_exponential_series() {
        let (w, v) = (DVec3::new(0.7, -0.2, 0.4), DVec3::new(1.0, 2.0, -0.5));
        let mut xi = DMat4::ZERO;
        let s = skew(w);
        xi.x_axis = s.x_axis.extend(0.0);
        xi.y_axis = s.y_axis.extend(0.0);
        xi.z_axis = s.z_axis.extend(0.0);
        xi.w_axis = v.extend(0.0);
        let (mut term, mut sum) = (DMat4::IDENTITY, DMat4::IDENTITY);
        for k in 1..40 {
            term = term * xi * (1.0 / k as f64);
            sum += term;
        }
        let got = Se3::exp(w, v).to_mat4();
        for c in 0..4 {
            assert!((got.col(c) - sum.col(c)).length() < 1e-13);
        }
    }
}
