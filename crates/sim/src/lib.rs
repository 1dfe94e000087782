//! ESIM-style event camera simulator (Rebecq et al., CoRL 2018).
//!
//! Feed log-intensity frames L = log(I + eps) in time order; each pixel keeps a reference level
//! and emits an event every time L crosses reference ± C, with the timestamp linearly
//! interpolated between the two frames that bracket the crossing. Per-pixel thresholds C+/C−
//! are drawn once around their nominal values. Colour sensors see one Bayer channel per pixel.

pub mod render;
mod rng;

use rayon::prelude::*;

pub use evsplat_events::Bayer;
use evsplat_events::Sensor;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SimError {
    #[error("sensor size {0}x{1} must be positive and at most 65535x65535")]
    BadSize(usize, usize),
    #[error("contrast thresholds must be positive and finite (c_pos={0}, c_neg={1})")]
    BadThreshold(f64, f64),
    #[error("{name}={value} must be finite and >= 0")]
    Negative { name: &'static str, value: f64 },
    #[error("{0} hot pixels requested but the sensor has {1} pixels")]
    TooManyHotPixels(usize, usize),
    #[error("frame has {got} values, expected {expected} ({height}x{width}x{channels})")]
    FrameSize {
        got: usize,
        expected: usize,
        height: usize,
        width: usize,
        channels: usize,
    },
    #[error("frame time {t} us is not after the previous frame's {prev} us")]
    NotIncreasing { t: i64, prev: i64 },
    #[error("frame at {t} us has a non-finite log intensity at pixel (x={x}, y={y})")]
    NonFinite { t: i64, x: usize, y: usize },
}

#[derive(Clone, Debug)]
pub struct SimConfig {
    pub c_pos: f64,
    pub c_neg: f64,
    /// Standard deviation of the per-pixel thresholds around c_pos / c_neg.
    pub sigma_c: f64,
    /// Events closer than this to the pixel's previous event are dropped (the reference still moves).
    pub refractory_us: i64,
    /// Background activity: Poisson rate per pixel, random polarity.
    pub noise_rate_hz: f64,
    /// Number of hot pixels, chosen at random, each firing positive events at `hot_rate_hz`.
    pub hot_pixels: usize,
    pub hot_rate_hz: f64,
    pub bayer: Bayer,
    pub seed: u64,
}

/// The smallest per-pixel threshold, as a fraction of the nominal one: a wide sigma must not
/// produce zero or negative thresholds (infinite event counts).
const MIN_THRESHOLD_FRACTION: f64 = 0.1;

// Keyed random streams.
const STREAM_C_POS: u64 = 1;
const STREAM_C_NEG: u64 = 2;
const STREAM_HOT: u64 = 3;
const STREAM_NOISE_COUNT: u64 = 4;
const STREAM_NOISE_DRAW: u64 = 5;

#[derive(Clone, Copy, Debug)]
struct Pixel {
    c_pos: f64,
    c_neg: f64,
    l_ref: f64,
    l_last: f64,
    last_event: i64,
    hot: bool,
}

/// Events as columns, sorted by t (then y, x).
pub use evsplat_events::Events;

type Ev = (i64, u16, u16, i8); // (t, y, x, p): sort order t, then y, then x

pub struct EventSimulator {
    width: usize,
    height: usize,
    cfg: SimConfig,
    pixels: Vec<Pixel>,
    /// Channel of the RGB frame that each pixel sees (all 0 for mono).
    channel: Vec<u8>,
    last_t: Option<i64>,
    step: u64,
}

fn check_rate(name: &'static str, value: f64) -> Result<(), SimError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(SimError::Negative { name, value })
    }
}

impl EventSimulator {
    pub fn new(width: usize, height: usize, cfg: SimConfig) -> Result<Self, SimError> {
        if width == 0 || height == 0 || width > 65535 || height > 65535 {
            return Err(SimError::BadSize(width, height));
        }
        let ok = |c: f64| c.is_finite() && c > 0.0;
        if !(ok(cfg.c_pos) && ok(cfg.c_neg)) {
            return Err(SimError::BadThreshold(cfg.c_pos, cfg.c_neg));
        }
        check_rate("sigma_c", cfg.sigma_c)?;
        check_rate("noise_rate_hz", cfg.noise_rate_hz)?;
        check_rate("hot_rate_hz", cfg.hot_rate_hz)?;
        if cfg.refractory_us < 0 {
            return Err(SimError::Negative {
                name: "refractory_us",
                value: cfg.refractory_us as f64,
            });
        }
        let n = width * height;
        if cfg.hot_pixels > n {
            return Err(SimError::TooManyHotPixels(cfg.hot_pixels, n));
        }
        let draw = |nominal: f64, stream: u64, i: usize| {
            let c = nominal + cfg.sigma_c * rng::normal(cfg.seed, stream, i as u64);
            c.max(MIN_THRESHOLD_FRACTION * nominal)
        };
        let mut pixels: Vec<Pixel> = (0..n)
            .map(|i| Pixel {
                c_pos: draw(cfg.c_pos, STREAM_C_POS, i),
                c_neg: draw(cfg.c_neg, STREAM_C_NEG, i),
                l_ref: 0.0,
                l_last: 0.0,
                last_event: i64::MIN / 2,
                hot: false,
            })
            .collect();
        // Hot pixels: the first `hot_pixels` of a keyed random permutation (partial Fisher-Yates).
        let mut order: Vec<usize> = (0..n).collect();
        for k in 0..cfg.hot_pixels {
            let j = k + (rng::uniform(cfg.seed, STREAM_HOT, k as u64, 0) * (n - k) as f64) as usize;
            order.swap(k, j.min(n - 1));
            pixels[order[k]].hot = true;
        }
        let sensor = Sensor {
            width: width as u32,
            height: height as u32,
        };
        let channel = cfg.bayer.channel_map(sensor);
        Ok(EventSimulator {
            width,
            height,
            cfg,
            pixels,
            channel,
            last_t: None,
            step: 0,
        })
    }

