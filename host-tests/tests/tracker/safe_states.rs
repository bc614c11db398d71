//! Safe states: the fault record survives a reset and reads as fresh from any RAM garbage,
//! the thermometer falls back from the CCD board's sensor to the MCU's, and housekeeping
//! sums the frame summaries' losses.

use proptest::prelude::*;
use startrack_core::safe::{
    FAULT_RECORD_WORDS, FallbackThermometer, FaultRecord, Health, ResetCause, SetupFaults,
    ThermoSource,
};
use startrack_core::store::{ActiveTable, SlotHeader, TableKind};
use startrack_core::tracker::{
    FixedTemperature, FrameSummary, Mode, TemperatureSource, Thermometer,
};
use startrack_core::units::Kelvin;

fn k(v: u32) -> Kelvin {
    Kelvin::from_num(v)
}

#[test]
fn the_record_counts_boots_and_watchdog_resets_across_resets() {
    // Power-on: the RAM holds garbage, the record starts fresh.
    let garbage = [0xA5A5_A5A5u32; FAULT_RECORD_WORDS];
    let (mut r, recovered) = FaultRecord::from_words(&garbage);
    assert!(!recovered);
    assert_eq!(r, FaultRecord::FRESH);
    r.on_boot(ResetCause::PowerOn);
    r.on_setup_done(SetupFaults::empty());
    let mut ram = r.to_words();
    // The watchdog resets twice, the second boot with a set-up fault; a commanded reset.
    for (cause, faults) in [
        (ResetCause::Watchdog, SetupFaults::empty()),
        (
            ResetCause::Watchdog,
            SetupFaults::NO_TABLE | SetupFaults::EXTERNAL_THERMOMETER,
        ),
        (ResetCause::Software, SetupFaults::empty()),
    ] {
        let (mut r, recovered) = FaultRecord::from_words(&ram);
        assert!(recovered);
        r.on_boot(cause);
        r.on_setup_done(faults);
        ram = r.to_words();
    }
    let (r, _) = FaultRecord::from_words(&ram);
    assert_eq!(r.boots, 4);
    assert_eq!(r.watchdog_resets, 2);
    assert_eq!(r.setup_failure_boots, 1);
    assert_eq!(
        r.last_setup_faults,
        SetupFaults::NO_TABLE | SetupFaults::EXTERNAL_THERMOMETER
    );
    assert_eq!(r.last_reset, Some(ResetCause::Software));
}

#[test]
fn every_single_bit_flip_of_the_record_reads_as_fresh() {
    let mut r = FaultRecord::FRESH;
    r.on_boot(ResetCause::Watchdog);
    r.on_setup_done(SetupFaults::READOUT);
    let w = r.to_words();
    assert_eq!(FaultRecord::from_words(&w), (r, true));
    for bit in 0..32 * FAULT_RECORD_WORDS {
        let mut x = w;
        x[bit / 32] ^= 1 << (bit % 32);
        assert_eq!(
            FaultRecord::from_words(&x),
            (FaultRecord::FRESH, false),
            "bit {bit}"
        );
    }
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(proptest::prelude::ProptestConfig::default()))]
    #[test]
    fn random_ram_reads_as_fresh(words in prop::array::uniform8(any::<u32>())) {
        let (r, ok) = FaultRecord::from_words(&words);
        prop_assert!(!ok);
        prop_assert_eq!(r, FaultRecord::FRESH);
    }

    #[test]
    fn a_record_round_trips(boots in any::<u32>(), wd in any::<u32>(), sf in any::<u32>(),
                            bits in any::<u32>(), cause in 0..5usize) {
        let causes = [ResetCause::PowerOn, ResetCause::Watchdog, ResetCause::Software,
                      ResetCause::Pin, ResetCause::Other];
        let r = FaultRecord {
            boots,
            watchdog_resets: wd,
            setup_failure_boots: sf,
            last_setup_faults: SetupFaults::from_bits_retain(bits),
            last_reset: Some(causes[cause]),
        };
        prop_assert_eq!(FaultRecord::from_words(&r.to_words()), (r, true));
    }
}

