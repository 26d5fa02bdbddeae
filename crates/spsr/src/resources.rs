//! Process-wide facts the pipeline asks the operating system for: the peak resident memory
//! (reported per stage) and the memory still available (the default limit of a run). Linux
//! reports both through `/proc`; elsewhere they are unknown (`None`).

/// The process's peak resident set size so far, in bytes (Linux `VmHWM`).
pub fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    proc_kib(&status, "VmHWM:").map(|kb| kb * 1024)
}

/// Memory the machine can still give this process: available memory plus what the process
/// already holds, in bytes (Linux).
pub fn memory_budget() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    let available = proc_kib(&meminfo, "MemAvailable:")? * 1024;
    let status = std::fs::read_to_string("/proc/self/status").ok();
    let own = status.and_then(|s| proc_kib(&s, "VmRSS:")).unwrap_or(0) * 1024;
    Some(available + own)
}

/// The value in KiB of the `/proc` line starting with `key`.
fn proc_kib(text: &str, key: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with(key))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Hands the memory freed so far back to the operating system. glibc's allocator keeps freed
/// blocks of up to 32 MiB in its per-thread arenas for reuse; between the phases of a slab
/// run, which each free everything they built, that kept memory (about half the live memory
/// at depth 11) would otherwise add to the next phase's peak, and so would the extraction's
/// scratch to the mesh check's (`pipeline::reconstruct_input`). Elsewhere it does nothing.
pub fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn malloc_trim(pad: usize) -> std::os::raw::c_int;
        }
        // SAFETY: `malloc_trim` takes no pointers; it only returns the free pages of glibc's
        // arenas to the kernel, and is safe to call from any thread at any time.
        unsafe {
            malloc_trim(0);
        }
    }
}

/// Blocks of this size and larger are given back to the operating system as soon as they are
/// freed ([`return_large_blocks_when_freed`]).
const LARGE_BLOCK: i32 = 4 << 20;

/// Makes glibc's allocator give every block of 4 MiB or more back to the operating system as
/// soon as it is freed, for the rest of the process. By default glibc raises that threshold
/// as large blocks are freed, up to 32 MiB, and keeps the freed blocks below it for reuse.
/// A reconstruction's stages each build and free arrays of that size, so its peak would be
/// well above what it holds at any time:
/// - a slab run, whose phases each build and free their slab's tree: 1,037 MiB against
///   774 MiB with this (depth 11), for about a tenth more time;
/// - a run in one piece (issue 20; 1 M points at depth 10, median of 3 alternated runs):
///   878 against 755 MiB at degree 1 and 835 against 663 MiB at degree 2, for 1–2 % more time
///   (the kernel hands out fresh pages).
///
/// Both take the trade. Elsewhere it does nothing.
pub fn return_large_blocks_when_freed() {
    /// glibc's `M_MMAP_THRESHOLD` (malloc.h).
    const M_MMAP_THRESHOLD: i32 = -3;
    set_allocator_option(M_MMAP_THRESHOLD, LARGE_BLOCK);
}

/// Makes every thread that has not yet allocated share glibc's main arena, for the rest of
/// the process. By default glibc gives each thread an arena of its own (up to eight per
/// core), and memory a worker thread freed in its arena is reused only by allocations that
/// land in that same arena: a reconstruction's parallel stages each leave their workers'
/// arenas with free space that the main thread's next arrays cannot use. Measured on 4 M
/// points at depth 10, degree 1 (issue 20): peak 728–734 MiB with an arena per thread, 671–677
/// MiB with one, the time within the runs' scatter. Threads that already have an arena keep
/// it, so call this before the worker threads start. Elsewhere it does nothing.
pub fn share_one_allocator_arena() {
    /// glibc's `M_ARENA_MAX` (malloc.h).
    const M_ARENA_MAX: i32 = -8;
    set_allocator_option(M_ARENA_MAX, 1);
}

/// glibc's `mallopt(param, value)` (Linux with glibc; elsewhere nothing).
fn set_allocator_option(param: i32, value: i32) {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn mallopt(
                param: std::os::raw::c_int,
                value: std::os::raw::c_int,
            ) -> std::os::raw::c_int;
        }
        // SAFETY: `mallopt` takes no pointers; it sets a tuning value of the allocator, which
        // glibc allows at any time from any thread.
        unsafe {
            mallopt(param, value);
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    let _ = (param, value);
}
