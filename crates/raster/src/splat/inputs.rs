//! What a render is asked for: the Gaussians and the camera, checked at the boundary, and the
//! uniforms (`Params`) every pass reads.

use super::buffers::GRAD_HEAD;
use super::{MAX_FEATURES, TILE};
use crate::context::GpuError;
use crate::wgsl::Params;

/// Pinhole camera: world->camera `viewmat` (row-major 4x4), intrinsics `k` (row-major 3x3).
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub viewmat: [f32; 16],
    pub k: [f32; 9],
    pub width: u32,
    pub height: u32,
    pub near: f32,
    pub far: f32,
}

/// The Gaussians to render, as flat row-major arrays.
#[derive(Clone, Copy, Debug)]
pub struct Gaussians<'a> {
    pub means: &'a [f32],
    pub quats: &'a [f32],
    pub scales: &'a [f32],
    pub opacities: &'a [f32],
    pub features: &'a [f32],
    pub d: usize,
    pub background: &'a [f32],
}

impl Gaussians<'_> {
    pub fn len(&self) -> usize {
        self.opacities.len()
    }

    pub fn is_empty(&self) -> bool {
        self.opacities.is_empty()
    }

    pub(super) fn check(&self) -> Result<(), GpuError> {
        let n = self.len();
        let bad = |what: &str, got: usize, want: usize| {
            GpuError::Invalid(format!(
                "rasterize: {what} has {got} values, expected {want} for {n} Gaussians with {} features",
                self.d
            ))
        };
        if self.d == 0 || self.d > MAX_FEATURES {
            return Err(GpuError::Invalid(format!(
                "rasterize: features have {} channels; 1 to {MAX_FEATURES} are supported",
                self.d
            )));
        }
        for (what, got, want) in [
            ("means", self.means.len(), 3 * n),
            ("quats", self.quats.len(), 4 * n),
            ("scales", self.scales.len(), 3 * n),
            ("features", self.features.len(), self.d * n),
            ("background", self.background.len(), self.d),
        ] {
            if got != want {
                return Err(bad(what, got, want));
            }
        }
        if n >= (u32::MAX / 16) as usize {
            return Err(GpuError::Invalid(format!(
                "rasterize: {n} Gaussians are too many"
            )));
        }
        Ok(())
    }

    /// The inputs in the order they lie back to back in the inputs buffer (at the offsets
    /// recorded in `Params`).
    pub(super) fn parts(&self) -> [&[f32]; 6] {
        [
            self.means,
            self.quats,
            self.scales,
            self.opacities,
            self.features,
            self.background,
        ]
    }
}

impl Camera {
    pub(super) fn check(&self) -> Result<(), GpuError> {
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            return Err(GpuError::Invalid(format!(
                "rasterize: image size {}x{} must be 1..16384 on each side",
                self.width, self.height
            )));
        }
        if !(self.near > 0.0 && self.far > self.near) {
            return Err(GpuError::Invalid(format!(
                "rasterize: need 0 < near < far, got near={} far={}",
                self.near, self.far
            )));
        }
        let (fx, fy) = (self.k[0], self.k[4]);
        if !(fx > 0.0 && fy > 0.0) {
            return Err(GpuError::Invalid(format!(
                "rasterize: K must have positive focal lengths, got fx={fx} fy={fy}"
            )));
        }
        Ok(())
    }

    pub fn tiles(&self) -> (u32, u32) {
        (self.width.div_ceil(TILE), self.height.div_ceil(TILE))
    }

    /// Bands of whole tile rows, each with at most `max_rows` pixel rows (a multiple of TILE);
    /// one band when the whole image fits, even when its height is not a multiple of TILE (the
    /// partial last tile row on its own would take a second render state).
    pub(super) fn bands(&self, max_rows: u32) -> Vec<Band> {
        let tiles_y = self.tiles().1;
        let step = if max_rows >= self.height {
            tiles_y.max(1)
        } else {
            (max_rows / TILE).max(1)
        };
        (0..tiles_y)
            .step_by(step as usize)
            .map(|ty0| Band {
                ty0,
                rows: (self.height - ty0 * TILE).min(step * TILE),
            })
            .collect()
    }
}

/// Rows of the image rendered on their own, as an image of those rows: tile rows from `ty0`,
/// `rows` pixel rows (whole tiles but at the image's bottom edge). Large renders are split into
/// bands when their per-pixel or tile-pair buffers would exceed the storage-binding limit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Band {
    pub ty0: u32,
    pub rows: u32,
}

impl Band {
    /// The two halves (by tile rows) of a band of at least two tile rows.
    pub(super) fn split(self) -> Option<[Band; 2]> {
        let tile_rows = self.rows.div_ceil(TILE);
        let top = tile_rows / 2;
        (top > 0).then(|| {
            [
                Band {
                    ty0: self.ty0,
                    rows: top * TILE,
                },
                Band {
                    ty0: self.ty0 + top,
                    rows: self.rows - top * TILE,
                },
            ]
        })
    }

    /// Pixels of the band in an image `width` wide, and its first pixel's index in the image.
    pub(super) fn pixels(self, width: u32) -> (usize, usize) {
        let w = width as usize;
        (self.rows as usize * w, (self.ty0 * TILE) as usize * w)
    }
}

/// The uniforms of every pass for `n` Gaussians with `d` channels seen from `cam`, rendering
/// `band` of its rows, with room for `cap` tile intersections.
pub(super) fn params(n: usize, d: usize, cam: &Camera, band: Band, cap: u64) -> Params {
    let (n, d) = (n as u32, d as u32);
    let (tiles_x, image_tiles_y) = cam.tiles();
    let mut view = [0f32; 16];
    // Row-major 4x4 in, column-major mat4x4 out.
    for r in 0..4 {
        for c in 0..4 {
            view[4 * c + r] = cam.viewmat[4 * r + c];
        }
    }
    let (fx, fy, cx, cy) = (cam.k[0], cam.k[4], cam.k[2], cam.k[5]);
    let (w, h) = (cam.width as f32, cam.height as f32);
    // gsplat's guard band: 30% of the half field of view beyond each image edge.
    let (tan_x, tan_y) = (0.5 * w / fx, 0.5 * h / fy);
    Params {
        view,
        fx,
        fy,
        cx,
        cy,
        near: cam.near,
        far: cam.far,
        lim_x_pos: (w - cx) / fx + 0.3 * tan_x,
        lim_x_neg: cx / fx + 0.3 * tan_x,
        lim_y_pos: (h - cy) / fy + 0.3 * tan_y,
        lim_y_neg: cy / fy + 0.3 * tan_y,
        width: cam.width,
        height: band.rows,
        n,
        d,
        tiles_x,
        tiles_y: band.rows.div_ceil(TILE),
        cap: cap as u32,
        off_quats: 3 * n,
        off_scales: 7 * n,
        off_opac: 10 * n,
        off_feat: 11 * n,
        off_bg: (11 + d) * n,
        grad_stride: GRAD_HEAD as u32 + d,
        band_ty0: band.ty0,
        image_tiles_y,
        _pad0: 0,
        _pad1: 0,
        _pad2: 0,
    }
}
