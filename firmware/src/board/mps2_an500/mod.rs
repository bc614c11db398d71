//! QEMU's `mps2-an500` (Cortex-M7) as a board for processor-in-the-loop runs: the flight
//! application on the target's instruction set, memory map (sized as the H7's,
//! `firmware/memory/mps2-an500.x`), stack, tasks and interrupts, fed by the host's simulated
//! sensor and commanded by the ground tool (`startrack pil`, docs/hardware.md).
//!
//! | item | here |
//! |---|---|
//! | time | SysTick, exact under `-icount` ([`time`]) |
//! | watchdog | the CMSDK APB watchdog (0x4000_8000): its interrupt (the NMI) marks the cause and resets |
//! | table store | a RAM model of the H7's bank 2 at 0x6000_0000 ([`flash`]), loaded at power-on from the host's `pil-bank.bin` (kept over a reset, as flash is) |
//! | catalog | 0x0020_0000, where the PIL loads it (`-device loader`) |
//! | thermometer | none (the board has no sensor; housekeeping says so) |
//! | link | CMSDK UART0 ([`uart`]) |
//! | lines | from the host over semihosting ([`host`]): after each frame's exposure, each line when the sequencer's program for that frame's plan (compiled by the host) reads it out |
//! | log | defmt over semihosting (`defmt-print -e ELF` decodes it) |
//! | reset cause | a word kept over the reset in `.uninit`, written before each reset this firmware makes |
//!
//! After each frame the outcome, its stars, the SysTick count and the painted stack's
//! high-water mark go to the host ([`after_frame`]).

pub mod executor;
pub mod flash;
pub mod host;
pub mod time;
pub mod uart;

use super::{Started, WatchdogPort};
use crate::d2_ram::D2Ready;
use crate::lines::{BUFFERS, FILLED, FREE, LINE_LEN, LineBuf, REQUESTS, RawLine};
use crate::spawn::spawn_or_log;
use core::cell::RefCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicU32, Ordering};
use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use semihosting::io::Read;
use startrack_core::cycle::FrameOutcome;
use startrack_core::safe::{ResetCause, SetupFaults};
use startrack_core::store::{H743_BANK_B, H743_BANK2, Layout};
use startrack_core::tracker::{FixedTemperature, Integration, StarRecord};
use static_cell::ConstStaticCell;

use defmt_semihosting as _;
pub use executor::Executor;

/// The table store's flash: the RAM model of bank 2.
pub type Flash = flash::RamBank;

/// The store's layout: the H7's bank 2, as on the flight board.
pub const STORE_LAYOUT: Layout = H743_BANK2;

/// No sensor on this board.
pub type Thermometer = FixedTemperature;

/// The catalog's region (memory map `CATALOG`).
pub const CATALOG_ADDRESS: usize = 0x0020_0000;
/// Its length, bytes.
pub const CATALOG_REGION_B: usize = 1024 * 1024;

/// The CMSDK watchdog's registers.
const WDOG_LOAD: usize = 0x4000_8000;
const WDOG_CTRL: usize = 0x4000_8008;
const WDOG_INTCLR: usize = 0x4000_800C;
const WDOG_LOCK: usize = 0x4000_8C00;
const WDOG_UNLOCK: u32 = 0x1ACC_E551;
/// CTRL: interrupt (the NMI) and reset enabled.
const WDOG_INTEN_RESEN: u32 = 0b11;
/// The watchdog's clock, Hz (QEMU's 25 MHz SYSCLK).
const WDOG_CLOCK_HZ: u32 = 25_000_000;

fn write_reg(addr: usize, value: u32) {
    // SAFETY: `addr` is one of the CMSDK watchdog's word-aligned registers, always mapped on
    // this board; only the watchdog task writes them.
    unsafe { core::ptr::write_volatile(core::ptr::with_exposed_provenance_mut::<u32>(addr), value) }
}

/// The CMSDK watchdog: it counts down [`crate::watchdog::TIMEOUT_US`] of its clock; at zero
/// its interrupt, the NMI, records the cause and resets (its own reset would follow a second
/// period later).
pub struct Watchdog;

impl WatchdogPort for Watchdog {
    fn unleash(&mut self) {
        let load = (u64::from(crate::watchdog::TIMEOUT_US) * u64::from(WDOG_CLOCK_HZ) / 1_000_000)
            .min(u64::from(u32::MAX)) as u32;
        write_reg(WDOG_LOCK, WDOG_UNLOCK);
        write_reg(WDOG_LOAD, load);
        write_reg(WDOG_CTRL, WDOG_INTEN_RESEN);
        write_reg(WDOG_LOCK, 0);
    }

