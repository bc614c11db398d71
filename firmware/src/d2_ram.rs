//! Statics in the second RAM, the section `.d2sram` that each board's memory map places: on
//! the STM32H743 the D2 domain's SRAM1-3 (288 KB at 0x3000_0000, cacheable; the CPU, DMA1/2
//! and the MDMA reach it), on `mps2-an500` a RAM region of the same size. It holds large
//! buffers that only the CPU uses, so that the AXI SRAM keeps room for the `.bss` statics and
//! the DMA region (docs/hardware.md, "Memory").
//!
//! Two things differ from `.bss`, and each is a type here:
//! - The start-up code (cortex-m-rt) zeroes only `.bss`: a static here holds whatever the
//!   SRAM held at power-on. [`D2Cell`] is `MaybeUninit` storage, so nothing is assumed of it
//!   until [`D2Static::try_take`] has written zeros over it and hands it out, once, as a
//!   `&'static mut T` of a type that all-zero bytes make valid ([`bytemuck::Zeroable`]). The
//!   zeros go in whole aligned words (the cell is 32-byte aligned, its `T` whole words): the H7's SRAM1-3
//!   keep an ECC code per 32-bit word, and a partial write into a word never written is a
//!   read-modify-write of a code that does not match.
//! - On the H7 SRAM1-3 are not clocked after reset (RCC_AHB2ENR SRAM1EN..SRAM3EN), and an
//!   access is then a bus fault. [`D2Ready`] is the board's word that the memory is usable:
//!   only the board's `init` makes it, after enabling the clocks, and a cell is handed out
//!   only against it.
//!
//! Cost: the zeroing when a cell is handed out, about one store per 4 bytes (the calibration
//! table's 192 KB copy: ~49,000 stores, once at start-up); none afterwards.

use bytemuck::Zeroable;
use core::cell::UnsafeCell;
use core::mem::{MaybeUninit, size_of};
use core::sync::atomic::{AtomicBool, Ordering};

/// The board's word that `.d2sram` can be read and written (on the STM32H743: SRAM1-3
/// clocked).
#[derive(Clone, Copy)]
pub struct D2Ready(());

impl D2Ready {
    /// The word, from the board's `init`.
    ///
    /// # Safety
    ///
    /// The memory the board's map gives `.d2sram` must be readable and writable from now on
    /// (on the STM32H743: SRAM1EN, SRAM2EN and SRAM3EN set in RCC_AHB2ENR, and never cleared).
    pub unsafe fn new() -> Self {
        Self(())
    }
}

/// The storage of one `T` in `.d2sram` (the static carries `#[link_section = ".d2sram.NAME"]`),
/// aligned to a D-cache line (32 bytes, whole ECC words). Reached only through the
/// [`D2Static`] that refers to it.
#[repr(C, align(32))]
pub struct D2Cell<T>(UnsafeCell<MaybeUninit<T>>);

impl<T> D2Cell<T> {
    /// Storage with no value yet.
    pub const fn new() -> Self {
        Self(UnsafeCell::new(MaybeUninit::uninit()))
    }
}

// SAFETY: the cell's memory is reached only through `D2Static::try_take`, which hands out
// one `&mut T` once; `T: Send` lets that reference go to another task.
unsafe impl<T: Send> Sync for D2Cell<T> {}

/// A [`D2Cell`] handed out once, zeroed (the `.bss` static beside the cell: the flag must
/// start cleared, which `.d2sram` would not guarantee).
pub struct D2Static<T: 'static> {
    cell: &'static D2Cell<T>,
    taken: AtomicBool,
}

impl<T: Zeroable + Send> D2Static<T> {
    /// The hand-out of `cell`.
    pub const fn new(cell: &'static D2Cell<T>) -> Self {
        Self {
            cell,
            taken: AtomicBool::new(false),
        }
    }

    /// The cell's `T`, all zero, the first time only (`None` after).
    #[expect(
        clippy::mut_from_ref,
        reason = "one `&mut` handed out once from a shared static, as static_cell's `try_take`"
    )]
    pub fn try_take(&'static self, _ready: D2Ready) -> Option<&'static mut T> {
        if self.taken.swap(true, Ordering::AcqRel) {
            return None;
        }
        const {
            assert!(
                size_of::<T>().is_multiple_of(4),
                "a D2Cell holds whole 32-bit words"
            )
        };
        let words = self.cell.0.get().cast::<u32>();
        for i in 0..size_of::<T>() / 4 {
            // SAFETY: `_ready` says the memory is usable; `taken` was false, so nothing else
            // refers to the cell; every word written lies inside its `T` (the cell is 32-byte
            // aligned, `repr(C, align(32))`, and the `T` a whole number of words long).
            // Volatile, so the stores stay whole-word stores.
            unsafe { words.add(i).write_volatile(0) };
        }
        // SAFETY: every byte of the `T` is zero now, a valid `T` (`Zeroable`), and the
        // reference is the only one ever made (`taken`).
        Some(unsafe { &mut *self.cell.0.get().cast::<T>() })
    }
}
