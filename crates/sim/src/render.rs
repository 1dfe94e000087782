//! Analytic ray caster for the synthetic scenes: textured spheres, boxes, thin quads and
//! wing-shaped quads. It shares nothing with the splatting rasterizer, so ground truth cannot
//! inherit the rasterizer's bugs. One ray per pixel centre; the nearest hit wins.

use rayon::prelude::*;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RenderError {
    #[error("shape '{0}' is unknown; use sphere, box, quad or wing")]
    UnknownShape(String),
    #[error(
        "texture '{0}' is unknown; use solid, checker, wall, segments, wing, clock, feathers, \
         noise or blobs"
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
    /// Value noise per colour channel, mapped to base ± amp (see `value_noise`).
    Noise {
        seed: u64,
        freq: f64,
        octaves: u32,
        base: [f64; 3],
        amp: [f64; 3],
    },
    /// Gaussian colour blobs in the object x-y plane, blended in order over a base colour.
    Blobs {
        base: [f64; 3],
        blobs: Vec<Blob>,
    },
}

#[derive(Clone, Debug)]
struct Blob {
    centre: [f64; 2],
    sigma: f64,
    colour: [f64; 3],
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
    rgb64(p).map(|v| v as f32)
}

fn palette(p: &[f64]) -> Vec<Rgb> {
    p.chunks_exact(3).map(rgb).collect()
}

fn rgb64(p: &[f64]) -> [f64; 3] {
    [p[0], p[1], p[2]]
}

/// More octaves than this add detail far below a pixel and only cost time.
const MAX_OCTAVES: u32 = 8;
/// Keyed random stream of the noise lattice (octave o uses NOISE_STREAM + o).
const NOISE_STREAM: u64 = 1000;
/// Blob widths below this are treated as this (a zero width would divide by zero).
const MIN_BLOB_SIGMA: f64 = 1e-9;

/// Lattice values in [0, 1) of the three colour channels at integer point (ix, iy, iz):
/// one 64-bit hash split into three 21-bit fractions, so the channels are independent.
fn lattice(seed: u64, octave: u32, ix: i64, iy: i64, iz: i64) -> [f64; 3] {
    // Wrapping casts: coordinates beyond ±2^31 cells alias, far outside any scene.
    let yz = ((iy as u32 as u64) << 32) | iz as u32 as u64;
    let h = crate::rng::bits(seed, NOISE_STREAM + octave as u64, ix as u64, yz);
    let unit = 1.0 / (1u64 << 21) as f64;
    [0, 1, 2].map(|c| ((h >> (21 * c)) & 0x1F_FFFF) as f64 * unit)
}

fn smoothstep(t: f64) -> f64 {
    t * t * (3.0 - 2.0 * t)
}