    fn pet(&mut self) {
        write_reg(WDOG_LOCK, WDOG_UNLOCK);
        // Clears the interrupt and reloads the counter.
        write_reg(WDOG_INTCLR, 1);
        write_reg(WDOG_LOCK, 0);
    }
}

/// The reset cause across a reset: [`MARK_MAGIC`] and the cause's code, in `.uninit`.
#[unsafe(link_section = ".uninit.RESET_MARK")]
static mut RESET_MARK: MaybeUninit<[u32; 2]> = MaybeUninit::uninit();
const MARK_MAGIC: u32 = 0x5253_544d;

/// The bank was loaded from the host since power-on: [`BANK_MAGIC`], in `.uninit`.
#[unsafe(link_section = ".uninit.BANK_MARK")]
static mut BANK_MARK: MaybeUninit<u32> = MaybeUninit::uninit();
const BANK_MAGIC: u32 = 0x4241_4e4b;

const fn cause_code(cause: ResetCause) -> u32 {
    match cause {
        ResetCause::PowerOn => 1,
        ResetCause::Watchdog => 2,
        ResetCause::Software => 3,
        ResetCause::Pin => 4,
        ResetCause::Other => 5,
    }
}

fn write_mark(cause: ResetCause) {
    // SAFETY: a volatile write of two words to a static of that size; the mark is written
    // only just before a reset (nothing else runs after it) and read once at start-up.
    unsafe {
        core::ptr::write_volatile(
            core::ptr::addr_of_mut!(RESET_MARK).cast::<[u32; 2]>(),
            [MARK_MAGIC, cause_code(cause)],
        );
    }
}

/// Resets the MCU after marking why.
pub fn system_reset(cause: ResetCause) -> ! {
    write_mark(cause);
    cortex_m::peripheral::SCB::sys_reset()
}

/// Why the MCU reset, as [`init`] read it.
pub fn reset_cause() -> ResetCause {
    match BOOT_CAUSE.load(Ordering::Relaxed) {
        2 => ResetCause::Watchdog,
        3 => ResetCause::Software,
        4 => ResetCause::Pin,
        5 => ResetCause::Other,
        _ => ResetCause::PowerOn,
    }
}

/// The cause's code read at start-up.
static BOOT_CAUSE: AtomicU32 = AtomicU32::new(1);

/// Reads the mark this firmware wrote before the reset (none: power-on) and clears it.
fn take_mark() -> u32 {
    // SAFETY: read and cleared once at start-up, before any task runs; every bit pattern is
    // a valid `[u32; 2]`, and the write covers the whole static.
    let [magic, code] = unsafe {
        let words = core::ptr::read_volatile(core::ptr::addr_of!(RESET_MARK).cast::<[u32; 2]>());
        core::ptr::write_volatile(
            core::ptr::addr_of_mut!(RESET_MARK).cast::<[u32; 2]>(),
            [0, 0],
        );
        words
    };
    if magic == MARK_MAGIC {
        code
    } else {
        cause_code(ResetCause::PowerOn)
    }
}

/// The watchdog's interrupt: the frame loop stopped making progress.
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    system_reset(ResetCause::Watchdog)
}

/// A hard fault: recorded as the reset cause `Other`, then a reset.
#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    system_reset(ResetCause::Other)
}

/// A panic: logged, recorded as the reset cause `Other`, then a reset.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    system_reset(ResetCause::Other)
}

/// defmt's panics (`defmt::panic!`, `unwrap!`) end as a panic does.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    system_reset(ResetCause::Other)
}

/// The line buffers (no DMA here: plain `.bss`).
static LINE_BUFFERS: ConstStaticCell<[LineBuf; BUFFERS]> =
    ConstStaticCell::new([[0; LINE_LEN]; BUFFERS]);

/// Units of the bank programmed since boot (the flash model's bitmap).
static PROGRAMMED: ConstStaticCell<[u32; (H743_BANK_B / 32 / 32) as usize]> =
    ConstStaticCell::new([0; (H743_BANK_B / 32 / 32) as usize]);

/// The channel to the host, shared by the line task and [`after_frame`] (both thread mode).
static HOST: Mutex<CriticalSectionRawMutex, RefCell<Option<host::HostChannel>>> =
    Mutex::new(RefCell::new(None));

