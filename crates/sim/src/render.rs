//! Analytic ray caster for the synthetic scenes: textured spheres, boxes, thin quads and
//! wing-shaped quads. It shares nothing with the splatting rasterizer, so ground truth cannot
//! inherit the rasterizer's bugs. One ray per pixel centre; the nearest hit wins.

use rayon::prelude::*;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RenderError {
    #[error("shape '{0}' is unknown; use sphere, box, quad or wing")]
    UnknownShape(String),
    #[error(
        "texture '{0}' is unknown; use solid, checker, wall, segments, wing, clock or feathers"
    )]
    UnknownTexture(String),
    #[error("{what} '{name}' needs {need} parameters, got {got}")]
    Params {
        what: &'static str,
        name: String,
        need: usize,
        got: usize,
    },
    #[error("{got} poses given for {prims} primitives")]
    PoseCount { got: usize, prims: usize },
}

type V3 = [f64; 3];

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Row-major 3x3 times vector.
fn mv(m: &[f64; 9], v: V3) -> V3 {
    [
        m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
        m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
        m[6] * v[0] + m[7] * v[1] + m[8] * v[2],
    ]
}

/// Transposed row-major 3x3 times vector.
fn mtv(m: &[f64; 9], v: V3) -> V3 {
    [
        m[0] * v[0] + m[3] * v[1] + m[6] * v[2],
        m[1] * v[0] + m[4] * v[1] + m[7] * v[2],
        m[2] * v[0] + m[5] * v[1] + m[8] * v[2],
    ]
}

/// Hits nearer than this are ignored (no shape reaches the camera).
const NEAR: f64 = 1e-3;
/// Lambert shading: ambient floor and the direction towards the light (world frame).
const AMBIENT: f64 = 0.45;
const LIGHT: V3 = [
    -0.3841106397986879,
    -0.6721936196476038,
    -0.5761659596980318,
];

#[derive(Clone, Debug)]
enum Shape {
    Sphere(f64),
    Box(V3),
    Quad(f64, f64),
    /// Quad whose [-1,1]² coordinates are cut to fore- and hind-wing lobes; side = ±1.
    Wing(f64, f64, f64),
}

type Rgb = [f32; 3];

#[derive(Clone, Debug)]
enum Texture {
    Solid(Rgb),
    Checker {
        cells: [f64; 2],
        scale: [f64; 2],
        axes: [usize; 2],
        a: Rgb,
        b: Rgb,
    },
    Wall {
        cell: f64,
        palette: Vec<Rgb>,
        table: Vec<u8>,
    },
    Segments {
        n_lon: f64,
        n_lat: f64,
        palette: Vec<Rgb>,
    },
    Wing {
        half: [f64; 2],
        side: f64,
    },
    Clock {
        half: [f64; 2],
    },
    Feathers,
}

#[derive(Clone, Debug)]
pub struct Primitive {
    shape: Shape,
    texture: Texture,
    moving: bool,
}

fn need(what: &'static str, name: &str, p: &[f64], n: usize) -> Result<(), RenderError> {
    if p.len() < n {
        return Err(RenderError::Params {
            what,
            name: name.into(),
            need: n,
            got: p.len(),
        });
    }
    Ok(())
}

fn rgb(p: &[f64]) -> Rgb {
    [p[0] as f32, p[1] as f32, p[2] as f32]
}

fn palette(p: &[f64]) -> Vec<Rgb> {
    p.chunks_exact(3).map(rgb).collect()
}

/// Tile colour table of the wall texture: a fixed 64x64 pseudo-random pattern per seed.
fn wall_table(seed: u64, colours: usize) -> Vec<u8> {
    (0..64 * 64)
        .map(|i| {
            (crate::rng::uniform(seed, 99, i as u64, 0) * colours as f64) as u8
                % colours.max(1) as u8
        })
        .collect()
}

