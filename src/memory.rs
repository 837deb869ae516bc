//! Process memory: the peak resident size reported in `report.json`, and handing freed heap back
//! to the system between stages.
//!
//! glibc's allocator keeps freed small blocks resident, per thread arena. A stage that frees a
//! large tree of small allocations on one thread (the glTF JSON tree, ~1 GB on 100M-triangle
//! sites) leaves that memory resident while the next stage allocates afresh on rayon's
//! threads, so both count towards the peak. `malloc_trim` returns every whole free page.

/// Peak resident memory of this process so far (Linux `VmHWM`), 0 where unknown.
pub fn peak_memory_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<u64>().ok())
        })
        .map_or(0, |kb| kb * 1024)
}

/// Returns the heap's free pages to the system (glibc; elsewhere a no-op).
pub fn release_freed_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only inspects and releases the allocator's own free lists.
    unsafe {
        libc::malloc_trim(0);
    }
}