/// Nothing the application needs beyond [`Parts`]' other fields.
pub struct Io;

/// What [`start_lines`] takes.
pub struct LinePath;

/// What the application gets from the board at start-up.
pub struct Parts {
    /// The CMSDK watchdog.
    pub watchdog: Watchdog,
    /// The RAM model of bank 2.
    pub flash: Flash,
    /// No reading.
    pub thermometer: Thermometer,
    /// `EXTERNAL_THERMOMETER`: the board has no sensor.
    pub thermometer_faults: SetupFaults,
    /// `.d2sram` usable (plain RAM here, as the H7's D2 SRAM once clocked).
    pub d2_ready: D2Ready,
    /// Nothing.
    pub io: Io,
}

/// SysTick up, the bank loaded at power-on, the host's channel open.
pub fn init() -> Parts {
    let startup_counts = match cortex_m::Peripherals::take() {
        Some(cp) => time::init(cp.SYST),
        None => 0,
    };
    let cause = take_mark();
    BOOT_CAUSE.store(cause, Ordering::Relaxed);
    load_bank();
    match host::HostChannel::open() {
        Ok(mut ch) => {
            if let Err(e) = ch.boot(cause as u8, startup_counts) {
                defmt::error!("pil: host channel: {}", e);
            }
            HOST.lock(|h| *h.borrow_mut() = Some(ch));
        }
        Err(e) => defmt::error!("pil: no host channel ({}): no lines", e),
    }
    let flash = match PROGRAMMED.try_take() {
        Some(bitmap) => flash::RamBank::new(bitmap),
        // `init` runs once; a second call has no bitmap to give (cannot happen).
        None => cortex_m::peripheral::SCB::sys_reset(),
    };
    Parts {
        watchdog: Watchdog,
        flash,
        thermometer: FixedTemperature(None),
        thermometer_faults: SetupFaults::EXTERNAL_THERMOMETER,
        // SAFETY: the map puts `.d2sram` in QEMU's SSRAM2/3, always readable and writable.
        d2_ready: unsafe { D2Ready::new() },
        io: Io,
    }
}

/// At power-on (no bank mark), fills the bank from the host's `pil-bank.bin` (1 MB), or
/// erases it when there is none; after a reset the bank is left as the last run left it.
fn load_bank() {
    // SAFETY: read and written only here, once at start-up; any bits are a valid `u32`.
    let mark = unsafe { core::ptr::read_volatile(core::ptr::addr_of!(BANK_MARK).cast::<u32>()) };
    if mark == BANK_MAGIC {
        return;
    }
    // SAFETY: the STORE region (1 MB of RAM at 0x6000_0000, outside every linker section);
    // nothing else uses it before the store is mounted.
    let bank = unsafe {
        core::slice::from_raw_parts_mut(
            core::ptr::with_exposed_provenance_mut::<u8>(flash::STORE_ADDRESS),
            H743_BANK_B as usize,
        )
    };
    let loaded = semihosting::fs::File::open(c"pil-bank.bin").and_then(|mut f| f.read_exact(bank));
    if loaded.is_err() {
        defmt::warn!("pil: no pil-bank.bin: the store's bank starts erased");
        bank.fill(0xFF);
    }
    // SAFETY: as above.
    unsafe {
        core::ptr::write_volatile(core::ptr::addr_of_mut!(BANK_MARK).cast::<u32>(), BANK_MAGIC)
    };
}

/// The link on UART0 and the line buffers.
pub fn start_io(spawner: Spawner, _io: Io) -> Started<LinePath> {
    uart::init();
    spawn_or_log(spawner, "link rx", uart::link_rx_task());
    spawn_or_log(spawner, "link tx", uart::link_tx_task());
    let line_buffers = LINE_BUFFERS.try_take();
    let faults = if line_buffers.is_none() {
        SetupFaults::LINE_BUFFERS
    } else {
        SetupFaults::empty()
    };
    Started {
        line_buffers,
        lines: Some(LinePath),
        faults,
    }
}

/// The host's line task.
pub fn start_lines(spawner: Spawner, _lines: LinePath) -> bool {
    spawn_or_log(spawner, "host lines", host_lines_task())
}