    /// Per-pixel thresholds (C+, C−), row-major.
    pub fn thresholds(&self) -> (Vec<f64>, Vec<f64>) {
        self.pixels.iter().map(|p| (p.c_pos, p.c_neg)).unzip()
    }

    /// Add the frame at time `t_us` (row-major, `bayer.channels()` interleaved values per pixel)
    /// and return the events between the previous frame and this one. The first frame only sets
    /// the reference levels.
    pub fn push(&mut self, t_us: i64, frame: &[f32]) -> Result<Events, SimError> {
        let (w, h, ch) = (self.width, self.height, self.cfg.bayer.channels());
        if frame.len() != w * h * ch {
            return Err(SimError::FrameSize {
                got: frame.len(),
                expected: w * h * ch,
                height: h,
                width: w,
                channels: ch,
            });
        }
        if let Some(prev) = self.last_t {
            if t_us <= prev {
                return Err(SimError::NotIncreasing { t: t_us, prev });
            }
        }
        let channel = &self.channel;
        let seen =
            |x: usize, y: usize| frame[(y * w + x) * ch + channel[y * w + x] as usize] as f64;
        if let Some(i) = (0..w * h).find(|&i| !seen(i % w, i / w).is_finite()) {
            return Err(SimError::NonFinite {
                t: t_us,
                x: i % w,
                y: i / w,
            });
        }
        let Some(t0) = self.last_t else {
            for (i, px) in self.pixels.iter_mut().enumerate() {
                let l = seen(i % w, i / w);
                px.l_ref = l;
                px.l_last = l;
            }
            self.last_t = Some(t_us);
            return Ok(Events::default());
        };
        let cfg = &self.cfg;
        let step = self.step;
        let mut evs: Vec<Ev> = self
            .pixels
            .par_chunks_mut(w)
            .enumerate()
            .flat_map_iter(|(y, row)| {
                let mut out = Vec::new();
                for (x, px) in row.iter_mut().enumerate() {
                    let l1 = seen(x, y);
                    crossings(
                        px,
                        l1,
                        t0,
                        t_us,
                        cfg.refractory_us,
                        x as u16,
                        y as u16,
                        &mut out,
                    );
                    let idx = (y * w + x) as u64;
                    noise(
                        cfg, px.hot, idx, step, t0, t_us, x as u16, y as u16, &mut out,
                    );
                }
                out
            })
            .collect();
        evs.par_sort_unstable();
        self.last_t = Some(t_us);
        self.step += 1;
        let mut out = Events {
            x: Vec::with_capacity(evs.len()),
            y: Vec::with_capacity(evs.len()),
            t: Vec::with_capacity(evs.len()),
            p: Vec::with_capacity(evs.len()),
        };
        for (t, y, x, p) in evs {
            out.t.push(t);
            out.y.push(y);
            out.x.push(x);
            out.p.push(p);
        }
        Ok(out)
    }
}

/// Threshold crossings of one pixel between (t0, l_last) and (t1, l1), linearly interpolated.
#[allow(clippy::too_many_arguments)]
fn crossings(
    px: &mut Pixel,
    l1: f64,
    t0: i64,
    t1: i64,
    refractory: i64,
    x: u16,
    y: u16,
    out: &mut Vec<Ev>,
) {
    let l0 = px.l_last;
    let dl = l1 - l0;
    let dt = (t1 - t0) as f64;
    // |L - L_ref| < C holds on entry, so only crossings in the direction of the change occur.
    loop {
        let (level, p) = if l1 >= px.l_ref + px.c_pos {
            (px.l_ref + px.c_pos, 1i8)
        } else if l1 <= px.l_ref - px.c_neg {
            (px.l_ref - px.c_neg, -1i8)
        } else {
            break;
        };
        px.l_ref = level;
        // dl != 0 here: a crossing needs l1 beyond a level that l0 was inside of.
        let frac = ((level - l0) / dl).clamp(0.0, 1.0);
        let t = t0 + (frac * dt).round() as i64;
        if t - px.last_event >= refractory {
            px.last_event = t;
            out.push((t, y, x, p));
        }
    }
    px.l_last = l1;
}

