//! Fractal value noise of the noise texture, hashed from a keyed random stream.

use super::V3;

/// Keyed random stream of the noise lattice (octave o uses NOISE_STREAM + o).
const NOISE_STREAM: u64 = 1000;

/// Lattice values in [0, 1) of the three colour channels at integer point (ix, iy, iz):
/// one 64-bit hash split into three 21-bit fractions, so the channels are independent.
pub(super) fn lattice(seed: u64, octave: u32, ix: i64, iy: i64, iz: i64) -> [f64; 3] {
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
pub(super) fn value_noise(seed: u64, freq: f64, octaves: u32, p: V3) -> [f64; 3] {
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
