//! The cost and aggregation volumes' memory: w·h·D u16 each, 320 MiB at 1280 × 1024 × 128.
//!
//! In 4 KiB pages such a volume is 82 000 page faults on first touch, and where the first touch
//! is a read (a sum read before it is added to) every page is mapped twice: the shared zero page,
//! then a copy, whose swap flushes the other threads' TLBs by interrupt. `perf` put a third of
//! a 1280 × 1024 pair's time in the kernel that way (`docs/performance.md`). On Linux the
//! volumes therefore ask for transparent huge pages (`madvise(MADV_HUGEPAGE)`, honoured where
//! `/sys/kernel/mm/transparent_hugepage/enabled` is `always` or `madvise`), 2 MiB a fault, and
//! are written before they are read.

use rayon::prelude::*;

/// A vector of `len` copies of `value`, in huge pages where the system gives them, written by
/// every thread (faulting 320 MiB in takes the kernel a few tenths of a second).
pub fn filled<T: Copy + Send + Sync>(len: usize, value: T) -> Vec<T> {
    let mut volume: Vec<T> = Vec::with_capacity(len);
    advise_huge_pages(volume.as_mut_ptr().cast(), len * size_of::<T>());
    fill(&mut volume, len, value);
    volume
}

/// `volume` as `len` copies of `value`, written in parallel into its capacity, a chunk at a
/// time (rayon's `collect_into_vec` writes element by element: 5 % of a 1280 × 1024 pair).
fn fill<T: Copy + Send + Sync>(volume: &mut Vec<T>, len: usize, value: T) {
    volume.clear();
    volume.reserve(len);
    volume.spare_capacity_mut()[..len]
        .par_chunks_mut(1 << 16)
        .for_each(|chunk| chunk.fill(std::mem::MaybeUninit::new(value)));
    // SAFETY: the first `len` elements of the capacity were all written just above.
    unsafe { volume.set_len(len) };
}

/// `volume` as `len` copies of `value`, reusing its memory where it has room (no page is faulted
/// in again), else [`filled`] afresh.
pub fn refill<T: Copy + Send + Sync>(volume: &mut Vec<T>, len: usize, value: T) {
    if volume.capacity() < len {
        *volume = Vec::new();
        *volume = filled(len, value);
    } else {
        fill(volume, len, value);
    }
}

/// The two volumes of a depth map, kept from one depth map to the next (the consistency check's
/// maps, the frames of a sequence) so that their pages are faulted in once.
#[derive(Debug, Default)]
pub struct Volumes {
    /// The matching costs, `[(y·w + x)·D + h]`.
    pub cost: Vec<u16>,
    /// The aggregated costs, likewise.
    pub sum: Vec<u16>,
}

/// Below this a buffer is left to the allocator as it is: huge pages pay off on volumes only.
const HUGE_PAGE_MIN_BYTES: usize = 16 << 20;

#[cfg(target_os = "linux")]
fn advise_huge_pages(start: *mut u8, bytes: usize) {
    if bytes < HUGE_PAGE_MIN_BYTES {
        return;
    }
    // madvise wants a page-aligned start; the allocation's first partial page keeps small pages.
    const PAGE: usize = 4096;
    let aligned = (start as usize).next_multiple_of(PAGE);
    let end = start as usize + bytes;
    if aligned >= end {
        return;
    }
    // SAFETY: the range lies within the vector's own allocation (capacity `bytes`, not yet
    // touched); MADV_HUGEPAGE only changes how its pages are backed, never their contents, and
    // its failure (an old kernel, THP off) leaves ordinary pages: the result is ignored.
    unsafe {
        libc::madvise(
            aligned as *mut libc::c_void,
            end - aligned,
            libc::MADV_HUGEPAGE,
        );
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge_pages(_start: *mut u8, _bytes: usize) {}

#[cfg(test)]
mod tests {
    #[test]
    fn a_volume_holds_its_value_everywhere() {
        let v = super::filled(20 << 20, 7u16);
        assert_eq!(v.len(), 20 << 20);
        assert!(v.iter().all(|&x| x == 7));
        assert_eq!(super::filled(3, 1u8), [1, 1, 1]);
        let (mut v, mut small) = (v, vec![1u16; 2]);
        let at = v.as_ptr();
        super::refill(&mut v, 10, 3u16);
        assert_eq!((v.as_ptr(), v.as_slice()), (at, &[3u16; 10][..]));
        super::refill(&mut small, 5, 4u16);
        assert_eq!(small, [4; 5]);
    }
}
