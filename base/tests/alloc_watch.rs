//! The watching allocator's counts against allocations whose sizes are known.

use base::alloc_watch::{HARD_LIMIT, across_threads, on_this_thread};

#[global_allocator]
static ALLOCATOR: base::alloc_watch::Watching = base::alloc_watch::Watching;

const MB: usize = 1 << 20;

/// The tests take turns: memory another test frees would hide some of a measured call's.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn turn() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

#[test]
fn a_call_reports_its_largest_request_and_what_it_held_at_once() {
    let _turn = turn();
    let ((), u) = on_this_thread(|| {
        let a = vec![1u8; 3 * MB];
        drop(std::hint::black_box(a));
        let b = vec![1u8; 2 * MB];
        let c = vec![1u8; 2 * MB];
        std::hint::black_box((&b, &c));
    });
    assert_eq!(u.largest, 3 * MB);
    // Two 2 MB vectors at once beat the 3 MB one alone; a few bytes of the harness' own.
    assert!((4 * MB..4 * MB + 64 * 1024).contains(&u.peak), "{u:?}");

    // Growing by doubling holds the old block and the new one while it copies.
    let (v, u) = on_this_thread(|| {
        let mut v = Vec::<u8>::new();
        for i in 0..(4 * MB) {
            v.push(i as u8);
        }
        v
    });
    assert_eq!(v.capacity(), 4 * MB);
    assert!(u.peak >= 4 * MB + 2 * MB, "{u:?}");

    // Memory the caller already held does not count, nor does what the call frees of it.
    let held = vec![1u8; 8 * MB];
    let (held, u) = on_this_thread(move || {
        drop(held);
        vec![0u8; MB]
    });
    assert_eq!(held.len(), MB);
    assert!(u.peak <= MB + 64 * 1024, "{u:?}");
}

#[test]
fn nested_measurements_see_their_own_share() {
    let _turn = turn();
    let ((), outer) = on_this_thread(|| {
        let a = vec![1u8; 5 * MB];
        let ((), inner) = on_this_thread(|| {
            std::hint::black_box(vec![1u8; MB]);
        });
        assert!(inner.peak < 2 * MB && inner.largest == MB, "{inner:?}");
        std::hint::black_box(a);
    });
    assert_eq!(outer.largest, 5 * MB);
    assert!(outer.peak >= 6 * MB, "{outer:?}");
}

#[test]
fn a_request_above_the_hard_limit_fails_instead_of_being_made() {
    let _turn = turn();
    let mut v = Vec::<u8>::new();
    assert!(v.try_reserve_exact(HARD_LIMIT + 1).is_err());
    assert!(v.try_reserve_exact(MB).is_ok());
}

#[test]
fn work_on_other_threads_counts_across_threads() {
    let _turn = turn();
    let ((), peak) = across_threads(|| {
        std::thread::scope(|s| {
            let (tx, rx) = std::sync::mpsc::channel::<()>();
            let (tx2, rx2) = std::sync::mpsc::channel::<()>();
            s.spawn(move || {
                let a = vec![1u8; 3 * MB];
                tx.send(()).unwrap();
                rx2.recv().unwrap();
                std::hint::black_box(a);
            });
            rx.recv().unwrap();
            let b = vec![1u8; 3 * MB];
            tx2.send(()).unwrap();
            std::hint::black_box(b);
        });
    });
    assert!(peak >= 6 * MB, "{peak}");
}
