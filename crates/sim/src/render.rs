//! Analytic ray caster for the synthetic scenes: textured spheres, boxes, thin quads and
//! wing-shaped quads. It shares nothing with the splatting rasterizer, so ground truth cannot
//! inherit the rasterizer's bugs. The nearest hit wins. A pixel's colour is the mean of an n x n
//! grid of rays over its area (a real pixel integrates the light that falls on it, and Blender,
//! which renders the paper's scenes, filters over the pixel too); depth and the moving mask are
//! the centre ray's, so they stay exact.

use rayon::prelude::*;

mod noise;
mod params;
mod shape;
mod texture;

use shape::Shape;
use texture::Texture;

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
    #[error("{0} samples per pixel side: use an odd number from 1 to {MAX_SAMPLES}")]
    Samples(usize),
}

/// Most rays per pixel side (a 9x9 grid): beyond it the cost grows with no visible change.
pub const MAX_SAMPLES: usize = 9;

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

/// Lambert shading: ambient floor and the direction towards the light (world frame).
const AMBIENT: f64 = 0.45;
const LIGHT: V3 = [
    -0.3841106397986879,
    -0.6721936196476038,
    -0.5761659596980318,
];

#[derive(Clone, Debug)]
pub struct Primitive {
    shape: Shape,
    texture: Texture,
    moving: bool,
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
/// (fx, fy, cx, cy) and size width x height. Each pixel's colour is the mean of `samples` x
/// `samples` rays through the centres of a regular grid over the pixel (`samples` odd, so the
/// middle ray goes through the pixel centre (j+0.5, i+0.5); 1 = that ray alone); depth and
/// mask are the middle ray's.
pub fn render(
    prims: &[Primitive],
    poses: &[Pose],
    c2w: Pose,
    k: [f64; 4],
    size: (usize, usize),
    samples: usize,
) -> Result<Frame, RenderError> {
    if poses.len() != prims.len() {
        return Err(RenderError::PoseCount {
            got: poses.len(),
            prims: prims.len(),
        });
    }
    if samples.is_multiple_of(2) || samples > MAX_SAMPLES {
        return Err(RenderError::Samples(samples));
    }
    let (width, height) = size;
    let [fx, fy, cx, cy] = k;
    let n = width * height;
    let mut rgb = vec![0f32; n * 3];
    let mut depth = vec![0f32; n];
    let mut mask = vec![false; n];
    let offsets: Vec<f64> = (0..samples)
        .map(|s| (s as f64 + 0.5) / samples as f64)
        .collect();
    let weight = 1.0 / (samples * samples) as f64;
    let middle = samples / 2;
    rgb.par_chunks_mut(width * 3)
        .zip(depth.par_chunks_mut(width))
        .zip(mask.par_chunks_mut(width))
        .enumerate()
        .for_each(|(i, ((rgb_row, depth_row), mask_row))| {
            // Camera origin in each object frame is the same for the whole row.
            let origins: Vec<V3> = poses.iter().map(|p| mtv(&p.r, sub(c2w.t, p.t))).collect();
            let scene = Scene {
                prims,
                poses,
                origins: &origins,
                c2w: &c2w,
            };
            for j in 0..width {
                let mut colour = [0f64; 3];
                for (a, &oy) in offsets.iter().enumerate() {
                    for (b, &ox) in offsets.iter().enumerate() {
                        let dc = [(j as f64 + ox - cx) / fx, (i as f64 + oy - cy) / fy, 1.0];
                        let Some((s, kp, c)) = scene.cast(dc) else {
                            continue;
                        };
                        for ch in 0..3 {
                            colour[ch] += c[ch] * weight;
                        }
                        if a == middle && b == middle {
                            // The camera-frame ray has z = 1, so the ray parameter is the depth.
                            depth_row[j] = s as f32;
                            mask_row[j] = prims[kp].moving;
                        }
                    }
                }
                for ch in 0..3 {
                    rgb_row[j * 3 + ch] = colour[ch] as f32;
                }
            }
        });
    Ok(Frame { rgb, depth, mask })
}

/// The primitives at their poses, seen from one camera (object-frame camera origins cached).
struct Scene<'a> {
    prims: &'a [Primitive],
    poses: &'a [Pose],
    origins: &'a [V3],
    c2w: &'a Pose,
}

