//! Clamping to bounds known only at run time, without a panic path.
//!
//! `f32::clamp` and `Ord::clamp` panic when `lo > hi` or a bound is NaN, and the float one
//! formats both bounds into its panic message: wherever the bounds are not constants, that
//! links core's float printing (about 20 KB of flash: the Grisu and Dragon printers and their
//! tables) into the firmware, and it is a panic on an input the core must survive (a NaN or
//! negative width in a fit). [`clamp`] returns what `clamp` returns whenever `lo <= hi`
//! (a NaN `x` stays NaN), and never panics: with `lo > hi` or a NaN bound it returns one of
//! `x`, `lo`, `hi`, so a caller's later checks see a value of the same kind.
//!
//! Cost: two comparisons, as `clamp` without its assertion.

/// `x` limited to `lo..=hi` (the same value as `x.clamp(lo, hi)` whenever `lo <= hi`).
pub(crate) fn clamp<T: PartialOrd>(x: T, lo: T, hi: T) -> T {
    if x < lo {
        lo
    } else if x > hi {
        hi
    } else {
        x
    }
}

#[cfg(test)]
mod tests {
    use super::clamp;

    #[test]
    fn agrees_with_std_clamp_when_the_bounds_are_ordered() {
        let values = [
            f32::NEG_INFINITY,
            -3.5,
            -0.0,
            0.0,
            0.25,
            1.0,
            7.0,
            f32::INFINITY,
            f32::NAN,
        ];
        for &lo in &values[..8] {
            for &hi in &values[..8] {
                if lo > hi {
                    continue;
                }
                for &x in &values {
                    let (a, b) = (clamp(x, lo, hi), x.clamp(lo, hi));
                    assert!(
                        a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                        "{x} in {lo}..={hi}: {a} vs {b}"
                    );
                }
            }
        }
        for x in -5i32..5 {
            assert_eq!(clamp(x, -2, 3), x.clamp(-2, 3));
        }
    }

    #[test]
    fn disordered_or_nan_bounds_do_not_panic() {
        assert_eq!(clamp(0.5f32, 1.0, -1.0), 1.0);
        assert_eq!(clamp(2.0f32, 1.0, -1.0), -1.0);
        assert_eq!(clamp(0.5f32, f32::NAN, 1.0), 0.5);
        assert_eq!(clamp(3.0f32, 0.0, f32::NAN), 3.0);
        assert_eq!(clamp(5u16, 9, 3), 9);
    }
}
