//! Counter-based random numbers: every draw is a pure function of (seed, stream, indices), so
//! results do not depend on thread scheduling or on the order pixels are visited.

/// SplitMix64 finaliser: a bijective 64-bit mixer with good avalanche.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// 64 well-mixed bits from the key.
pub fn bits(seed: u64, stream: u64, a: u64, b: u64) -> u64 {
    mix(mix(mix(seed ^ mix(stream)) ^ a) ^ b)
}

/// Uniform in [0, 1) from the key (53 random bits).
pub fn uniform(seed: u64, stream: u64, a: u64, b: u64) -> f64 {
    (bits(seed, stream, a, b) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Standard normal via Box-Muller on two keyed uniforms.
pub fn normal(seed: u64, stream: u64, a: u64) -> f64 {
    let u1 = uniform(seed, stream, a, 0).max(f64::MIN_POSITIVE);
    let u2 = uniform(seed, stream, a, 1);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Poisson(lambda) count by inversion; lambda is small here (rate x frame step).
pub fn poisson(seed: u64, stream: u64, a: u64, b: u64, lambda: f64) -> u32 {
    let u = uniform(seed, stream, a, b);
    let (mut k, mut p) = (0u32, (-lambda).exp());
    let mut cdf = p;
    // The cap keeps a pathological lambda from looping long; counts that high are not noise.
    while u > cdf && k < 1000 {
        k += 1;
        p *= lambda / k as f64;
        cdf += p;
    }
    k
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_mean_and_normal_variance_are_right() {
        let n = 200_000;
        let m: f64 = (0..n).map(|i| uniform(7, 1, i, 0)).sum::<f64>() / n as f64;
        let v: f64 = (0..n).map(|i| normal(7, 2, i).powi(2)).sum::<f64>() / n as f64;
        assert!((m - 0.5).abs() < 0.005, "{m}");
        assert!((v - 1.0).abs() < 0.02, "{v}");
    }

    #[test]
    fn poisson_mean_matches_lambda() {
        let n = 200_000;
        let m = (0..n).map(|i| poisson(3, 4, i, 0, 0.3) as f64).sum::<f64>() / n as f64;
        assert!((m - 0.3).abs() < 0.01, "{m}");
    }
}
