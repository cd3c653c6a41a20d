//! Decoding a capture's photos in parallel holds a bounded number of pixels at once, however
//! many threads there are: the loaders decode in groups that fit the budget. Alone in its
//! binary, because it measures the live memory of every thread.

mod common;

use scenes::{BitDepth, OpenOptions, Resolution};

#[global_allocator]
static ALLOCATOR: base::alloc_watch::Watching = base::alloc_watch::Watching;

const SIDE: u32 = 1024;
const VIEWS: usize = 8;

#[test]
fn parallel_decoding_holds_what_the_budget_allows() {
    let dir = tempfile::tempdir().unwrap();
    let (cameras, bounds) = common::arc_cameras(VIEWS, SIDE, SIDE, 7);
    let photos: Vec<_> = (0..VIEWS).map(|k| common::pattern(SIDE, SIDE, k)).collect();
    let dest = dir.path().join("capture");
    scenes::llff::write_llff(&dest, &cameras, &bounds, &photos, 1, BitDepth::Sixteen).unwrap();
    drop(photos);
    let capture = scenes::open(
        &dest,
        &OpenOptions {
            resolution: Resolution::Downsample(1),
            llffhold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(VIEWS)
        .build()
        .unwrap();
    let pixels = u64::from(SIDE * SIDE);
    let measure = |budget: u64| {
        pool.install(|| base::alloc_watch::across_threads(|| capture.check_images_within(budget)))
    };
    // One photo's decoding: its float RGB plus the decoder's 16-bit buffer and rows.
    let per_photo = pixels as usize * (12 + 6);
    let (ok, bounded) = measure(2 * pixels);
    ok.unwrap();
    let (ok, unbounded) = measure(u64::MAX);
    ok.unwrap();
    eprintln!(
        "peak while decoding {VIEWS} photos of {SIDE}x{SIDE} on {VIEWS} threads: {} MB within two photos' pixels, {} MB unbounded",
        bounded >> 20,
        unbounded >> 20
    );
    assert!(
        bounded <= 2 * per_photo + per_photo / 2,
        "decoding two photos at a time held {bounded} bytes (one photo's decode is about {per_photo})"
    );
    // What the budget prevents: every thread decoding at once.
    assert!(
        unbounded > bounded * 3 / 2,
        "unbounded decoding held {unbounded} bytes, bounded {bounded}"
    );
    // The photos the loader keeps are those asked for, in order.
    let kept = capture.load_images_within(&[3, 1], pixels).unwrap();
    assert_eq!(kept[0].data, capture.load_image(3).unwrap().data);
    assert_eq!(kept[1].data, capture.load_image(1).unwrap().data);
}
