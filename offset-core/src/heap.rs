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
//!
//! Past a few hundred thousand segments the buffers no longer fit the caches, and walking
//! them costs a page-table walk every 4 KiB: the process's allocator, [`PlanningHeap`],
//! asks the kernel to back each block of 2 MiB or more with transparent huge pages once
//! [`hold_freed_memory`] has run (before that, and in the daemon, it is the system's
//! allocator and nothing else). Where the kernel has transparent huge pages only on
//! request (`madvise`, Debian's default) that took about 5 % off the bench gear of 100,000
//! vertices with islands and 10-14 % off the one of a million (`kernel_case`, best of
//! repeated runs: 18.6 -> 17.1-17.9 ms and 261 -> 225-236 ms); where it has them always
//! or never, the request changes nothing.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, Ordering};

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
    let held = unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MAPPED_FROM as libc::c_int) == 1
            && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIMMED_PAST as libc::c_int) == 1
    };
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    let held = false;
    HUGE_PAGES.store(held, Ordering::Relaxed);
    held
}

/// Whether [`PlanningHeap`] asks for huge pages: set by [`hold_freed_memory`].
static HUGE_PAGES: AtomicBool = AtomicBool::new(false);

/// A transparent huge page (x86-64 and most aarch64 kernels).
const HUGE_PAGE: usize = 2 << 20;

/// The system's allocator; in a process that planning ends (see [`hold_freed_memory`]),
/// blocks of [`HUGE_PAGE`] or more are asked to be backed by huge pages, the whole pages
/// inside each block (see the module's paragraph). A binary that plans installs it:
/// `#[global_allocator] static HEAP: PlanningHeap = PlanningHeap;`.
pub struct PlanningHeap;

impl PlanningHeap {
    /// Asks for huge pages under the whole huge pages of the block at `p` of `size` bytes.
    fn advise(p: *mut u8, size: usize) {
        if p.is_null() || size < HUGE_PAGE || !HUGE_PAGES.load(Ordering::Relaxed) {
            return;
        }
        let start = (p as usize).next_multiple_of(HUGE_PAGE);
        let end = (p as usize + size) / HUGE_PAGE * HUGE_PAGE;
        if end > start {
            #[cfg(target_os = "linux")]
            // SAFETY: the range lies inside a block the allocator just handed out; the
            // advice changes how its pages are backed, not their contents or mapping (a
            // refusal leaves small pages, which is all that is lost)
            unsafe {
                libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE);
            }
        }
    }
}

// SAFETY: every call is the system allocator's, with the same layout; `advise` only adds
// advice about pages of the block returned
unsafe impl GlobalAlloc for PlanningHeap {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        Self::advise(p, layout.size());
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(layout);
        Self::advise(p, layout.size());
        p
    }

    unsafe fn dealloc(&self, p: *mut u8, layout: Layout) {
        System.dealloc(p, layout)
    }

    unsafe fn realloc(&self, p: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let q = System.realloc(p, layout, new_size);
        Self::advise(q, new_size);
        q
    }
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

    /// The kilobytes of huge pages under the mapping that holds address `at`
    /// (/proc/self/smaps).
    fn huge_kb_at(at: usize) -> Option<u64> {
        let smaps = std::fs::read_to_string("/proc/self/smaps").ok()?;
        let mut inside = false;
        for line in smaps.lines() {
            if let Some((range, _)) = line.split_once(' ') {
                if let Some((a, b)) = range.split_once('-') {
                    if let (Ok(a), Ok(b)) =
                        (usize::from_str_radix(a, 16), usize::from_str_radix(b, 16))
                    {
                        inside = a <= at && at < b;
                        continue;
                    }
                }
            }
            if inside {
                if let Some(kb) = line.strip_prefix("AnonHugePages:") {
                    return kb.trim().trim_end_matches("kB").trim().parse().ok();
                }
            }
        }
        None
    }

    #[test]
    fn a_large_block_of_the_planning_heap_is_backed_by_huge_pages_where_the_kernel_has_them() {
        let thp = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled")
            .unwrap_or_default();
        // (with huge pages never given, or given to every mapping anyway, the advice has
        // nothing to change: the allocator is the system's)
        if !thp.contains("[madvise]") {
            eprintln!("transparent huge pages: {thp:?}; nothing to check");
            return;
        }
        // the flag `hold_freed_memory` sets, without the thresholds it sets (they are the
        // whole process's, and the test above measures the defaults first)
        HUGE_PAGES.store(true, Ordering::Relaxed);
        let layout = Layout::from_size_align(64 << 20, 8).unwrap();
        // SAFETY: a fresh block of the heap, written in full, then freed with its layout
        unsafe {
            let p = PlanningHeap.alloc(layout);
            assert!(!p.is_null());
            std::ptr::write_bytes(p, 1, layout.size());
            let mid = p as usize + layout.size() / 2;
            let huge = huge_kb_at(mid).expect("the block's mapping in smaps");
            PlanningHeap.dealloc(p, layout);
            assert!(huge >= 2048, "{huge} kB of huge pages under a 64 MiB block");
        }
    }
}
