//! What reading and writing a URDF cost in memory: its robot's elements (and the document written), not its comments (a binary of its own, so that its
//! allocator counts this test's allocations only).

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use dynforge_robot::generator::generate;

use dynforge_proto::generator::GeneratorConfig;
use dynforge_robot::urdf;

struct Peak;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Peak {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let live = LIVE.fetch_add(layout.size(), Ordering::SeqCst) + layout.size();
        PEAK.fetch_max(live, Ordering::SeqCst);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Ordering::SeqCst);
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Peak = Peak;

/// The most memory `f` holds at once beyond what was held before it.
fn peak_of<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let before = LIVE.load(Ordering::SeqCst);
    PEAK.store(before, Ordering::SeqCst);
    let out = f();
    (out, PEAK.load(Ordering::SeqCst) - before)
}

/// A 16 MB comment (and markup inside comments, and a CDATA section holding a comment mark) leaves the model as it
/// is without them, with what the parse holds at once bounded by the comment-free document's needs: the reader
/// copies its input several times, 8x the file before comments were taken out.
#[test]
fn comments_are_neither_read_as_elements_nor_paid_for_in_memory() {
    let plain = generate(&GeneratorConfig::default(), 1, 3).unwrap().urdf();
    let (reference, small) = peak_of(|| urdf::parse(&plain, "plain.urdf").unwrap());
    let robot = plain.find("<robot").unwrap();
    let at = robot + plain[robot..].find('>').unwrap() + 1;
    let body = plain.find("<link").unwrap();
    let commented = format!(
        "{}\n<!--{}-->\n<!-- <link name=\"ghost\"/>\n  <joint name=\"ghost\" type=\"revolute\"/> -->\n\
         <gazebo><plugin><![CDATA[ <!-- not a comment ]]></plugin></gazebo>\n{}",
        &plain[..at],
        "x".repeat(16 << 20),
        &plain[body..]
    );
    let (model, held) = peak_of(|| urdf::parse(&commented, "commented.urdf").unwrap());
    assert_eq!(model, reference, "the comments changed the model");
    // The comment-free copy is at most 1 MB of capacity plus what the plain document's parse takes.
    assert!(held < small + (2 << 20), "parsing held {held} bytes at once, the comment-free document {small}");
    let joints = urdf::movable_joints(&commented, "commented.urdf").unwrap();
    assert_eq!(joints.free.len(), reference.dof());
    // Writing parameters into it keeps the comment and holds the document written (one copy) and little more.
    let ((written, _), held) = peak_of(|| urdf::patch(&commented, "commented.urdf", &model).unwrap());
    assert!(written.contains(&"x".repeat(16 << 20)), "the comment was not kept");
    assert!(held < written.len() + small + (2 << 20), "patching held {held} bytes at once for {}", written.len());
}
