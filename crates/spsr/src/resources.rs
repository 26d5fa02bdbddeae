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
