//! Shared helpers for the integration tests.

use ehactl_config::RigConfig;
use ehactl_plant::PlantParams;
use std::path::PathBuf;

/// Repository root.
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Load a config from configs/.
pub fn config(name: &str) -> RigConfig {
    RigConfig::load(&repo().join("configs").join(name)).expect("config loads")
}

/// A minimal blocked-cylinder plant: zero-lapped valve held closed, the 003 cylinder,
/// given mass and damping, no effects. Used for closed-form checks.
pub fn blocked_cylinder(mass: f64, damping: f64, x0: f64) -> PlantParams {
    let text = format!(
        r#"
[fluid]
density = 900.0
bulk_modulus = 1.8e9
[supply]
pressure = 24.0e6
[valve]
command_full_scale = 10.0
flow_form = "kq"
rated_flow = 5.8333e-4
rated_pressure_drop = 1.0e6
[cylinder]
area_a = 1.96e-3
area_b = 1.3e-3
dead_volume_a = 1.0e-4
dead_volume_b = 1.0e-4
stroke = 1.2
initial_position = {x0}
[mechanics]
mass = {mass}
damping = {damping}
end_stops = false
"#
    );
    toml::from_str(&text).expect("valid plant")
}

/// A global allocator that forwards to the system allocator and counts allocations per
/// thread, for the zero-allocation tests. A test binary installs it with
/// `#[global_allocator] static GLOBAL: CountingAlloc = CountingAlloc;` and reads
/// [`allocations`] around the code under test.
pub struct CountingAlloc;

thread_local! {
    // Per thread: other tests of the same binary run in parallel threads.
    static ALLOCS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

/// Allocations made so far by the calling thread (0 unless [`CountingAlloc`] is installed).
pub fn allocations() -> u64 {
    ALLOCS.with(|c| c.get())
}

// SAFETY: forwards to the system allocator; only counts (a const-initialised Cell
// thread-local needs no allocation and no destructor).
unsafe impl std::alloc::GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, l: std::alloc::Layout) -> *mut u8 {
        ALLOCS.with(|c| c.set(c.get() + 1));
        std::alloc::System.alloc(l)
    }
    unsafe fn alloc_zeroed(&self, l: std::alloc::Layout) -> *mut u8 {
        ALLOCS.with(|c| c.set(c.get() + 1));
        std::alloc::System.alloc_zeroed(l)
    }
    unsafe fn realloc(&self, p: *mut u8, l: std::alloc::Layout, n: usize) -> *mut u8 {
        ALLOCS.with(|c| c.set(c.get() + 1));
        std::alloc::System.realloc(p, l, n)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: std::alloc::Layout) {
        std::alloc::System.dealloc(p, l)
    }
}