impl Primitive {
    /// Build from names and flat parameter lists (see the Python scene library for each layout).
    pub fn new(
        shape: &str,
        size: &[f64],
        texture: &str,
        params: &[f64],
        moving: bool,
    ) -> Result<Self, RenderError> {
        let shape = match shape {
            "sphere" => need("shape", shape, size, 1).map(|_| Shape::Sphere(size[0]))?,
            "box" => {
                need("shape", shape, size, 3).map(|_| Shape::Box([size[0], size[1], size[2]]))?
            }
            "quad" => need("shape", shape, size, 2).map(|_| Shape::Quad(size[0], size[1]))?,
            "wing" => {
                need("shape", shape, size, 3).map(|_| Shape::Wing(size[0], size[1], size[2]))?
            }
            other => return Err(RenderError::UnknownShape(other.into())),
        };
        let p = params;
        let texture = match texture {
            "solid" => need("texture", texture, p, 3).map(|_| Texture::Solid(rgb(p)))?,
            "checker" => need("texture", texture, p, 12).map(|_| Texture::Checker {
                cells: [p[0], p[1]],
                scale: [p[2], p[3]],
                axes: [p[4] as usize % 3, p[5] as usize % 3],
                a: rgb(&p[6..9]),
                b: rgb(&p[9..12]),
            })?,
            "wall" => need("texture", texture, p, 5).map(|_| {
                let pal = palette(&p[2..]);
                let table = wall_table(p[1] as u64, pal.len());
                Texture::Wall {
                    cell: p[0],
                    palette: pal,
                    table,
                }
            })?,
            "segments" => need("texture", texture, p, 5).map(|_| Texture::Segments {
                n_lon: p[0],
                n_lat: p[1],
                palette: palette(&p[2..]),
            })?,
            "wing" => need("texture", texture, p, 3).map(|_| Texture::Wing {
                half: [p[0], p[1]],
                side: p[2],
            })?,
            "clock" => {
                need("texture", texture, p, 2).map(|_| Texture::Clock { half: [p[0], p[1]] })?
            }
            "feathers" => Texture::Feathers,
            other => return Err(RenderError::UnknownTexture(other.into())),
        };
        Ok(Primitive {
            shape,
            texture,
            moving,
        })
    }

