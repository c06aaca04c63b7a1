//! The cost and aggregation volumes' memory: w·h·D u16 each, 320 MiB at 1280 × 1024 × 128.
//!
//! Fresh, such a volume is 82 000 page faults, each a page the kernel clears; where the first
//! touch is a read (a sum read before it is added to) every page is mapped twice: the shared
//! zero page, then a copy, whose swap flushes the other threads' TLBs by interrupt. `perf` put a
//! third of a 1280 × 1024 pair's time in the kernel that way (`docs/performance.md`). The
//! volumes are therefore kept from one depth map to the next ([`Volumes`]), and never filled:
//! the cost volume's bands and SGM's first path write every value before anything reads it,
//! in parallel, so that the pages are faulted in by every thread.
//!
//! Transparent huge pages (`madvise(MADV_HUGEPAGE)`) were tried and dropped: the kernel
//! compacted memory to find them, and the pair took more system time with them than without
//! (1.2–1.9 against 0.8–1.0 s, in turns).

/// `volume` at `len` elements of any value, for a caller that writes every one before it reads
/// it: its memory reused where it has room (no page is faulted in again), else fresh zeroed
/// pages that the writes fault in.
pub fn resize_for_writing<T: Copy + Default>(volume: &mut Vec<T>, len: usize) {
    if volume.capacity() < len {
        // Freed first, so that the old and the new volume are never held together.
        *volume = Vec::new();
        // Zeroed by the kernel as the writes touch them; nothing reads a page first.
        *volume = vec![T::default(); len];
    } else {
        volume.resize(len, T::default());
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

#[cfg(test)]
mod tests {
    #[test]
    fn a_volume_keeps_its_memory_where_it_has_room() {
        let mut v: Vec<u16> = Vec::new();
        super::resize_for_writing(&mut v, 1 << 20);
        assert_eq!(v.len(), 1 << 20);
        let at = v.as_ptr();
        super::resize_for_writing(&mut v, 10);
        assert_eq!((v.as_ptr(), v.len()), (at, 10));
        super::resize_for_writing(&mut v, 1 << 19);
        assert_eq!((v.as_ptr(), v.len()), (at, 1 << 19));
        let mut small = vec![1u16; 2];
        super::resize_for_writing(&mut small, 5);
        assert_eq!(small.len(), 5);
    }
}