impl Scene<'_> {
    /// The nearest hit of the camera-frame ray direction `dc`: (ray parameter, primitive, shaded
    /// colour), or None when it hits nothing.
    fn cast(&self, dc: V3) -> Option<(f64, usize, [f64; 3])> {
        let dw = mv(&self.c2w.r, dc);
        let mut best: Option<(f64, usize, V3, V3)> = None;
        for (kp, (prim, pose)) in self.prims.iter().zip(self.poses).enumerate() {
            let dl = mtv(&pose.r, dw);
            if let Some((s, p, nrm)) = prim.intersect(self.origins[kp], dl) {
                if best.is_none_or(|b| s < b.0) {
                    best = Some((s, kp, p, nrm));
                }
            }
        }
        let (s, kp, p, nrm) = best?;
        let nw = mv(&self.poses[kp].r, nrm);
        let shade = AMBIENT + (1.0 - AMBIENT) * dot(nw, LIGHT).max(0.0);
        let c = self.prims[kp].texture.colour(p, nrm);
        Some((s, kp, c.map(|v| v.clamp(0.0, 1.0) as f64 * shade)))
    }
}

#[cfg(test)]
mod tests {
    use super::noise::lattice;
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
        let f = render(&[prim], &[pose], cam, [10.0, 10.0, 8.0, 8.0], (16, 16), 1).unwrap();
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
        let f = render(&[quad, cube], &poses, cam, [4.0, 4.0, 4.0, 4.0], (8, 8), 1).unwrap();
        assert!((f.depth[4 * 8 + 4] - 1.5).abs() < 1e-6); // front face of the cube
        assert!((f.depth[0] - 4.0).abs() < 1e-6); // wall at the corner
        assert!(f.mask[4 * 8 + 4] && !f.mask[0]);
    }

    /// A textured sphere in front of a textured wall, seen a little off-axis.
    fn edge_scene() -> (Vec<Primitive>, Vec<Pose>, Pose) {
        // checker: cells u, v; scale u, v; axes u, v; colours a, b.
        let wall_tex = [3.0, 8.0, 1.0, 1.0, 0.0, 1.0, 0.9, 0.2, 0.1, 0.1, 0.3, 0.8];
        let ball_tex = [5.0, 6.0, 1.0, 1.0, 0.0, 1.0, 1.0, 0.9, 0.0, 0.1, 0.5, 1.0];
        let wall = Primitive::new("quad", &[10.0, 10.0], "checker", &wall_tex, false).unwrap();
        let ball = Primitive::new("sphere", &[0.7], "checker", &ball_tex, true).unwrap();
        let at = |t: V3| Pose { r: ID, t };
        (
            vec![wall, ball],
            vec![at([0.0, 0.0, 4.0]), at([0.3, -0.2, 2.5])],
            at([0.05, 0.0, 0.0]),
        )
    }

    #[test]
    fn a_pixel_is_the_mean_of_centre_rays_through_its_sub_pixel_grid() {
        // Oracle: the ray at sub-pixel offset (ox, oy) of pixel (i, j) is the centre ray of a
        // one-sample render whose principal point moved by (0.5 - ox, 0.5 - oy).
        let (prims, poses, cam) = edge_scene();
        let (k, n) = ([14.0, 14.0, 10.0, 9.0], 3);
        let f = render(&prims, &poses, cam, k, (20, 18), n).unwrap();
        let mut want = vec![0f64; 20 * 18 * 3];
        for a in 0..n {
            for b in 0..n {
                let (ox, oy) = ((b as f64 + 0.5) / n as f64, (a as f64 + 0.5) / n as f64);
                let shifted = [k[0], k[1], k[2] + 0.5 - ox, k[3] + 0.5 - oy];
                let g = render(&prims, &poses, cam, shifted, (20, 18), 1).unwrap();
                for (w, v) in want.iter_mut().zip(&g.rgb) {
                    *w += *v as f64 / (n * n) as f64;
                }
            }
        }
        let centre = render(&prims, &poses, cam, k, (20, 18), 1).unwrap();
        assert!(f
            .rgb
            .iter()
            .zip(&want)
            .all(|(a, b)| (*a as f64 - b).abs() < 1e-5));
        // Depth and mask are the centre ray's; edges (and only edges) mix colours.
        assert_eq!(f.depth, centre.depth);
        assert_eq!(f.mask, centre.mask);
        let mixed = f
            .rgb
            .iter()
            .zip(&centre.rgb)
            .filter(|(a, b)| (*a - *b).abs() > 1e-3);
        assert!(mixed.count() > 20);
    }

    #[test]
    fn even_or_too_many_samples_are_an_error() {
        let (prims, poses, cam) = edge_scene();
        for n in [0, 2, MAX_SAMPLES + 2] {
            let got = render(&prims, &poses, cam, [4.0, 4.0, 4.0, 4.0], (8, 8), n);
            assert_eq!(got.err(), Some(RenderError::Samples(n)));
        }
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
