//! Giving memory back: after a large job ends or a large file has been taken in, the freed
//! heap is returned to the system (glibc keeps it otherwise, and the daemon's resident memory
//! would stay at its peak), and the daemon's resident size can be read for the benchmark.

/// Returns freed heap pages to the system (glibc's `malloc_trim`, every arena); a no-op
/// elsewhere.
pub fn give_back() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks and trims the allocator's own free lists
    unsafe {
        libc::malloc_trim(0);
    }
}

/// The resident memory of process `pid` (this process for None), in bytes, from
/// /proc/PID/status.
pub fn resident_bytes(pid: Option<u32>) -> Option<u64> {
    let path = match pid {
        Some(p) => format!("/proc/{p}/status"),
        None => "/proc/self/status".to_string(),
    };
    let text = std::fs::read_to_string(path).ok()?;
    let line = text.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
