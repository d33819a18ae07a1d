//! A pool of interchangeable per-run objects (tract plan states, ONNX Runtime sessions), so that
//! threads sharing one graph each run it with an object of their own.
//!
//! [`Pool::with`] takes an idle object (or makes one while fewer than the pool's cap exist; at the
//! cap it waits for one to come back), runs the closure on it and puts it back. The objects must be
//! interchangeable: a run's result may not depend on which one ran it (each graph run is a pure
//! function of its inputs; the caches are inputs and outputs).

use std::sync::{Condvar, Mutex, MutexGuard};

use anyhow::Result;

/// Idle objects and how many exist.
struct Slots<T> {
    idle: Vec<T>,
    live: usize,
}

/// A pool of at most `cap` objects, made on demand.
pub(crate) struct Pool<T> {
    slots: Mutex<Slots<T>>,
    returned: Condvar,
    cap: usize,
}

impl<T> std::fmt::Debug for Pool<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.lock();
        f.debug_struct("Pool")
            .field("idle", &s.idle.len())
            .field("live", &s.live)
            .field("cap", &self.cap)
            .finish()
    }
}

/// Puts the object back when the run ends (also when it panics: then the object is dropped, as a
/// run cut short may have left it half-updated).
struct Lease<'a, T> {
    pool: &'a Pool<T>,
    item: Option<T>,
}

impl<T> Drop for Lease<'_, T> {
    fn drop(&mut self) {
        let mut s = self.pool.lock();
        match self.item.take() {
            Some(t) if !std::thread::panicking() => s.idle.push(t),
            _ => s.live -= 1,
        }
        drop(s);
        self.pool.returned.notify_one();
    }
}

impl<T> Pool<T> {
    /// An empty pool of at most `cap` objects (at least one).
    pub(crate) fn new(cap: usize) -> Self {
        Self {
            slots: Mutex::new(Slots {
                idle: Vec::new(),
                live: 0,
            }),
            returned: Condvar::new(),
            cap: cap.max(1),
        }
    }

    /// A pool holding `first` (made at load time), of at most `cap` objects.
    // the ort backend's (not in the WebAssembly build)
    #[cfg_attr(target_arch = "wasm32", allow(dead_code))]
    pub(crate) fn with_first(first: T, cap: usize) -> Self {
        let p = Self::new(cap);
        {
            let mut s = p.lock();
            s.idle.push(first);
            s.live = 1;
        }
        p
    }

    // the slots are consistent after every panic (`Lease` and `with` update them with no call in
    // between that can panic), so a poisoned lock is taken over
    fn lock(&self) -> MutexGuard<'_, Slots<T>> {
        self.slots.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// How many objects exist (idle or running).
    #[cfg_attr(target_arch = "wasm32", allow(dead_code))]
    pub(crate) fn live(&self) -> usize {
        self.lock().live
    }

    /// Runs `f` on an idle object, or on one made by `make` while fewer than the cap exist, or waits
    /// for one to come back.
    pub(crate) fn with<R>(
        &self,
        make: impl FnOnce() -> Result<T>,
        f: impl FnOnce(&mut T) -> Result<R>,
    ) -> Result<R> {
        // an idle object, or a free slot to make one in (None); the lock is released before the run
        let idle = {
            let mut s = self.lock();
            loop {
                if let Some(t) = s.idle.pop() {
                    break Some(t);
                }
                if s.live < self.cap {
                    s.live += 1;
                    break None;
                }
                s = self.returned.wait(s).unwrap_or_else(|e| e.into_inner());
            }
        };
        let item = match idle {
            Some(t) => t,
            None => match make() {
                Ok(t) => t,
                Err(e) => {
                    self.lock().live -= 1;
                    self.returned.notify_one();
                    return Err(e);
                }
            },
        };
        let mut lease = Lease {
            pool: self,
            item: Some(item),
        };
        let t = lease.item.as_mut().expect("the lease holds its object");
        f(t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::{Arc, Barrier};

    #[test]
    fn reuses_idle_objects_and_makes_new_ones_only_under_contention() {
        let made = AtomicUsize::new(0);
        let p: Pool<usize> = Pool::new(4);
        for _ in 0..5 {
            p.with(|| Ok(made.fetch_add(1, Ordering::SeqCst)), |_| Ok(()))
                .unwrap();
        }
        assert_eq!(
            made.load(Ordering::SeqCst),
            1,
            "one object serves runs one after the other"
        );
        // two runs at once need two objects
        let p = Arc::new(p);
        let made = Arc::new(made);
        let both = Arc::new(Barrier::new(2));
        let hs: Vec<_> = (0..2)
            .map(|_| {
                let (p, made, both) = (Arc::clone(&p), Arc::clone(&made), Arc::clone(&both));
                std::thread::spawn(move || {
                    p.with(
                        || Ok(made.fetch_add(1, Ordering::SeqCst)),
                        |_| {
                            both.wait();
                            Ok(())
                        },
                    )
                    .unwrap()
                })
            })
            .collect();
        for h in hs {
            h.join().unwrap();
        }
        assert_eq!(made.load(Ordering::SeqCst), 2);
        assert_eq!(p.live(), 2);
    }

    #[test]
    fn the_cap_makes_runs_wait_and_a_failed_make_frees_its_slot() {
        let p = Arc::new(Pool::<u32>::new(1));
        let inside = Arc::new(AtomicUsize::new(0));
        let most = Arc::new(AtomicUsize::new(0));
        let hs: Vec<_> = (0..4)
            .map(|_| {
                let (p, inside, most) = (Arc::clone(&p), Arc::clone(&inside), Arc::clone(&most));
                std::thread::spawn(move || {
                    p.with(
                        || Ok(0),
                        |_| {
                            let n = inside.fetch_add(1, Ordering::SeqCst) + 1;
                            most.fetch_max(n, Ordering::SeqCst);
                            std::thread::sleep(std::time::Duration::from_millis(5));
                            inside.fetch_sub(1, Ordering::SeqCst);
                            Ok(())
                        },
                    )
                    .unwrap()
                })
            })
            .collect();
        for h in hs {
            h.join().unwrap();
        }
        assert_eq!(
            most.load(Ordering::SeqCst),
            1,
            "a cap of one runs one at a time"
        );
        let q = Pool::<u32>::new(1);
        assert!(q
            .with(|| Err(anyhow::anyhow!("no session")), |_| Ok(()))
            .is_err());
        assert_eq!(q.live(), 0, "a failed make gives its slot back");
        let got = q.with(|| Ok(7), |t| Ok(*t)).unwrap();
        assert_eq!(got, 7);
    }
}
