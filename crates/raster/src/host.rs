//! Host-side phase times of the rasterizer's calls on this thread (buffer preparation, uploads,
//! encoding, submission, the wait for the device, copies out), summed per phase until taken.
//! Always on: an `Instant` per phase costs nanoseconds, and the PyO3 layer returns them with
//! every call so a host-side profile needs no special build (scripts/raster_host_phases.py).

use std::cell::RefCell;
use std::time::Instant;

/// (phase, seconds), in the order the phases first ran.
pub type HostTimes = Vec<(&'static str, f64)>;

thread_local! {
    static TIMES: RefCell<HostTimes> = const { RefCell::new(Vec::new()) };
}

/// Run `f`, adding its wall time to `phase`.
pub fn time<T>(phase: &'static str, f: impl FnOnce() -> T) -> T {
    let start = Instant::now();
    let out = f();
    let dt = start.elapsed().as_secs_f64();
    TIMES.with_borrow_mut(|times| match times.iter_mut().find(|(n, _)| *n == phase) {
        Some((_, t)) => *t += dt,
        None => times.push((phase, dt)),
    });
    out
}

/// The phases timed on this thread since the last `take`.
pub fn take() -> HostTimes {
    TIMES.with_borrow_mut(std::mem::take)
}