    /// Nearest hit of the ray o + s d (object frame): (s, point, normal).
    fn intersect(&self, o: V3, d: V3) -> Option<(f64, V3, V3)> {
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

fn frac(x: f64) -> f64 {
    x - x.floor()
}

fn scale(c: Rgb, k: f64) -> Rgb {
    [c[0] * k as f32, c[1] * k as f32, c[2] * k as f32]
}

impl Texture {
    /// Colour at object-frame point p with object-frame normal n (linear RGB).
    fn colour(&self, p: V3, n: V3) -> Rgb {
        match self {
            Texture::Solid(c) => *c,
            Texture::Checker {
                cells,
                scale: sc,
                axes,
                a,
                b,
            } => {
                let u = (p[axes[0]] / sc[0] * cells[0]).floor();
                let v = (p[axes[1]] / sc[1] * cells[1]).floor();
                if (u + v).rem_euclid(2.0) == 0.0 {
                    *a
                } else {
                    *b
                }
            }
            Texture::Wall {
                cell,
                palette,
                table,
            } => {
                let (u, v) = (p[0] / cell, p[1] / cell);
                let (iu, iv) = (
                    (u.floor() as i64).rem_euclid(64),
                    (v.floor() as i64).rem_euclid(64),
                );
                let (fu, fv) = (frac(u), frac(v));
                let c = palette[table[(iv * 64 + iu) as usize] as usize];
                // Grout and stripes are darker shades of the tile: clear edges of moderate
                // contrast (~0.5-1 in log intensity, a few events per crossing).
                if fu < 0.06 || fv < 0.06 {
                    return scale(c, 0.35);
                }
                // Diagonal stripes in every third tile: edges in every orientation.
                if (iu + iv) % 3 == 0 && frac((fu + fv) * 4.0) < 0.5 {
                    scale(c, 0.6)
                } else {
                    c
                }
            }
            Texture::Segments {
                n_lon,
                n_lat,
                palette,
            } => {
                let r = dot(p, p).sqrt().max(1e-12);
                let lon = p[1].atan2(p[0]);
                let lat = (p[2] / r).clamp(-1.0, 1.0).asin();
                let seg = (((lon + std::f64::consts::PI) / std::f64::consts::TAU * n_lon).floor()
                    as usize)
                    % palette.len();
                let band = ((lat + std::f64::consts::FRAC_PI_2) / std::f64::consts::PI * n_lat)
                    .floor() as i64;
                if band % 2 == 0 {
                    palette[seg]
                } else {
                    scale(palette[seg], 0.55)
                }
            }
            Texture::Wing { half, side } => {
                let (u, v) = (p[0] / half[0] * side, p[1] / half[1]);
                let (r, ang) = ((u + 1.0).hypot(v), v.atan2(u + 1.0));
                let border = r > 1.55;
                if border && ((frac(u * 4.0) - 0.5).hypot(frac(v * 4.0) - 0.5) < 0.22) {
                    return [0.95, 0.95, 0.9]; // white spots in the black border
                }
                let vein = (frac(ang * 7.0 / std::f64::consts::PI) - 0.5).abs() < 0.07
                    || (r - 1.1).abs() < 0.05;
                if vein || border {
                    [0.12, 0.08, 0.06]
                } else {
                    [0.95, 0.45, 0.05]
                }
            }
            Texture::Clock { half } => {
                let front = n[2] < -0.5; // the dial faces -z in the clock's frame
                let (x, y) = (p[0] / half[0], p[1] / half[1]);
                let (r, ang) = (x.hypot(y), y.atan2(x));
                if front && (r - 0.9).abs() < 0.05 {
                    [0.85, 0.8, 0.4] // brass rim
                } else if front && r < 0.85 {
                    let tick =
                        r > 0.68 && (frac(ang * 6.0 / std::f64::consts::PI) - 0.5).abs() > 0.42;
                    if tick {
                        [0.12; 3]
                    } else {
                        [0.92, 0.92, 0.85]
                    }
                } else if !front && frac((p[0] + p[1]) * 10.0) < 0.3 {
                    [0.45, 0.03, 0.03]
                } else {
                    [0.75, 0.08, 0.06]
                }
            }
            Texture::Feathers => {
                let r = dot(p, p).sqrt().max(1e-12);
                let lon = p[2].atan2(p[0]);
                let lat = (p[1] / r).clamp(-1.0, 1.0).asin();
                let k = 6.0 / std::f64::consts::PI;
                if (frac(lon * k) < 0.5) ^ (frac(lat * k) < 0.5) {
                    [0.95, 0.78, 0.08]
                } else {
                    [0.8, 0.55, 0.04]
                }
            }
        }
    }
}

/// One rendered frame: linear RGB (H*W*3), camera-frame depth (0 where nothing is hit) and
/// the moving-object mask, all row-major.
pub struct Frame {
    pub rgb: Vec<f32>,
    pub depth: Vec<f32>,
    pub mask: Vec<bool>,
}

/// A rigid pose as row-major rotation + translation (object-to-world or camera-to-world).
#[derive(Clone, Copy, Debug)]
pub struct Pose {
    pub r: [f64; 9],
    pub t: V3,
}

/// Render `prims` at their object-to-world `poses` seen from camera `c2w` with intrinsics
/// (fx, fy, cx, cy) and size width x height. Rays go through pixel centres (j+0.5, i+0.5).
pub fn render(
    prims: &[Primitive],
    poses: &[Pose],
    c2w: Pose,
    k: [f64; 4],
    width: usize,
    height: usize,
) -> Result<Frame, RenderError> {
    if poses.len() != prims.len() {
        return Err(RenderError::PoseCount {
            got: poses.len(),
            prims: prims.len(),
        });
    }
    let [fx, fy, cx, cy] = k;
    let n = width * height;
    let mut rgb = vec![0f32; n * 3];
    let mut depth = vec![0f32; n];
    let mut mask = vec![false; n];
    rgb.par_chunks_mut(width * 3)
        .zip(depth.par_chunks_mut(width))
        .zip(mask.par_chunks_mut(width))
        .enumerate()
        .for_each(|(i, ((rgb_row, depth_row), mask_row))| {
            // Camera origin in each object frame is the same for the whole row.
            let origins: Vec<V3> = poses.iter().map(|p| mtv(&p.r, sub(c2w.t, p.t))).collect();
            for j in 0..width {
                let dc = [(j as f64 + 0.5 - cx) / fx, (i as f64 + 0.5 - cy) / fy, 1.0];
                let dw = mv(&c2w.r, dc);
                let mut best: Option<(f64, usize, V3, V3)> = None;
                for (kp, (prim, pose)) in prims.iter().zip(poses).enumerate() {
                    let dl = mtv(&pose.r, dw);
                    if let Some((s, p, nrm)) = prim.intersect(origins[kp], dl) {
                        if best.is_none_or(|b| s < b.0) {
                            best = Some((s, kp, p, nrm));
                        }
                    }
                }
                if let Some((s, kp, p, nrm)) = best {
                    let prim = &prims[kp];
                    let nw = mv(&poses[kp].r, nrm);
                    let shade = AMBIENT + (1.0 - AMBIENT) * dot(nw, LIGHT).max(0.0);
                    let c = prim.texture.colour(p, nrm);
                    for ch in 0..3 {
                        rgb_row[j * 3 + ch] = (c[ch].clamp(0.0, 1.0) as f64 * shade) as f32;
                    }
                    // The camera-frame ray has z = 1, so the ray parameter is the depth.
                    depth_row[j] = s as f32;
                    mask_row[j] = prim.moving;
                }
            }
        });
    Ok(Frame { rgb, depth, mask })
}

#[cfg(test)]
mod tests {
    use super::*;

    const ID: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

    #[test]
    fn sphere_depth_matches_the_analytic_surface() {
        let prim = Primitive::new("sphere", &[1.0], "solid", &[1.0, 1.0, 1.0], true).unwrap();
        let pose = Pose {
            r: ID,
            t: [0.0, 0.0, 5.0],
        };
        let cam = Pose { r: ID, t: [0.0; 3] };
        let f = render(&[prim], &[pose], cam, [10.0, 10.0, 8.0, 8.0], 16, 16).unwrap();
        for i in 0..16 {
            for j in 0..16 {
                let (x, y) = ((j as f64 + 0.5 - 8.0) / 10.0, (i as f64 + 0.5 - 8.0) / 10.0);
                // |s (x, y, 1) - (0,0,5)|^2 = 1  ->  s^2 (x^2+y^2+1) - 10 s + 24 = 0
                let a = x * x + y * y + 1.0;
                let disc = 25.0 - 24.0 * a;
                let want = if disc > 0.0 {
                    (5.0 - disc.sqrt()) / a
                } else {
                    0.0
                };
                assert!((f.depth[i * 16 + j] as f64 - want).abs() < 1e-5);
                assert_eq!(f.mask[i * 16 + j], disc > 0.0);
            }
        }
    }

    #[test]
    fn nearer_box_occludes_the_quad_behind_it() {
        let quad = Primitive::new("quad", &[10.0, 10.0], "solid", &[0.2, 0.2, 0.2], false).unwrap();
        let cube =
            Primitive::new("box", &[0.5, 0.5, 0.5], "solid", &[1.0, 0.0, 0.0], true).unwrap();
        let poses = [
            Pose {
                r: ID,
                t: [0.0, 0.0, 4.0],
            },
            Pose {
                r: ID,
                t: [0.0, 0.0, 2.0],
            },
        ];
        let cam = Pose { r: ID, t: [0.0; 3] };
        let f = render(&[quad, cube], &poses, cam, [4.0, 4.0, 4.0, 4.0], 8, 8).unwrap();
        assert!((f.depth[4 * 8 + 4] - 1.5).abs() < 1e-6); // front face of the cube
        assert!((f.depth[0] - 4.0).abs() < 1e-6); // wall at the corner
        assert!(f.mask[4 * 8 + 4] && !f.mask[0]);
    }
}