/// Background-activity and hot-pixel events of one pixel in (t0, t1].
#[allow(clippy::too_many_arguments)]
fn noise(
    cfg: &SimConfig,
    hot: bool,
    idx: u64,
    step: u64,
    t0: i64,
    t1: i64,
    x: u16,
    y: u16,
    out: &mut Vec<Ev>,
) {
    let seconds = (t1 - t0) as f64 * 1e-6;
    for (rate, stream, forced) in [
        (cfg.noise_rate_hz, 0u64, None),
        (if hot { cfg.hot_rate_hz } else { 0.0 }, 1, Some(1i8)),
    ] {
        if rate <= 0.0 {
            continue;
        }
        let key = idx << 1 | stream;
        let count = rng::poisson(cfg.seed, STREAM_NOISE_COUNT, key, step, rate * seconds);
        for k in 0..count as u64 {
            let u = rng::uniform(cfg.seed, STREAM_NOISE_DRAW, key, step << 20 | k << 1);
            let t = t0 + 1 + (u * (t1 - t0) as f64) as i64;
            let p = forced.unwrap_or_else(|| {
                if rng::uniform(cfg.seed, STREAM_NOISE_DRAW, key, step << 20 | k << 1 | 1) < 0.5 {
                    1
                } else {
                    -1
                }
            });
            out.push((t.min(t1), y, x, p));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(c: f64) -> SimConfig {
        SimConfig {
            c_pos: c,
            c_neg: c,
            sigma_c: 0.0,
            refractory_us: 0,
            noise_rate_hz: 0.0,
            hot_pixels: 0,
            hot_rate_hz: 0.0,
            bayer: Bayer::Mono,
            seed: 0,
        }
    }

    #[test]
    fn a_single_step_emits_one_event_per_threshold_at_interpolated_times() {
        let mut s = EventSimulator::new(1, 1, cfg(0.25)).unwrap();
        s.push(0, &[0.0]).unwrap();
        let e = s.push(1000, &[1.0]).unwrap();
        assert_eq!(e.t, vec![250, 500, 750, 1000]);
        assert_eq!(e.p, vec![1; 4]);
        let e = s.push(2000, &[0.4]).unwrap();
        assert_eq!(e.t, vec![1000 + 417, 1000 + 833]); // levels 0.75 and 0.5 on the way to 0.4
        assert_eq!(e.p, vec![-1, -1]);
    }

    #[test]
    fn per_pixel_thresholds_follow_the_requested_normal() {
        let mut c = cfg(0.2);
        c.c_neg = 0.3;
        c.sigma_c = 0.03;
        let s = EventSimulator::new(200, 200, c).unwrap();
        let (p, n) = s.thresholds();
        let stats = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            (
                m,
                (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt(),
            )
        };
        let ((mp, sp), (mn, sn)) = (stats(&p), stats(&n));
        assert!(
            (mp - 0.2).abs() < 1e-3 && (sp - 0.03).abs() < 1e-3,
            "{mp} {sp}"
        );
        assert!(
            (mn - 0.3).abs() < 1e-3 && (sn - 0.03).abs() < 1e-3,
            "{mn} {sn}"
        );
        assert!(p.iter().zip(&n).all(|(a, b)| *a >= 0.02 && *b >= 0.03));
    }

    #[test]
    fn refractory_period_drops_close_events() {
        let mut c = cfg(0.1);
        c.refractory_us = 300;
        let mut s = EventSimulator::new(1, 1, c).unwrap();
        s.push(0, &[0.0]).unwrap();
        let e = s.push(1000, &[1.05]).unwrap(); // crossings every ~95 us
        assert!(e.t.windows(2).all(|w| w[1] - w[0] >= 300));
        assert_eq!(e.len(), 3);
    }

    #[test]
    fn bad_frames_are_errors() {
        let mut s = EventSimulator::new(2, 1, cfg(0.2)).unwrap();
        assert!(matches!(s.push(0, &[0.0]), Err(SimError::FrameSize { .. })));
        assert_eq!(
            s.push(0, &[0.0, f32::NAN]),
            Err(SimError::NonFinite { t: 0, x: 1, y: 0 })
        );
        s.push(5, &[0.0, 0.0]).unwrap();
        assert_eq!(
            s.push(5, &[0.0, 0.0]),
            Err(SimError::NotIncreasing { t: 5, prev: 5 })
        );
    }

    #[test]
    fn hot_pixels_fire_at_their_rate_and_nowhere_else() {
        let mut c = cfg(0.2);
        c.hot_pixels = 3;
        c.hot_rate_hz = 2000.0;
        let mut s = EventSimulator::new(16, 16, c).unwrap();
        let frame = vec![0.0f32; 256];
        let mut n = 0;
        let mut where_ = std::collections::BTreeSet::new();
        for k in 0..=1000 {
            let e = s.push(k * 1000, &frame).unwrap();
            n += e.len();
            where_.extend(e.x.iter().zip(&e.y).map(|(&x, &y)| (x, y)));
            assert!(e.p.iter().all(|&p| p == 1));
        }
        assert_eq!(where_.len(), 3);
        assert!((n as f64 - 6000.0).abs() < 300.0, "{n}");
    }
}
