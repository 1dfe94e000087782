// Shared by every splatting pass: crates/raster/build/main.rs puts it before each pass's own files
// (its KERNELS table). It holds the per-call parameters and the numerical guards, each named once;
// the host's `Params` struct and constants are generated from this file. Every pass binds `params`.

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
    height: u32, // rows of the band rendered (the image's unless it is rendered in bands)
    n: u32, // Gaussians
    d: u32, // feature channels
    tiles_x: u32,
    tiles_y: u32, // tile rows of the band
    cap: u32, // capacity of the tile-intersection buffers
    off_quats: u32, // offsets into `inputs` (means start at 0)
    off_scales: u32,
    off_opac: u32,
    off_feat: u32,
    off_bg: u32,
    grad_stride: u32, // floats per Gaussian in the gradient buffer: 8 + d
    // The band: its first tile row in the image, and the image's tile rows. A band is rendered as
    // an image of its own rows (tile lists, pixel buffers) with the image's projection, tile tests
    // and pixel centres, so its pixels are the whole image's, bit for bit.
    band_ty0: u32,
    image_tiles_y: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// Tile side in pixels: the compositing passes run one workgroup of TILE x TILE / (4 QUADS)
// invocations per tile (see Lanes). 8x8 rather than 16x16: the lists are shorter, so each
// pixel evaluates about half as many Gaussians (docs/experiments/rasterizer.md, "Rasterizer: subgroup gradient sums, 8x8 tiles"), for twice the
// tile keys to sort.
const TILE: u32 = 8u;
// Feature channels: the compositing passes use `D`, which the host declares per pipeline
// (crates/raster/src/kernels.rs) as the render's channel count, 1 to MAX_D, so per-pixel channel
// loops unroll into registers.
const MAX_D: u32 = 32u;
// Floats per Gaussian in the gradient accumulator before the D features (rasterize_bwd.wgsl), and
// floats per Gaussian written by project_bwd.wgsl (mean 3, quaternion 4, scale 3).
const GRAD_HEAD: u32 = 8u;
const PARAM_GRADS: u32 = 10u;
// 3DGS guards.
const LOW_PASS: f32 = 0.3; // px^2 added to the 2-D covariance diagonal (anti-aliasing, det > 0)
const ALPHA_MIN: f32 = 0.00392156862745098; // 1/255: fainter fragments are skipped
const ALPHA_MAX: f32 = 0.99; // alpha clamp: keeps 1/(1 - alpha) finite in the backward pass
const T_MIN: f32 = 1e-4; // stop compositing once transmittance would fall below this
const POWER_CUT: f32 = -4.5; // -0.5 * 3^2: nothing beyond 3 sigma
const MAX_VAR_PX: f32 = 1e12; // cull 2-D variances beyond (1e6 px)^2: keeps the determinant finite
const QUAT_EPS2: f32 = 1e-12; // squared-norm floor when normalising quaternions
const ALPHA_EPS: f32 = 1e-6; // depth = sum(w z) / alpha only where alpha exceeds this, else 0
const CULLED_KEY: u32 = 0xffffffffu;
// The radix sorts (sort.wgsl) and the tile-range pass work in blocks of SORT_BLOCK keys, one
// workgroup of SORT_THREADS invocations per block, each invocation SORT_BLOCK / SORT_THREADS keys
// (more keys per workgroup: fewer workgroups and barriers, which lavapipe pays for per workgroup;
// 2048 was no faster, and its 16 KiB of block digits and ranks would exceed the workgroup memory
// Vulkan guarantees).
const SORT_BLOCK: u32 = 1024u;
const SORT_THREADS: u32 = 256u;
const SORT_KEYS: u32 = SORT_BLOCK / SORT_THREADS;
// Compositing: a workgroup of TILE invocations covers a tile, each invocation one column of it as
// two quads of four consecutive pixels, the lanes of vec4s: every Gaussian loaded from the tile
// list serves eight pixels, the per-pixel state is vectors, not arrays indexed by pixel, and the
// invocations (run together as SIMD lanes on a CPU, a warp on a GPU) cover the tile, so a splat
// that misses it is skipped by all of them at once. On lavapipe a tile is then one subgroup (its
// 8 SIMD lanes), so the backward pass sums each Gaussian's gradients across lanes and adds them
// with atomics once per tile, not once per half tile (docs/experiments/rasterizer.md, "Two quads per invocation"); on a GPU
// with 32-wide subgroups the workgroup fills a quarter of one.

// Four pixels of a tile: one column, four consecutive rows (the vec4 lanes).
struct Lanes {
    tile: u32, // the tile's index in the band
    px: u32, // the column
    py: vec4<u32>, // the rows, in the band
    inside: vec4<bool>, // inside the image (the last tiles overhang it)
    centre_x: f32, // pixel centres, in the whole image
    centre_y: vec4<f32>,
}

// Quads per invocation (both compositing passes hold theirs by name, q0 and q1).
const QUADS: u32 = 2u;

