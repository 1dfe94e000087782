//! Building primitives from shape and texture names and flat parameter lists.

use super::shape::Shape;
use super::texture::{Blob, Rgb, Texture};
use super::{Primitive, RenderError};

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
/// Blob widths below this are treated as this (a zero width would divide by zero).
const MIN_BLOB_SIGMA: f64 = 1e-9;

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
}
