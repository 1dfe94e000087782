//! Shapes of the primitives and their ray intersections (object frame).

use super::{dot, Primitive, V3};

/// Hits nearer than this are ignored (no shape reaches the camera).
const NEAR: f64 = 1e-3;

#[derive(Clone, Debug)]
pub(super) enum Shape {
    Sphere(f64),
    Box(V3),
    Quad(f64, f64),
    /// Quad whose [-1,1]² coordinates are cut to fore- and hind-wing lobes; side = ±1.
    Wing(f64, f64, f64),
}

impl Primitive {
    /// Nearest hit of the ray o + s d (object frame): (s, point, normal).
    pub(super) fn intersect(&self, o: V3, d: V3) -> Option<(f64, V3, V3)> {
        let at = |s: f64| [o[0] + s * d[0], o[1] + s * d[1], o[2] + s * d[2]];
        match self.shape {
            Shape::Sphere(r) => {
                let (a, b, c) = (dot(d, d), dot(d, o), dot(o, o) - r * r);
                let disc = b * b - a * c;
                if disc <= 0.0 || a <= 0.0 {
                    return None;
                }
                let s = (-b - disc.sqrt()) / a;
                (s > NEAR).then(|| {
                    let p = at(s);
                    (s, p, [p[0] / r, p[1] / r, p[2] / r])
                })
            }
            Shape::Box(h) => {
                let (mut s_in, mut s_out, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
                for k in 0..3 {
                    if d[k] == 0.0 {
                        if o[k].abs() > h[k] {
                            return None;
                        }
                        continue;
                    }
                    let (t1, t2) = ((-h[k] - o[k]) / d[k], (h[k] - o[k]) / d[k]);
                    let (lo, hi) = (t1.min(t2), t1.max(t2));
                    if lo > s_in {
                        s_in = lo;
                        axis = k;
                    }
                    s_out = s_out.min(hi);
                }
                (s_in <= s_out && s_in > NEAR).then(|| {
                    let mut n = [0.0; 3];
                    n[axis] = -d[axis].signum();
                    (s_in, at(s_in), n)
                })
            }
            Shape::Quad(a, b) | Shape::Wing(a, b, _) => {
                if d[2] == 0.0 {
                    return None;
                }
                let s = -o[2] / d[2];
                let p = at(s);
                let (u, v) = (p[0] / a, p[1] / b);
                let inside = s > NEAR && u.abs() <= 1.0 && v.abs() <= 1.0;
                let kept = match self.shape {
                    Shape::Wing(_, _, side) => wing_lobes(u * side, v),
                    _ => true,
                };
                (inside && kept).then(|| (s, p, [0.0, 0.0, -d[2].signum()]))
            }
        }
    }
}

/// Fore- and hind-wing ellipses; u measured away from the hinge side.
fn wing_lobes(u: f64, v: f64) -> bool {
    let fore = (u - 0.05).powi(2) / 0.95f64.powi(2) + (v + 0.38).powi(2) / 0.62f64.powi(2) < 1.0;
    let hind = (u + 0.2).powi(2) / 0.75f64.powi(2) + (v - 0.5).powi(2) / 0.5f64.powi(2) < 1.0;
    fore || hind
}
