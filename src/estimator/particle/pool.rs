//! A second thread for one motion's frames (issue 32): the caller and one persistent worker
//! claim the chunks of a job from a shared counter, so each chunk runs once, on either thread,
//! and writes only its own outputs; every sum over the particles is taken afterwards on the
//! caller, in the serial order. What a chunk computes does not depend on which thread runs it,
//! so the results are the same bits with or without the worker.
//!
//! The caller never waits for a worker that has not started on the job: it withdraws the job
//! once every chunk is claimed, and waits only while the worker is inside one (on a loaded
//! machine, the caller then simply does all the chunks itself).

use std::marker::PhantomData;
use std::ops::Range;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// No job; a job waiting for the worker; the worker on it; the worker done with it; stop.
const IDLE: u8 = 0;
const POSTED: u8 = 1;
const TAKEN: u8 = 2;
const DONE: u8 = 3;
const EXIT: u8 = 4;

/// How long the worker spins for the next job before sleeping (a frame's jobs follow each other
/// within tens of microseconds; a sleeping worker joins a job late, never delays it), and how
/// long the caller spins for a worker inside a chunk before yielding its core to it.
const SPIN: Duration = Duration::from_micros(60);

/// A job's work, its lifetime erased: only dereferenced between the worker's taking it and its
/// `DONE`, while [`Pool::run`] (which holds the borrow) waits.
#[derive(Clone, Copy)]
struct Work(*const (dyn Fn(usize, usize) + Sync + 'static));

// SAFETY: the pointee is `Sync`, and the pointer is only dereferenced while the borrow it was
// made from is alive (see `Work`).
unsafe impl Send for Work {}

struct Shared {
    state: AtomicU8,
    /// The next chunk to claim, and the job's chunk count and work.
    next: AtomicUsize,
    job: Mutex<Option<(usize, Work)>>,
    /// The worker's chunk panicked: the caller panics too rather than use missing outputs.
    panicked: AtomicBool,
}

/// The caller's thread and one worker (thread 0 and 1 of the work's second argument).
pub(super) struct Pool {
    shared: Arc<Shared>,
    worker: Option<JoinHandle<()>>,
    /// Not `Sync`: two callers posting jobs at once would share one counter.
    _one_caller: PhantomData<std::cell::Cell<()>>,
}

impl Pool {
    /// A pool with one worker, or `None` where the machine has a single core or no thread
    /// can be started.
    pub(super) fn new() -> Option<Self> {
        if std::thread::available_parallelism().map_or(1, usize::from) < 2 {
            return None;
        }
        let shared = Arc::new(Shared {
            state: AtomicU8::new(IDLE),
            next: AtomicUsize::new(0),
            job: Mutex::new(None),
            panicked: AtomicBool::new(false),
        });
        let theirs = Arc::clone(&shared);
        let worker = std::thread::Builder::new()
            .name("particle-filter".into())
            .spawn(move || serve(&theirs))
            .ok()?;
        Some(Self {
            shared,
            worker: Some(worker),
            _one_caller: PhantomData,
        })
    }

    /// Runs `work(chunk, thread)` once for every chunk in `0..chunks`, on this thread (0) and
    /// the worker (1), and returns when all have run, with how the work went.
    pub(super) fn run(&self, chunks: usize, work: &(dyn Fn(usize, usize) + Sync)) -> Outcome {
        let shared = &*self.shared;
        // SAFETY: only the lifetime changes; the worker dereferences the pointer only between
        // taking the job and `DONE`, and this function does not return (nor unwind, `Wait`)
        // before the job is withdrawn untaken or done.
        let erased = unsafe {
            std::mem::transmute::<
                *const (dyn Fn(usize, usize) + Sync + '_),
                *const (dyn Fn(usize, usize) + Sync + 'static),
            >(work)
        };
        *shared.job.lock().unwrap_or_else(PoisonError::into_inner) = Some((chunks, Work(erased)));
        shared.panicked.store(false, Ordering::Relaxed);
        shared.next.store(0, Ordering::Relaxed);
        shared.state.store(POSTED, Ordering::Release);
        if let Some(worker) = &self.worker {
            worker.thread().unpark();
        }
        let wait = Wait(shared);
        let mut own = 0;
        claim(shared, chunks, |chunk| {
            work(chunk, 0);
            own += 1;
        });
        let done = Instant::now();
        drop(wait);
        if shared.panicked.swap(false, Ordering::Relaxed) {
            panic!("the particle filter's worker thread panicked");
        }
        Outcome {
            own,
            chunks,
            waited: done.elapsed(),
        }
    }
}

/// A pool kept between motions (starting a thread per motion costs a wake-up and a join on a
/// loaded machine); a clone starts without one.
#[derive(Default)]
pub(super) struct Spare(Mutex<Option<Pool>>);

impl Spare {
    /// The kept pool, else a new one.
    pub(super) fn take(&self) -> Option<Pool> {
        let kept = self.0.lock().unwrap_or_else(PoisonError::into_inner).take();
        kept.or_else(Pool::new)
    }

    /// Keeps `pool` for the next motion (one pool at most).
    pub(super) fn keep(&self, pool: Pool) {
        let mut slot = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        if slot.is_none() {
            *slot = Some(pool);
        }
    }
}

impl Clone for Spare {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl std::fmt::Debug for Spare {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Spare")
    }
}

/// How a job went: the chunks the caller ran itself, of all, and how long it waited for the
/// worker's last chunk.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Outcome {
    pub(super) own: usize,
    pub(super) chunks: usize,
    pub(super) waited: Duration,
}

impl Outcome {
    /// Both jobs' counts and waits.
    pub(super) fn add(self, other: Self) -> Self {
        Self {
            own: self.own + other.own,
            chunks: self.chunks + other.chunks,
            waited: self.waited + other.waited,
        }
    }
}

/// A slice whose disjoint ranges a job's chunks write, each from its own thread.
pub(super) struct Disjoint<'a, T> {
    start: *mut T,
    len: usize,
    _slice: PhantomData<&'a mut [T]>,
}

// SAFETY: shares only what `&mut [T]` would send to each thread, one range each (`range`).
unsafe impl<T: Send> Sync for Disjoint<'_, T> {}

impl<'a, T> Disjoint<'a, T> {
    pub(super) fn new(slice: &'a mut [T]) -> Self {
        Self {
            start: slice.as_mut_ptr(),
            len: slice.len(),
            _slice: PhantomData,
        }
    }

    /// The elements `range` (clamped to the slice).
    ///
    /// # Safety
    /// No two ranges taken during the `Disjoint`'s life may overlap while both are in use:
    /// each chunk of a job takes its own.
    #[allow(clippy::mut_from_ref)]
    pub(super) unsafe fn range(&self, range: Range<usize>) -> &mut [T] {
        let end = range.end.min(self.len);
        let start = range.start.min(end);
        // SAFETY: within the slice, and not overlapping any other range in use (the caller's
        // promise), so this is the only reference to these elements.
        unsafe { std::slice::from_raw_parts_mut(self.start.add(start), end - start) }
    }
}

/// Withdraws the job, or waits for the worker to finish it, also when the caller unwinds.
struct Wait<'a>(&'a Shared);

impl Drop for Wait<'_> {
    fn drop(&mut self) {
        let state = &self.0.state;
        if (state.compare_exchange(POSTED, IDLE, Ordering::AcqRel, Ordering::Acquire)).is_ok() {
            return;
        }
        // The worker is inside a chunk: a chunk's time, unless it was preempted.
        let start = Instant::now();
        while state.load(Ordering::Acquire) != DONE {
            match start.elapsed() < SPIN {
                true => std::hint::spin_loop(),
                false => std::thread::yield_now(),
            }
        }
        state.store(IDLE, Ordering::Release);
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        self.shared.state.store(EXIT, Ordering::Release);
        if let Some(worker) = self.worker.take() {
            worker.thread().unpark();
            // A worker that panicked outside a chunk has nothing left to report.
            let _ = worker.join();
        }
    }
}

