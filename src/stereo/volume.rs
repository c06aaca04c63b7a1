//! The cost and aggregation volumes' memory: w·h·D u16 each, 320 MiB at 1280 × 1024 × 128.
//!
//! Fresh, such a volume is 82 000 page faults, each a page the kernel clears; where the first
//! touch is a read (a sum read before it is added to) every page is mapped twice: the shared
//! zero page, then a copy, whose swap flushes the other threads' TLBs by interrupt. `perf` put a
//! third of a 1280 × 1024 pair's time in the kernel that way (`docs/performance.md`). The
//! volumes are therefore kept from one depth map to the next ([`Volumes`]) and written, by every
//! thread, before they are read.
//!
//! Transparent huge pages (`madvise(MADV_HUGEPAGE)`) were tried and dropped: the kernel
//! compacted memory to find them, and the pair took more system time with them than without
//! (1.2–1.9 against 0.8–1.0 s, in turns).

use rayon::prelude::*;

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
/// in again).
pub fn refill<T: Copy + Send + Sync>(volume: &mut Vec<T>, len: usize, value: T) {
    if volume.capacity() < len {
        // Freed first, so that the old and the new volume are never held together.
        *volume = Vec::new();
    }
    fill(volume, len, value);
}

/// `volume` at `len` elements of any value, for a caller that writes every one before it reads
/// it: its memory reused where it has room, else fresh zeroed pages that the writes fault in.
pub fn resize_for_writing<T: Copy + Default>(volume: &mut Vec<T>, len: usize) {
    if volume.capacity() < len {
        *volume = Vec::new();
        // Zeroed by the kernel as the writes touch them; nothing reads a page first.
        *volume = vec![T::default(); len];
    } else {
        volume.resize(len, T::default());
        volume.truncate(len);
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
    fn a_volume_holds_its_value_everywhere() {
        let mut v = Vec::new();
        super::refill(&mut v, 20 << 20, 7u16);
        assert_eq!(v.len(), 20 << 20);
        assert!(v.iter().all(|&x| x == 7));
        let (mut v, mut small) = (v, vec![1u16; 2]);
        let at = v.as_ptr();
        super::refill(&mut v, 10, 3u16);
        assert_eq!((v.as_ptr(), v.as_slice()), (at, &[3u16; 10][..]));
        super::refill(&mut small, 5, 4u16);
        assert_eq!(small, [4; 5]);
    }
}
