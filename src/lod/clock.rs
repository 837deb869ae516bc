//! Where the HLOD stage's time goes (paper III.C; report.json `hlod_timings_s`): seconds spent
//! simplifying and in each part of measuring the error ([`super::hlod_content`]), summed over the
//! tiles. Tiles are built several at a time, so the sums are shares of the work, not a split of
//! the stage's wall time.

use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::Instant;

/// The sub-stages timed.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Part {
    Simplify = 0,
    FullToCoarse = 1,
    Faces = 2,
    CoarseToFull = 3,
}

/// Seconds per sub-stage, summed over the tiles, and the candidate contents measured.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct HlodTimings {
    /// Our QEM on the children's merged content (every try).
    pub simplify: f64,
    /// Full-detail samples against a candidate content.
    pub measure_full_to_coarse: f64,
    /// The full-detail faces certified against it.
    pub measure_faces: f64,
    /// Its samples bounded through the children.
    pub measure_coarse_to_full: f64,
    /// Candidate contents measured (the first try, finer, coarser and grid tries).
    pub measurements: u64,
}

static NANOS: [AtomicU64; 4] = [const { AtomicU64::new(0) }; 4];
static MEASUREMENTS: AtomicU64 = AtomicU64::new(0);

/// Runs `f`, adding its time to `part`.
pub(crate) fn timed<T>(part: Part, f: impl FnOnce() -> T) -> T {
    let t = Instant::now();
    let out = f();
    add(part, t);
    out
}

/// Adds the time since `since` to `part`.
pub(crate) fn add(part: Part, since: Instant) {
    NANOS[part as usize].fetch_add(since.elapsed().as_nanos() as u64, Relaxed);
}

/// Counts one candidate content measured.
pub(crate) fn count_measurement() {
    MEASUREMENTS.fetch_add(1, Relaxed);
}

/// The figures gathered since the last call, which starts them again from zero (a conversion
/// takes them before and after its HLOD stage; conversions in one process at once share them).
pub fn take() -> HlodTimings {
    let s = |p: Part| NANOS[p as usize].swap(0, Relaxed) as f64 * 1e-9;
    HlodTimings {
        simplify: s(Part::Simplify),
        measure_full_to_coarse: s(Part::FullToCoarse),
        measure_faces: s(Part::Faces),
        measure_coarse_to_full: s(Part::CoarseToFull),
        measurements: MEASUREMENTS.swap(0, Relaxed),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn take_returns_what_was_timed_and_starts_again() {
        take();
        let v = timed(Part::Faces, || {
            std::thread::sleep(std::time::Duration::from_millis(5));
            7
        });
        count_measurement();
        assert_eq!(v, 7);
        let t = take();
        // Other tests in this process may time tiles too: at least what this one did.
        assert!(t.measure_faces >= 0.005 && t.measurements >= 1, "{t:?}");
    }
}
