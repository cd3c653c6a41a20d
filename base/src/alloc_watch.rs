//! The system allocator keeping count of what is allocated, for tests that bound what a hostile
//! file makes a reader reserve. A test binary installs it with
//! `#[global_allocator] static A: base::alloc_watch::Watching = base::alloc_watch::Watching;`
//! and measures a call with [`on_this_thread`] (the largest single request and the peak of
//! live bytes the call held, on the calling thread) or [`across_threads`] (the peak of live
//! bytes over every thread, for parallel work; meaningful only while nothing else runs in the
//! binary).
//!
//! A request above [`HARD_LIMIT`] fails (the process aborts saying "memory allocation of N
//! bytes failed"): a reader that a few bytes can talk into reserving gigabytes then fails its
//! test instead of taking the machine's memory with it.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicIsize, Ordering};

/// The largest single request a watched binary may make.
pub const HARD_LIMIT: usize = 4 << 30;

thread_local! {
    /// The largest allocation this thread made since the last [`largest`].
    static LARGEST: Cell<usize> = const { Cell::new(0) };
    /// Bytes this thread allocated minus bytes it freed (memory allocated on one thread and
    /// freed on another moves between the counts, so only differences are meaningful).
    static LIVE: Cell<isize> = const { Cell::new(0) };
    /// The most `LIVE` has been since [`on_this_thread`] started measuring.
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

/// Live bytes over all threads, and their peak since [`across_threads`] started.
static GLOBAL_LIVE: AtomicIsize = AtomicIsize::new(0);
static GLOBAL_PEAK: AtomicIsize = AtomicIsize::new(0);

/// The system allocator, keeping count.
pub struct Watching;

fn grew(bytes: usize) {
    let bytes = bytes as isize;
    let _ = LARGEST.try_with(|l| l.set(l.get().max(bytes as usize)));
    let _ = LIVE.try_with(|l| {
        let now = l.get() + bytes;
        l.set(now);
        let _ = PEAK.try_with(|p| p.set(p.get().max(now)));
    });
    let now = GLOBAL_LIVE.fetch_add(bytes, Ordering::Relaxed) + bytes;
    GLOBAL_PEAK.fetch_max(now, Ordering::Relaxed);
}

fn shrank(bytes: usize) {
    let bytes = bytes as isize;
    let _ = LIVE.try_with(|l| l.set(l.get() - bytes));
    GLOBAL_LIVE.fetch_sub(bytes, Ordering::Relaxed);
}

unsafe impl GlobalAlloc for Watching {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > HARD_LIMIT {
            return std::ptr::null_mut();
        }
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        shrank(layout.size());
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > HARD_LIMIT {
            return std::ptr::null_mut();
        }
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > HARD_LIMIT {
            return std::ptr::null_mut();
        }
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            // Counted as the new block arriving before the old one leaves, which is what a
            // copying reallocation holds at its peak.
            grew(new_size);
            shrank(layout.size());
        }
        p
    }
}

/// The largest allocation on this thread since the last call, resetting it.
pub fn largest() -> usize {
    LARGEST.with(|l| l.replace(0))
}

/// What a measured call allocated on its thread.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Usage {
    /// The largest single request.
    pub largest: usize,
    /// The most bytes the call held at once beyond what the thread held when it began.
    pub peak: usize,
}

/// Runs `f` and reports what it allocated on this thread (work it hands to other threads is
/// not counted: see [`across_threads`]).
pub fn on_this_thread<R>(f: impl FnOnce() -> R) -> (R, Usage) {
    let before_largest = LARGEST.with(|l| l.replace(0));
    let start = LIVE.with(|l| l.get());
    let outer_peak = PEAK.with(|p| p.replace(start));
    let r = f();
    let peak = PEAK.with(|p| p.replace(outer_peak.max(p.get())));
    let largest = LARGEST.with(|l| l.replace(before_largest.max(l.get())));
    let usage = Usage {
        largest,
        peak: (peak - start).max(0) as usize,
    };
    (r, usage)
}

/// Runs `f` and reports the most bytes held at once over every thread beyond what was live
/// when it began.
pub fn across_threads<R>(f: impl FnOnce() -> R) -> (R, usize) {
    let start = GLOBAL_LIVE.load(Ordering::Relaxed);
    GLOBAL_PEAK.store(start, Ordering::Relaxed);
    let r = f();
    let peak = GLOBAL_PEAK.load(Ordering::Relaxed);
    (r, (peak - start).max(0) as usize)
}
