//! The hot-loop algorithms must not touch the heap: they run millions of times per second in the workers.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use dynforge_robot::generator::generate;

use dynforge_proto::generator::GeneratorConfig;
use dynforge_robot::{Data, aba, crba, energy, forward_kinematics, friction_torque, point_jacobian, regressor, rnea};
use nalgebra::Vector3;

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn dynamics_calls_do_not_allocate() {
    let model = generate(&GeneratorConfig::default(), 1, 7).unwrap().model;
    let mut data = Data::new(&model);
    let (q, qd, qdd) = ([0.3, -0.5, 1.1, 0.2, -0.7, 0.4], [0.5; 6], [-1.0; 6]);
    let mut fric = [0.0; 6];
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    let mut sink = 0.0;
    for _ in 0..10 {
        sink += rnea(&model, &mut data, &q, &qd, &qdd)[0];
        sink += aba(&model, &mut data, &q, &qd, &qdd)[0];
        sink += crba(&model, &mut data, &q)[(0, 0)];
        sink += regressor(&model, &mut data, &q, &qd, &qdd)[(0, 0)];
        sink += energy(&model, &mut data, &q, &qd).total();
        forward_kinematics(&model, &mut data, &q);
        point_jacobian(&model, &mut data, 5, &Vector3::new(0.0, 0.0, 0.1));
        friction_torque(&model, &qd, &mut fric);
    }
    let after = ALLOCATIONS.load(Ordering::SeqCst);
    assert!(sink.is_finite());
    assert_eq!(after - before, 0, "dynamics calls allocated {} times", after - before);
}
