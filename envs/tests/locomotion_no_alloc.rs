//! The locomotion envs' `step`, `reset` and reward calls do not allocate: a counting
//! global allocator sees no allocation on this thread while they run.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

use ess_envs::{Env, Humanoid, HumanoidConfig, Walker2d, Walker2dConfig};

/// Allocations made while counting was on (on any thread that turned it on).
static COUNT: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

struct Counting;

// SAFETY: forwards every call to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.with(Cell::get) {
            COUNT.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.with(Cell::get) {
            COUNT.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `steps` env steps (resets included) with fixed pseudo-random
/// actions, all buffers allocated up front.
fn allocations(env: &mut dyn Env, steps: usize) -> usize {
    let spec = env.spec().clone();
    let mut obs = vec![0.0f32; spec.obs_dim];
    let mut act = vec![0.0f32; spec.act_dim];
    let mut r = vec![0.0f32; spec.n_modes];
    let mut seed = 0;
    env.reset(seed, &mut obs).expect("reset");
    COUNT.store(0, Ordering::Relaxed);
    COUNTING.with(|c| c.set(true));
    for i in 0..steps {
        for (j, a) in act.iter_mut().enumerate() {
            *a = (((i * 31 + j * 17) % 41) as f32 / 20.0) - 1.0;
        }
        let out = env.step(&act, &mut obs).expect("step");
        env.mode_rewards(&mut r);
        env.task_rewards(&mut r);
        let _ = env.forward_velocity();
        if out.done() {
            seed += 1;
            env.reset(seed, &mut obs).expect("reset");
        }
    }
    COUNTING.with(|c| c.set(false));
    COUNT.load(Ordering::Relaxed)
}

#[test]
fn stepping_and_resetting_the_locomotion_envs_does_not_allocate() {
    let mut walker = Walker2d::new(Walker2dConfig::default()).expect("walker2d");
    assert_eq!(allocations(&mut walker, 500), 0, "walker2d");
    let mut humanoid = Humanoid::new(HumanoidConfig::default()).expect("humanoid");
    assert_eq!(allocations(&mut humanoid, 500), 0, "humanoid");
    // The counter does see allocations.
    COUNT.store(0, Ordering::Relaxed);
    COUNTING.with(|c| c.set(true));
    drop(std::hint::black_box(Vec::<u8>::with_capacity(8)));
    COUNTING.with(|c| c.set(false));
    assert_eq!(COUNT.load(Ordering::Relaxed), 1);
}
