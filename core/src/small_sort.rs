//! Sorting the frame's short lists (the stars of a frame, at most a few dozen) by insertion:
//! one small loop per element type instead of the slice sort's generic pattern-defeating
//! quicksort, whose code is 10-18 KB for each element type and comparison it is used with,
//! more than the firmware's three code sectors can spare.
//!
//! Cost: `n (n - 1) / 2` comparisons and moves at worst (496 for 32 stars), `n - 1` on a
//! sorted list; stable (equal elements keep their order); no allocation, no panic.

use core::cmp::Ordering;

/// Sorts `v` by `cmp`, stably, in place.
pub(crate) fn sort_by<T: Copy>(v: &mut [T], mut cmp: impl FnMut(&T, &T) -> Ordering) {
    for i in 1..v.len() {
        let mut j = i;
        while j > 0 {
            let (Some(a), Some(b)) = (v.get(j - 1), v.get(j)) else {
                break;
            };
            if cmp(a, b) != Ordering::Greater {
                break;
            }
            v.swap(j - 1, j);
            j -= 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::sort_by;

    /// Against the standard library's stable sort, on lists with many equal keys.
    #[test]
    fn sorts_stably_as_the_slice_sort_does() {
        let mut seed = 0x2545_f491u32;
        for n in 0..40u8 {
            let mut v: heapless::Vec<(u8, u8), 40> = (0..n)
                .map(|k| {
                    seed ^= seed << 13;
                    seed ^= seed >> 17;
                    seed ^= seed << 5;
                    ((seed % 7) as u8, k)
                })
                .collect();
            let mut want = v.clone();
            want.sort_by_key(|e| core::cmp::Reverse(e.0));
            sort_by(&mut v, |a, b| b.0.cmp(&a.0));
            assert_eq!(v, want, "n = {n}");
        }
    }
}
