//! The scheduler's tick grid (see the parent module): ticks fall on `epoch + k * slot`, a whole number
//! of slots per token, and a session steps at the grid point of its slot.

use std::time::{Duration, Instant};

use livegesture::frontend::FrontendConfig;

/// The slot of the tick grid: the token's duration divided into a whole number of slots of about
/// `wait` (zero: no grid, a due session steps at once).
pub(super) fn tick_slot(f: &FrontendConfig, wait: Duration) -> Duration {
    if wait.is_zero() {
        return Duration::ZERO;
    }
    let token = Duration::from_secs_f64(f.frames_per_token as f64 / f.fps.max(1) as f64);
    let n = (token.as_secs_f64() / wait.as_secs_f64()).round().max(1.0);
    token.div_f64(n)
}

/// Slots of `slot` per token (1 without a grid).
pub(super) fn slots_per_token(f: &FrontendConfig, slot: Duration) -> u64 {
    if slot.is_zero() {
        return 1;
    }
    let token = f.frames_per_token as f64 / f.fps.max(1) as f64;
    (token / slot.as_secs_f64()).round().max(1.0) as u64
}

/// The index `k` of the first instant of the grid `epoch + k * slot` at or after `t` (0 without a
/// grid).
pub(super) fn grid_index_after(epoch: Instant, slot: Duration, t: Instant) -> u128 {
    if slot.is_zero() {
        return 0;
    }
    let since = t.saturating_duration_since(epoch).as_nanos();
    since.div_ceil(slot.as_nanos().max(1))
}

/// The grid point a session due at `at` steps at on the grid `epoch + k * slot` of `n` slots per
/// token, given its home slot: the first grid point at or after `at`, or the one after it when that
/// is the slot just before `home` (`n >= 3`, where a slot earlier and a slot later differ). Without
/// a grid: `at`.
pub(super) fn slot_deadline(
    epoch: Instant,
    slot: Duration,
    n: u64,
    at: Instant,
    home: Option<u64>,
) -> Instant {
    if slot.is_zero() {
        return at;
    }
    let k = grid_index_after(epoch, slot, at);
    match home {
        Some(h) if n >= 3 && (k % n as u128) as u64 == (h + n - 1) % n => {
            grid_point(epoch, slot, k + 1)
        }
        _ => grid_point(epoch, slot, k),
    }
}

/// The slot of the token (`0 .. n`) of grid point `t` (of the grid `epoch + k * slot`, `n` slots per
/// token).
pub(super) fn slot_index(epoch: Instant, slot: Duration, n: u64, t: Instant) -> u64 {
    (grid_index_after(epoch, slot, t) % n.max(1) as u128) as u64
}

/// Grid point `k`: `epoch + k * slot`.
pub(super) fn grid_point(epoch: Instant, slot: Duration, k: u128) -> Instant {
    epoch + Duration::from_nanos((k * slot.as_nanos()).min(u64::MAX as u128) as u64)
}

/// The first instant of the grid `epoch + k * slot` at or after `t`.
pub(super) fn grid_after(epoch: Instant, slot: Duration, t: Instant) -> Instant {
    if slot.is_zero() {
        return t;
    }
    grid_point(epoch, slot, grid_index_after(epoch, slot, t))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_divides_a_token_into_whole_slots() {
        let f = FrontendConfig::default(); // 4 frames at 30 fps: 133.3 ms
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        assert!((ms(tick_slot(&f, Duration::from_millis(30))) - 133.333 / 4.0).abs() < 1e-3);
        assert!((ms(tick_slot(&f, Duration::from_millis(60))) - 133.333 / 2.0).abs() < 1e-3);
        assert!((ms(tick_slot(&f, Duration::from_millis(500))) - 133.333).abs() < 1e-3);
        assert_eq!(tick_slot(&f, Duration::ZERO), Duration::ZERO);
        let e = Instant::now();
        let slot = Duration::from_millis(10);
        assert_eq!(grid_after(e, slot, e), e);
        assert_eq!(grid_after(e, slot, e + Duration::from_millis(1)), e + slot);
        assert_eq!(grid_after(e, slot, e + slot), e + slot);
        assert_eq!(
            grid_after(e, slot, e + Duration::from_millis(25)),
            e + 3 * slot
        );
        assert_eq!(grid_after(e, Duration::ZERO, e + slot), e + slot);
    }

    #[test]
    fn a_session_keeps_its_slot_against_jitter() {
        let f = FrontendConfig::default();
        let slot = tick_slot(&f, Duration::from_millis(30));
        let n = slots_per_token(&f, slot);
        assert_eq!(n, 4);
        let e = Instant::now();
        let ms = |x: f64| Duration::from_secs_f64(x / 1e3);
        // a phase 1 ms before grid point 5 (slot 1 of its token): jitter of 0 to 13.3 ms puts the
        // audio on either side of it
        let early = e + 5 * slot - ms(1.0);
        let late = e + 5 * slot + ms(12.0);
        // a new session takes the slot it is due in
        assert_eq!(slot_deadline(e, slot, n, early, None), e + 5 * slot);
        assert_eq!(slot_deadline(e, slot, n, late, None), e + 6 * slot);
        // at home in slot 2 (grid point 6), an early token waits for it; a late one is in it anyway
        assert_eq!(slot_deadline(e, slot, n, early, Some(2)), e + 6 * slot);
        assert_eq!(slot_deadline(e, slot, n, late, Some(2)), e + 6 * slot);
        // at home in slot 1, a late one moves on (it cannot step earlier)
        assert_eq!(slot_deadline(e, slot, n, late, Some(1)), e + 6 * slot);
        // two slots from home (a client that paused or caught up): the slot it is due in
        assert_eq!(slot_deadline(e, slot, n, early, Some(3)), e + 5 * slot);
        assert_eq!(
            slot_deadline(e, slot, n, early + slot, Some(0)),
            e + 6 * slot
        );
        // the slot before home wraps around the token: slot 3 is just before slot 0
        let t = e + 7 * slot - ms(1.0); // due in grid point 7, slot 3
        assert_eq!(slot_deadline(e, slot, n, t, Some(0)), e + 8 * slot);
        // two slots per token cannot tell earlier from later: no waiting
        assert_eq!(slot_deadline(e, 2 * slot, 2, early, Some(1)), e + 6 * slot);
        // without a grid: at once
        assert_eq!(slot_deadline(e, Duration::ZERO, 1, late, Some(0)), late);
    }
}
