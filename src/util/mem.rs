//! The process's peak resident memory (Linux `/proc/self/status` `VmHWM`), which the survey exports print so that
//! their host-memory bound can be checked on any run, and its reset between the stages of `msnerf process`.

/// Peak resident set size in bytes; None where `/proc` does not say.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Resets the peak resident set size to the current one (Linux: `5` into `/proc/self/clear_refs`), so that a stage
/// of a longer run can measure its own peak. Memory an earlier stage freed is first handed back to the system
/// (glibc's `malloc_trim`), or the allocator's kept pages would count as the next stage's. Returns whether it could.
pub fn reset_peak_rss() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free heap pages; any pad is valid.
    unsafe {
        libc::malloc_trim(0);
    }
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// The largest peak resident set size of the child processes waited for so far (COLMAP), in bytes (`getrusage`);
/// None where the platform does not say.
pub fn children_peak_rss_bytes() -> Option<u64> {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: getrusage fills the struct it is given; RUSAGE_CHILDREN is a valid `who`.
        let mut u: libc::rusage = unsafe { std::mem::zeroed() };
        let rc = unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut u) };
        (rc == 0 && u.ru_maxrss > 0).then(|| u.ru_maxrss as u64 * 1024)
    }
    #[cfg(not(target_os = "linux"))]
    {
        None
    }
}
