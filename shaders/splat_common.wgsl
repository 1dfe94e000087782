// Shared by every splatting pass: crates/raster/src/splat/mod.rs prepends the files a pass
// names on its first line ("// prelude: splat_common.wgsl ..."). This one holds the per-call
// parameters and the numerical guards, each named once. Every pass binds `params`.

struct Params {
    view: mat4x4<f32>, // world -> camera, column-major
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    near: f32,
    far: f32,
    lim_x_pos: f32, // guard band of the frustum for the EWA Jacobian, in x/z units
    lim_x_neg: f32,
    lim_y_pos: f32,
    lim_y_neg: f32,
    width: u32,
    height: u32,
    n: u32, // Gaussians
    d: u32, // feature channels
    tiles_x: u32,
    tiles_y: u32,
    cap: u32, // capacity of the tile-intersection buffers
    off_quats: u32, // offsets into `inputs` (means start at 0)
    off_scales: u32,
    off_opac: u32,
    off_feat: u32,
    off_bg: u32,
    grad_stride: u32, // floats per Gaussian in the gradient buffer: 8 + d
    _pad: u32,
}

const TILE: u32 = 16u;
// Feature channels. The pipelines are built once per channel count with this constant set to it
// (crates/raster/src/splat/mod.rs), so per-pixel channel loops unroll into registers; 32 (the
// maximum) is what the file says for validation.
const D: u32 = 32u;
// 3DGS guards.
const LOW_PASS: f32 = 0.3; // px^2 added to the 2-D covariance diagonal (anti-aliasing, det > 0)
const ALPHA_MIN: f32 = 0.00392156862745098; // 1/255: fainter fragments are skipped
const ALPHA_MAX: f32 = 0.99; // alpha clamp: keeps 1/(1 - alpha) finite in the backward pass
const T_MIN: f32 = 1e-4; // stop compositing once transmittance would fall below this
const POWER_CUT: f32 = -4.5; // -0.5 * 3^2: nothing beyond 3 sigma, so the 3-sigma tile bbox is exact
const MAX_VAR_PX: f32 = 1e12; // cull 2-D variances beyond (1e6 px)^2: keeps the determinant finite
const QUAT_EPS2: f32 = 1e-12; // squared-norm floor when normalising quaternions
const ALPHA_EPS: f32 = 1e-6; // depth = sum(w z) / alpha only where alpha exceeds this, else 0
const CULLED_KEY: u32 = 0xffffffffu;
// Compositing: a 16x4 workgroup covers a 16x16 tile, each invocation PX pixels (rows y, y+4,
// y+8, y+12), so every Gaussian loaded from the tile list serves PX pixels.
const PX: u32 = 4u;

// Pixel row of an invocation's j-th pixel in its tile.
fn tile_row(tile_y: u32, local_y: u32, j: u32) -> u32 {
    return tile_y * TILE + local_y + 4u * j;
}

// Exponent of a splat at offset dd = mean2d - pixel centre with conic (a, b, c) in co.xyz.
fn splat_power(co: vec4<f32>, dd: vec2<f32>) -> f32 {
    return -0.5 * (co.x * dd.x * dd.x + co.z * dd.y * dd.y) - co.y * dd.x * dd.y;
}

// Tile rectangle [x0, x1) x [y0, y1) covered by the square of half-side `radius` around `m`.
fn tile_rect(m: vec2<f32>, radius: f32) -> vec4<u32> {
    let t = f32(TILE);
    let tx = f32(params.tiles_x);
    let ty = f32(params.tiles_y);
    let x0 = clamp(floor((m.x - radius) / t), 0.0, tx);
    let x1 = clamp(floor((m.x + radius) / t) + 1.0, 0.0, tx);
    let y0 = clamp(floor((m.y - radius) / t), 0.0, ty);
    let y1 = clamp(floor((m.y + radius) / t) + 1.0, 0.0, ty);
    return vec4<u32>(u32(x0), u32(y0), u32(x1), u32(y1));
}

