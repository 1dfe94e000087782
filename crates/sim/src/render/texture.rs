//! Surface textures: colour at an object-frame point.

use super::noise::value_noise;
use super::{dot, V3};

pub(super) type Rgb = [f32; 3];

#[derive(Clone, Debug)]
pub(super) enum Texture {
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
pub(super) struct Blob {
    pub(super) centre: [f64; 2],
    pub(super) sigma: f64,
    pub(super) colour: [f64; 3],
}

fn frac(x: f64) -> f64 {
    x - x.floor()
}

fn scale(c: Rgb, k: f64) -> Rgb {
    [c[0] * k as f32, c[1] * k as f32, c[2] * k as f32]
}

impl Texture {
    /// Colour at object-frame point p with object-frame normal n (linear RGB).
    pub(super) fn colour(&self, p: V3, n: V3) -> Rgb {
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
