//! A mutex's guard, also after a holder panicked.

use std::sync::{Mutex, MutexGuard};

/// The guard of `m`, whether or not a holder panicked while holding it (a poisoned lock is
/// taken as it is).
pub(super) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}
