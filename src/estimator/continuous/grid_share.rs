//! The tabulated feature maps shared by every live fit that builds the same grid: the continuous
//! tracker, its temporal form and the particle filter fit the same surrogates, and a grid of
//! 0.02 mm is hundreds of megabytes, so one run (or several runs of a sweep) holds it once. The
//! same holding ([`try_shared`]) shares each feature's fitted map (`surrogate::share`).
//!
//! Tables are found by a key of everything they depend on, bit for bit, and held weakly: once the
//! last fit using a table is dropped it is freed, and the next fit tabulates it again.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock, TryLockError, Weak};

/// One grid's values (see `surrogate::Grid::table`).
pub(super) type Table = Vec<[f64; 4]>;

/// A key's value while some fit holds it; its lock is held while it is being built, so a second
/// fit of the same value waits for the first instead of building a copy.
type Slot<T> = Arc<Mutex<Weak<T>>>;

/// The live values of one kind, by key.
pub(super) type Live<T> = Mutex<HashMap<Vec<u8>, Slot<T>>>;

fn live() -> &'static Live<Table> {
    static LIVE: OnceLock<Live<Table>> = OnceLock::new();
    LIVE.get_or_init(Mutex::default)
}

/// The live table of `key`, or the one `build` makes (then live under `key`).
pub(super) fn shared(key: Vec<u8>, build: impl FnOnce() -> Table) -> Arc<Table> {
    try_shared_infallible(live(), key, true, build)
        .unwrap_or_else(|| unreachable!("a waiting call always gives a table"))
}

/// [`try_shared`] of a value whose build cannot fail.
pub(super) fn try_shared_infallible<T>(
    live: &Live<T>,
    key: Vec<u8>,
    wait: bool,
    build: impl FnOnce() -> T,
) -> Option<Arc<T>> {
    match try_shared(live, key, wait, || {
        Ok::<_, std::convert::Infallible>(build())
    })? {
        Ok(value) => Some(value),
        Err(never) => match never {},
    }
}

/// The value live under `key` in `live`, or the one `build` makes (then live under `key`; an
/// error is returned and nothing is kept). While another fit builds it, `wait` waits for that
/// value, and without `wait` nothing happens (`None`): the caller can do other work first.
pub(super) fn try_shared<T, E>(
    live: &Live<T>,
    key: Vec<u8>,
    wait: bool,
    build: impl FnOnce() -> Result<T, E>,
) -> Option<Result<Arc<T>, E>> {
    let slot = {
        let mut live = live.lock().unwrap_or_else(|e| e.into_inner());
        // Drop the keys of freed values (a slot being built is locked, and kept).
        live.retain(|_, slot| {
            Arc::strong_count(slot) > 1 || slot.try_lock().map_or(true, |t| t.strong_count() > 0)
        });
        live.entry(key).or_default().clone()
    };
    let mut held = match slot.try_lock() {
        Ok(held) => held,
        Err(TryLockError::Poisoned(e)) => e.into_inner(),
        Err(TryLockError::WouldBlock) if wait => slot.lock().unwrap_or_else(|e| e.into_inner()),
        Err(TryLockError::WouldBlock) => return None,
    };
    if let Some(value) = held.upgrade() {
        return Some(Ok(value));
    }
    Some(build().map(|value| {
        let value = Arc::new(value);
        *held = Arc::downgrade(&value);
        value
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_live_table_is_built_once_and_freed_with_its_last_user() {
        let key = b"grid_share test key".to_vec();
        let mut builds = 0;
        let mut build = || {
            builds += 1;
            vec![[1.0, 2.0, 3.0, 4.0]; 3]
        };
        let first = shared(key.clone(), &mut build);
        let second = shared(key.clone(), &mut build);
        assert!(Arc::ptr_eq(&first, &second), "one table for both");
        let other = shared(b"another key".to_vec(), &mut build);
        assert!(!Arc::ptr_eq(&first, &other));
        drop((first, second, other));
        let again = shared(key, &mut build);
        assert_eq!(builds, 3, "freed with its last user, then built again");
        assert_eq!(again[2], [1.0, 2.0, 3.0, 4.0]);
        drop(again);
        // The next call forgets the keys of freed tables.
        drop(shared(b"a third key".to_vec(), Vec::new));
        let live = live().lock().unwrap_or_else(|e| e.into_inner());
        assert!(!live.contains_key(b"another key".as_slice()));
    }
}