/// Fractal value noise at object-frame point p, per colour channel, in [0, 1]: octave o has
/// lattice spacing 1 / (freq 2^o) and weight 2^-o; values at lattice points are hashed from
/// (seed, o, cell) and blended with smoothstep weights (continuous, with continuous slope).
/// The sum is divided by the total weight, so each channel's mean is 1/2 for any parameters.
fn value_noise(seed: u64, freq: f64, octaves: u32, p: V3) -> [f64; 3] {
    let (mut acc, mut total) = ([0.0; 3], 0.0);
    for o in 0..octaves {
        let f = freq * (1u64 << o) as f64;
        let weight = 0.5f64.powi(o as i32);
        let q = [p[0] * f, p[1] * f, p[2] * f];
        let cell = q.map(f64::floor);
        let t = [0, 1, 2].map(|k| smoothstep(q[k] - cell[k]));
        for corner in 0..8 {
            let pick = |k: usize| (corner >> k) & 1 == 1;
            let w = (0..3)
                .map(|k| if pick(k) { t[k] } else { 1.0 - t[k] })
                .product::<f64>();
            // On a plane through lattice points (a quad's z = 0) half the corners weigh 0.
            if w == 0.0 {
                continue;
            }
            let at = |k: usize| cell[k] as i64 + pick(k) as i64;
            let h = lattice(seed, o, at(0), at(1), at(2));
            for (a, v) in acc.iter_mut().zip(h) {
                *a += weight * w * v;
            }
        }
        total += weight;
    }
    acc.map(|a| a / total)
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
            "noise" => need("texture", texture, p, 9).map(|_| Texture::Noise {
                seed: p[0] as u64,
                freq: p[1],
                octaves: (p[2] as u32).clamp(1, MAX_OCTAVES),
                base: rgb64(&p[3..6]),
                amp: rgb64(&p[6..9]),
            })?,
            "blobs" => need("texture", texture, p, 9).map(|_| Texture::Blobs {
                base: rgb64(p),
                blobs: p[3..]
                    .chunks_exact(6)
                    .map(|b| Blob {
                        centre: [b[0], b[1]],
                        sigma: b[2].max(MIN_BLOB_SIGMA),
                        colour: rgb64(&b[3..6]),
                    })
                    .collect(),
            })?,
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
            Texture::Noise {
                seed,
                freq,
                octaves,
                base,
                amp,
            } => {
                let v = value_noise(*seed, *freq, *octaves, p);
                [0, 1, 2].map(|c| (base[c] + amp[c] * (2.0 * v[c] - 1.0)).clamp(0.0, 1.0) as f32)
            }
            Texture::Blobs { base, blobs } => {
                let mut c = *base;
                for b in blobs {
                    let r2 = (p[0] - b.centre[0]).powi(2) + (p[1] - b.centre[1]).powi(2);
                    let w = (-r2 / (2.0 * b.sigma * b.sigma)).exp();
                    // A convex blend per blob: the result stays within the given colours.
                    for (v, target) in c.iter_mut().zip(b.colour) {
                        *v += w * (target - *v);
                    }
                }
                c.map(|v| v as f32)
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

    fn texture(name: &str, params: &[f64]) -> Texture {
        Primitive::new("quad", &[1.0, 1.0], name, params, false)
            .unwrap()
            .texture
    }

    fn colour64(t: &Texture, p: V3) -> [f64; 3] {
        t.colour(p, [0.0, 0.0, -1.0]).map(|c| c as f64)
    }

    /// seed 7, 4 cells per metre, `octaves`, base 0.5 grey, amplitude 0.4.
    fn grey_noise(seed: f64, octaves: f64) -> Texture {
        texture("noise", &[seed, 4.0, octaves, 0.5, 0.5, 0.5, 0.4, 0.4, 0.4])
    }

    /// base + amp (2 v - 1) for lattice value v, as the texture maps it.
    fn mapped(v: f64) -> f64 {
        0.5 + 0.4 * (2.0 * v - 1.0)
    }

    #[test]
    fn noise_is_the_hashed_lattice_value_at_lattice_points_and_their_mean_halfway() {
        let t = grey_noise(7.0, 1.0);
        // Lattice points (spacing 1/4 m) hold their hashed values exactly.
        let corner = |i: i64, j: i64, k: i64| lattice(7, 0, i, j, k).map(mapped);
        for (i, j, k) in [(0, 0, 0), (3, -2, 0), (-5, 4, 1)] {
            let p = [i as f64 / 4.0, j as f64 / 4.0, k as f64 / 4.0];
            let (got, want) = (colour64(&t, p), corner(i, j, k));
            for c in 0..3 {
                assert!((got[c] - want[c]).abs() < 1e-6, "{got:?} vs {want:?}");
            }
        }
        // Halfway along a lattice edge smoothstep(1/2) = 1/2: the mean of the two ends.
        let (got, a, b) = (
            colour64(&t, [2.5 / 4.0, 1.0 / 4.0, 0.0]),
            corner(2, 1, 0),
            corner(3, 1, 0),
        );
        for c in 0..3 {
            assert!((got[c] - (a[c] + b[c]) / 2.0).abs() < 1e-6);
        }
    }

    #[test]
    fn noise_is_centred_on_its_base_within_its_amplitude_and_slope_bound() {
        let octaves = 3;
        let t = grey_noise(7.0, octaves as f64);
        // |d noise / dx| <= 1.5 f sum_o 2^o 2^-o / sum_o 2^-o (smoothstep slope <= 1.5).
        let weights: f64 = (0..octaves).map(|o| 0.5f64.powi(o)).sum();
        let slope = 2.0 * 0.4 * 1.5 * 4.0 * octaves as f64 / weights;
        let (n, h) = (20_000u64, 1e-5);
        let (mut sum, mut lo, mut hi, mut steepest) = ([0.0; 3], 1.0f64, 0.0f64, 0.0f64);
        for i in 0..n {
            let u = |s: u64| (crate::rng::uniform(3, s, i, 0) - 0.5) * 20.0;
            let p = [u(1), u(2), u(3)];
            let c = colour64(&t, p);
            let dx = colour64(&t, [p[0] + h, p[1], p[2]]);
            for ch in 0..3 {
                sum[ch] += c[ch];
                (lo, hi) = (lo.min(c[ch]), hi.max(c[ch]));
                steepest = steepest.max((dx[ch] - c[ch]).abs() / h);
            }
        }
        for s in sum {
            assert!((s / n as f64 - 0.5).abs() < 0.01, "mean {}", s / n as f64);
        }
        assert!(lo >= 0.1 - 1e-6 && hi <= 0.9 + 1e-6, "range {lo}..{hi}");
        assert!(
            hi - lo > 0.4,
            "range {lo}..{hi} is too narrow to be a texture"
        );
        assert!(
            steepest <= slope * 1.001,
            "slope {steepest} > bound {slope}"
        );
    }

    #[test]
    fn noise_is_fixed_by_its_seed() {
        let p = [0.37, -1.21, 0.05];
        let (a, b, c) = (
            grey_noise(7.0, 2.0),
            grey_noise(7.0, 2.0),
            grey_noise(8.0, 2.0),
        );
        assert_eq!(colour64(&a, p), colour64(&b, p));
        assert_ne!(colour64(&a, p), colour64(&c, p));
    }

    #[test]
    fn blobs_blend_gaussians_over_the_base_in_order() {
        // Black base; a white blob (sigma 1) at the origin, then a red one (sigma 0.5) at x = 3.
        let t = texture(
            "blobs",
            &[
                0.0, 0.0, 0.0, //
                0.0, 0.0, 1.0, 1.0, 1.0, 1.0, //
                3.0, 0.0, 0.5, 1.0, 0.0, 0.0,
            ],
        );
        let white = |r2: f64| (-r2 / 2.0).exp();
        let red = |r2: f64| (-r2 / 0.5).exp();
        for (x, y) in [(0.0, 0.0), (1.0, 0.0), (0.6, -0.8), (2.0, 1.0), (3.0, 0.0)] {
            let (w1, w2) = (white(x * x + y * y), red((x - 3.0) * (x - 3.0) + y * y));
            let want = [w1 + w2 * (1.0 - w1), w1 * (1.0 - w2), w1 * (1.0 - w2)];
            let got = colour64(&t, [x, y, 0.0]);
            for c in 0..3 {
                assert!(
                    (got[c] - want[c]).abs() < 1e-6,
                    "({x}, {y}): {got:?} vs {want:?}"
                );
            }
        }
        // One sigma from the white blob's centre: exp(-1/2) of the way from black to white.
        assert!((colour64(&t, [0.0, 1.0, 0.0])[1] - 0.606_530_66).abs() < 1e-6);
    }

    #[test]
    fn noise_and_blobs_with_too_few_parameters_are_one_line_errors() {
        for (name, got) in [("noise", 8), ("blobs", 4)] {
            let err = Primitive::new("quad", &[1.0, 1.0], name, &vec![0.5; got], false)
                .unwrap_err()
                .to_string();
            assert_eq!(
                err,
                format!("texture '{name}' needs 9 parameters, got {got}")
            );
        }
    }
}