/// Each request to the host, the frame's exposure waited, then the lines it sends into
/// [`FILLED`], each at the instant the flight sequencer would have read it out (the
/// header's `ready_us` after the exposure's end: the frame transfer, then the readout of
/// that frame's plan), up to its end of frame. Without the host the frame gets no line (the
/// tracker's line source ends it at its timeout).
#[embassy_executor::task]
async fn host_lines_task() {
    loop {
        let req = REQUESTS.wait().await;
        let sent = HOST.lock(|h| h.borrow_mut().as_mut().map(|ch| ch.request(&req)));
        if !matches!(sent, Some(Ok(()))) {
            continue;
        }
        // The integration before the readout (the sequencer's exposure), then the program.
        let exposure_start = embassy_time::Instant::now();
        embassy_time::Timer::after_micros(u64::from(req.exposure_us)).await;
        let program_start = embassy_time::Instant::now();
        let integration = Some(Integration {
            start_us: exposure_start.as_micros(),
            end_us: program_start.as_micros(),
        });
        loop {
            let header = HOST.lock(|h| h.borrow_mut().as_mut().map(|ch| ch.line_header()));
            let Some(Ok(header)) = header else {
                defmt::error!("pil: host channel lost at frame {}", req.frame);
                break;
            };
            // The line's last sample (or the program's end) on the sequencer's clock.
            embassy_time::Timer::at(
                program_start + embassy_time::Duration::from_micros(u64::from(header.ready_us)),
            )
            .await;
            if header.line == host::END_OF_FRAME {
                break;
            }
            if header.line == host::INJECT_HANG {
                // The fault test: the thread-mode loop stops here for good, waiting for an
                // event that never comes (interrupts still run and return to this loop), the
                // tracker makes no more progress and the watchdog must reset. It waits with
                // WFI rather than spinning: under `-icount` QEMU ran a spinning loop at about
                // 1.3 M instructions a wall-clock second (measured on a loaded 2-core host),
                // so the watchdog's 8 s (4e9 instructions at `shift=1`) would take most of an
                // hour; in WFI the emulated clock jumps to the next interrupt (`sleep=off`).
                defmt::warn!("pil: hang injected at frame {}", req.frame);
                loop {
                    cortex_m::asm::wfi();
                }
            }
            if header.line == host::INJECT_PANIC {
                // The fault test: a panic must end in a reset with the cause recorded.
                panic!("pil: panic injected at frame {}", req.frame);
            }
            let buf = FREE.receive().await;
            let read = HOST.lock(|h| h.borrow_mut().as_mut().map(|ch| ch.line_samples(buf)));
            if !matches!(read, Some(Ok(()))) {
                defmt::error!("pil: host channel lost at frame {}", req.frame);
                if FREE.try_send(buf).is_err() {
                    defmt::error!("lines: free-buffer channel full, a line buffer is lost");
                }
                break;
            }
            FILLED
                .send(RawLine {
                    frame: req.frame,
                    line: header.line,
                    last: header.last,
                    samples: buf,
                    integration,
                })
                .await;
            if header.last {
                break;
            }
        }
    }
}

unsafe extern "C" {
    /// The stack's lowest address (cortex-m-rt; the memory map's `STACK` origin).
    static _stack_end: u32;
    /// One past its highest.
    static _stack_start: u32;
}

/// Bytes of the stack ever used: from its top down to the lowest word that no longer holds
/// cortex-m-rt's paint (0xCCCC_CCCC). Cost: one load a word of the unused part.
pub fn stack_used_b() -> u32 {
    let bottom = core::ptr::addr_of!(_stack_end) as usize;
    let top = core::ptr::addr_of!(_stack_start) as usize;
    let mut at = bottom;
    while at < top {
        // SAFETY: `at` is a word of the stack region (between the linker's bounds, word
        // aligned); reading a word below the stack pointer is a plain RAM load.
        let w = unsafe { core::ptr::read_volatile(core::ptr::with_exposed_provenance::<u32>(at)) };
        if w != 0xCCCC_CCCC {
            break;
        }
        at += 4;
    }
    (top - at) as u32
}

/// The frame's outcome, its stars and integration, the emulated time (read first) and the
/// stack's high-water mark to the host.
pub fn after_frame(outcome: &FrameOutcome, stars: &[StarRecord], integration: Option<Integration>) {
    let counts = time::now_counts();
    let busy = time::busy_counts();
    let stack = stack_used_b();
    HOST.lock(|h| {
        if let Some(ch) = h.borrow_mut().as_mut()
            && let Err(e) = ch.outcome(outcome, stars, counts, busy, stack, integration)
        {
            defmt::error!("pil: host channel: {}", e);
        }
    });
}