/// Claims and runs chunks until none is left.
fn claim(shared: &Shared, chunks: usize, mut run: impl FnMut(usize)) {
    loop {
        let chunk = shared.next.fetch_add(1, Ordering::Relaxed);
        if chunk >= chunks {
            return;
        }
        run(chunk);
    }
}

/// The worker's loop: wait for a job (spinning a while, then asleep), take it, claim chunks.
fn serve(shared: &Shared) {
    loop {
        let start = Instant::now();
        loop {
            match shared.state.load(Ordering::Acquire) {
                EXIT => return,
                POSTED => break,
                _ if start.elapsed() < SPIN => std::hint::spin_loop(),
                _ => std::thread::park(),
            }
        }
        if (shared.state)
            .compare_exchange(POSTED, TAKEN, Ordering::AcqRel, Ordering::Acquire)
            .is_err()
        {
            continue;
        }
        let job = *shared.job.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some((chunks, Work(work))) = job {
            // SAFETY: the job is taken and not yet done, so `Pool::run` still holds the borrow.
            let work = unsafe { &*work };
            let outcome = catch_unwind(AssertUnwindSafe(|| {
                claim(shared, chunks, |chunk| work(chunk, 1));
            }));
            if outcome.is_err() {
                shared.panicked.store(true, Ordering::Relaxed);
            }
        }
        shared.state.store(DONE, Ordering::Release);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_chunk_runs_once_whoever_claims_it() {
        let Some(pool) = Pool::new() else { return };
        for chunks in [0, 1, 2, 3, 79, 1000] {
            for _ in 0..50 {
                let runs: Vec<AtomicUsize> = (0..chunks).map(|_| AtomicUsize::new(0)).collect();
                let threads = [AtomicUsize::new(0), AtomicUsize::new(0)];
                pool.run(chunks, &|chunk, thread| {
                    runs[chunk].fetch_add(1, Ordering::Relaxed);
                    threads[thread].fetch_add(1, Ordering::Relaxed);
                });
                assert!(
                    runs.iter().all(|r| r.load(Ordering::Relaxed) == 1),
                    "{chunks}"
                );
                let total: usize = threads.iter().map(|t| t.load(Ordering::Relaxed)).sum();
                assert_eq!(total, chunks);
            }
        }
        // Chunks long enough for the worker to wake: it takes a share of some job.
        let theirs = AtomicUsize::new(0);
        for _ in 0..50 {
            let outcome = pool.run(100, &|_, thread| {
                std::thread::sleep(Duration::from_micros(20));
                theirs.fetch_add(thread, Ordering::Relaxed);
            });
            assert_eq!(outcome.chunks, 100);
            assert!(outcome.own <= 100);
        }
        assert!(theirs.load(Ordering::Relaxed) > 0);
    }

    #[test]
    fn a_panic_in_a_chunk_reaches_the_caller_and_the_pool_goes_on() {
        let Some(pool) = Pool::new() else { return };
        for _ in 0..20 {
            let outcome = catch_unwind(AssertUnwindSafe(|| {
                pool.run(64, &|chunk, _| assert_ne!(chunk, 40, "chunk 40"));
            }));
            assert!(outcome.is_err());
        }
        let count = AtomicUsize::new(0);
        pool.run(10, &|_, _| {
            count.fetch_add(1, Ordering::Relaxed);
        });
        assert_eq!(count.load(Ordering::Relaxed), 10);
    }
}