// Quad `quad` (0 .. QUADS - 1) of invocation `lid`'s pixels in tile `wid`: column lid.x, rows
// 4 (QUADS lid.y + quad) .. + 3.
fn pixel_lanes(wid: vec3<u32>, lid: vec3<u32>, quad: u32) -> Lanes {
    var l: Lanes;
    l.tile = wid.x + wid.y * params.tiles_x;
    l.px = wid.x * TILE + lid.x;
    let row = wid.y * TILE + 4u * (QUADS * lid.y + quad);
    l.py = vec4<u32>(row) + vec4<u32>(0u, 1u, 2u, 3u);
    l.inside = (l.py < vec4<u32>(params.height)) & vec4<bool>(l.px < params.width);
    l.centre_x = f32(l.px) + 0.5;
    l.centre_y = vec4<f32>(l.py + params.band_ty0 * TILE) + 0.5;
    return l;
}

// Exponents of a splat with conic (a, b, c) in co.xyz at offsets (dx, dy) = mean2d - pixel centre
// of the four lanes (one column: one dx).
fn splat_powers(co: vec4<f32>, dx: f32, dy: vec4<f32>) -> vec4<f32> {
    return -0.5 * (co.x * dx * dx + co.z * dy * dy) - co.y * dx * dy;
}

// Culling of (tile, Gaussian) pairs. A pixel composites a splat only where power >= POWER_CUT and
// opacity * exp(power) >= ALPHA_MIN, i.e. inside the ellipse q <= q_max of q = -2 power, with
// q_max = min(9, 2 ln(opacity / ALPHA_MIN)) (opacity-aware, as gsplat's and Brush's extents). A
// tile gets the splat only when that ellipse reaches one of its pixel centres (an exact
// ellipse-rectangle test, as Speedy-Splat's), with margins so that float32 rounding never drops a
// fragment the compositing pass would draw:
const CULL_SLACK: f32 = 1e-3; // on q, for exp and log rounding
const CULL_REL: f32 = 1e-5; // relative to q's terms, which cancel for thin, tilted ellipses

fn cull_q_max(opacity: f32) -> f32 {
    return min(-2.0 * POWER_CUT, 2.0 * log(opacity / ALPHA_MIN)) + CULL_SLACK;
}

// q = a dx^2 + 2 b dx dy + c dy^2 for the conic (a, b, c).
fn conic_q(co: vec3<f32>, d: vec2<f32>) -> f32 {
    return co.x * d.x * d.x + 2.0 * co.y * d.x * d.y + co.z * d.y * d.y;
}

// Tiles whose pixels the splat at `m` (conic `co`, `radius` its 3-sigma radius) may reach when its
// ellipse is q <= q_max: the 3-sigma square shrunk to the opacity-aware extent.
// Rows limited to the band's; tile rows stay the image's.
fn cull_rect(m: vec2<f32>, radius: f32, q_max: f32) -> vec4<u32> {
    let r = min(radius, radius * sqrt(q_max / (-2.0 * POWER_CUT)) + 0.5);
    return tile_rect(m, r, params.band_ty0, params.band_ty0 + params.tiles_y);
}

// Does the ellipse q(mean - pixel) <= q_max reach a pixel centre of tile (tx, ty)? The smallest q
// over the tile's box of centres is 0 when the mean is inside, else on one of its four edges,
// where q is a 1-D quadratic minimised in closed form.
fn tile_hit(m: vec2<f32>, co: vec3<f32>, q_max: f32, tx: u32, ty: u32) -> bool {
    let first = vec2<f32>(f32(tx * TILE), f32(ty * TILE)) + 0.5;
    let lo = m - (first + f32(TILE - 1u)); // d = mean - pixel over the tile: [lo, hi]
    let hi = m - first;
    if (all(lo <= vec2<f32>(0.0)) && all(hi >= vec2<f32>(0.0))) {
        return true;
    }
    var q = 3.4e38;
    for (var e = 0u; e < 2u; e = e + 1u) {
        let x = select(lo.x, hi.x, e == 1u);
        let y = select(lo.y, hi.y, e == 1u);
        q = min(q, conic_q(co, vec2<f32>(x, clamp(-co.y * x / co.z, lo.y, hi.y))));
        q = min(q, conic_q(co, vec2<f32>(clamp(-co.y * y / co.x, lo.x, hi.x), y)));
    }
    let far = max(abs(lo), abs(hi));
    let terms = co.x * far.x * far.x + 2.0 * abs(co.y) * far.x * far.y + co.z * far.y * far.y;
    return q <= q_max + CULL_REL * terms;
}

// Tile rectangle [x0, x1) x [y0, y1) covered by the square of half-side `radius` around `m`,
// within the tile rows [ty0, ty1).
fn tile_rect(m: vec2<f32>, radius: f32, ty0: u32, ty1: u32) -> vec4<u32> {
    let t = f32(TILE);
    let tx = f32(params.tiles_x);
    let x0 = clamp(floor((m.x - radius) / t), 0.0, tx);
    let x1 = clamp(floor((m.x + radius) / t) + 1.0, 0.0, tx);
    let y0 = clamp(floor((m.y - radius) / t), f32(ty0), f32(ty1));
    let y1 = clamp(floor((m.y + radius) / t) + 1.0, f32(ty0), f32(ty1));
    return vec4<u32>(u32(x0), u32(y0), u32(x1), u32(y1));
}

