//! The heap while geometry runs. An offset takes and frees a few buffers of its input's
//! size at every stage, and a pocket offsets pass after pass. glibc serves a block over
//! 128 KiB by a fresh mapping, and gives the top of the heap back to the system as soon as
//! a little is free there, so each such buffer is faulted in page by page again: a fifth
//! of the time of a 10,000-vertex offset and of a 100,000-vertex one (docs/BENCHMARKS.md,
//! round of 2026-12-07). A process that plans calls [`hold_freed_memory`] once, first.
//!
//! Only processes that end after planning call it (the planner's child, the `plan`,
//! `offset` and `preview` commands, the benches): the daemon itself keeps glibc's defaults
//! and gives memory back after each job (`machlink::services::memory`).

/// Blocks below this come from the heap, not a fresh mapping of their own.
const MAPPED_FROM: usize = 1 << 30;
/// Free memory at the top of the heap is given back only past this.
const TRIMMED_PAST: usize = 1 << 30;

/// Has glibc keep freed memory for the next buffer (see the module's paragraph); false
/// where the C library is not glibc or refused a threshold.
pub fn hold_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets two of the allocator's thresholds; it takes the arena's
    // lock as any allocation does
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MAPPED_FROM as libc::c_int) == 1
            && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIMMED_PAST as libc::c_int) == 1
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    false
}

#[cfg(all(test, target_os = "linux", target_env = "gnu"))]
mod tests {
    use super::*;

    /// The page faults this thread has taken so far.
    fn faults() -> i64 {
        // SAFETY: getrusage writes the zeroed struct it is handed
        unsafe {
            let mut u: libc::rusage = std::mem::zeroed();
            assert_eq!(libc::getrusage(libc::RUSAGE_THREAD, &mut u), 0);
            u.ru_minflt
        }
    }

    /// A buffer written in full, freed, and taken and written again, as a stage's buffers
    /// are: the faults of the second time.
    fn faults_of_a_second_buffer(bytes: usize) -> i64 {
        let fill = |v: &mut Vec<u8>| {
            v.resize(bytes, 1);
            std::hint::black_box(&v);
        };
        let mut v = Vec::new();
        fill(&mut v);
        drop(v);
        let before = faults();
        let mut v = Vec::new();
        fill(&mut v);
        let taken = faults() - before;
        drop(v);
        taken
    }

    #[test]
    fn a_freed_buffer_is_taken_again_without_faulting_its_pages_in() {
        // (past 32 MiB, which glibc's own sliding threshold never reaches: whatever ran before)
        let bytes = 48 << 20;
        let pages = (bytes / 4096) as i64;
        // glibc's default: a block this size is a mapping of its own, every page faulted in
        // again (run on its own thread, before the thresholds change)
        let by_default = std::thread::spawn(move || faults_of_a_second_buffer(bytes)).join();
        assert!(hold_freed_memory(), "glibc refused the thresholds");
        let held = std::thread::spawn(move || faults_of_a_second_buffer(bytes)).join();
        let (by_default, held) = (by_default.unwrap(), held.unwrap());
        assert!(
            by_default > pages / 2,
            "{by_default} faults of {pages} pages by default"
        );
        assert!(
            held < pages / 10,
            "{held} faults of {pages} pages with freed memory held"
        );
    }
}