#[test]
fn the_thermometer_falls_back_to_the_mcu_then_to_nothing() {
    let mut t = FallbackThermometer::new(
        FixedTemperature(Some(k(173))),
        FixedTemperature(Some(k(300))),
    );
    assert_eq!(t.sensor_temperature_k(), Some(k(173)));
    assert_eq!(t.source(), ThermoSource::External);
    // A disconnected external sensor: no reading, or an implausible one.
    for bad in [None, Some(k(0)), Some(k(149)), Some(k(401))] {
        t.external = FixedTemperature(bad);
        assert_eq!(t.sensor_temperature_k(), Some(k(300)));
        assert_eq!(t.source(), ThermoSource::Mcu);
    }
    assert_eq!(t.external_failures(), 4);
    t.mcu = FixedTemperature(None);
    assert_eq!(t.sensor_temperature_k(), None);
    assert_eq!(t.source(), ThermoSource::None);
    assert_eq!(t.mcu_failures(), 1);
    t.external = FixedTemperature(Some(k(150)));
    assert_eq!(t.sensor_temperature_k(), Some(k(150)));
    assert_eq!(t.source(), ThermoSource::External);
}

#[test]
fn housekeeping_sums_the_frames_losses() {
    let mut h = Health::new(FaultRecord::FRESH, SetupFaults::NO_TABLE);
    let s = FrameSummary {
        next_mode: Mode::Tracking,
        temperature_k: k(173),
        temperature_source: TemperatureSource::Sensor,
        lines: 1033,
        lines_refused: 2,
        stars: 5,
        centroids: 5,
        candidates_dropped: 1,
        windows_dropped: 2,
        ring_lost: 3,
        calib_failed: 4,
        track_lost: 6,
        stars_dropped: 5,
        ..FrameSummary::empty(0, Mode::Acquisition, 0)
    };
    h.on_frame(&s);
    h.on_frame(&FrameSummary {
        calibrated: true,
        mode: Mode::Tracking,
        ..s
    });
    assert_eq!(h.mode, Mode::Tracking);
    assert_eq!(h.frames, 2);
    assert_eq!(h.frames_uncalibrated, 1);
    assert_eq!(h.lines_refused, 4);
    assert_eq!(h.stars_lost, 2 * (1 + 2 + 3 + 4 + 5));
    assert_eq!(h.track_lost, 12);
    let active = ActiveTable {
        slot: 1,
        header: SlotHeader {
            kind: TableKind::Calibration,
            sequence: 7,
            len_b: 100,
            crc32: 0x1234,
        },
        data_offset_b: 0,
    };
    h.calibration = Some(active.into());
    assert_eq!(
        h.calibration.map(|t| (t.sequence, t.crc32)),
        Some((7, 0x1234))
    );
}

#[test]
fn tmp117_words_convert_to_kelvin_against_an_f64_reference() {
    use startrack_core::safe::tmp117;
    // The datasheet's examples (TMP117, table 7-1): 0x6400 = 200 degC, 0x0080 = 1 degC,
    // 0xFF80 = -1 degC, 0xE480 = -55 degC.
    for (raw, celsius) in [
        (0x6400u16, 200.0),
        (0x0080, 1.0),
        (0x0000, 0.0),
        (0xFF80, -1.0),
        (0xE480, -55.0),
    ] {
        let k = tmp117::kelvin(raw).expect("a reading").to_num::<f64>();
        assert!((k - (celsius + 273.15)).abs() < 2e-5, "{raw:#06x}: {k}");
    }
    // Every word: within one U16F16 step of the f64 value, or the reset value (no reading).
    for raw in 0..=u16::MAX {
        let got = tmp117::kelvin(raw);
        if raw == tmp117::RESET_VALUE {
            assert_eq!(got, None);
            continue;
        }
        let want = 273.15 + f64::from(raw as i16) / 128.0;
        let k = got.expect("every other word converts").to_num::<f64>();
        assert!(
            (k - want).abs() <= 1.0 / 65536.0,
            "{raw:#06x}: {k} vs {want}"
        );
    }
    assert!(tmp117::is_tmp117(0x0117) && tmp117::is_tmp117(0x1117));
    assert!(!tmp117::is_tmp117(0x0000) && !tmp117::is_tmp117(0xFFFF));
}
