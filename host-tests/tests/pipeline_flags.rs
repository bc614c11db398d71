//! The `flags` column of the star list: stable bit numbers, one documented meaning per bit,
//! each core flag mapped to exactly one bit; and the pipeline's input checks.

use startrack_core::calib::PixelFlags;
use startrack_core::centroid::CentroidFlags;
use startrack_core::detect::DetectionFlags;
use startrack_core::table::CalibTable;
use startrack_host::pipeline::{
    FLAG_BITS, PipelineConfig, PipelineError, UNCORRECTED_BIT, flags_bitmask, process,
};
use startrack_host::sim::truth::TruthSections;
use startrack_host::sim::{SensorParams, Simulator};

#[test]
fn every_core_flag_has_its_own_documented_bit() {
    let none = (
        DetectionFlags::empty(),
        CentroidFlags::empty(),
        PixelFlags::empty(),
    );
    assert_eq!(flags_bitmask(none.0, none.1, none.2), 0);
    let mut seen = 0u32;
    let mut check = |m: u32, what: String| {
        assert_eq!(m.count_ones(), 1, "{what} sets {m:#x}");
        assert_eq!(seen & m, 0, "{what} reuses bit {}", m.trailing_zeros());
        seen |= m;
        let bit = m.trailing_zeros();
        assert!(
            FLAG_BITS.iter().any(|(b, _, _)| *b == bit),
            "{what}: bit {bit} undocumented"
        );
    };
    for f in DetectionFlags::all().iter() {
        check(flags_bitmask(f, none.1, none.2), format!("{f:?}"));
    }
    // BLENDED is reserved in the centroid flags (detection reports blends).
    for f in CentroidFlags::all()
        .iter()
        .filter(|f| *f != CentroidFlags::BLENDED)
    {
        check(flags_bitmask(none.0, f, none.2), format!("{f:?}"));
    }
    check(
        flags_bitmask(none.0, none.1, PixelFlags::HOT_CORRECTED),
        "HOT_CORRECTED".into(),
    );
    // Set by the pipeline itself (cog1/cog2 without a pixel-phase curve), not by a core flag.
    check(1 << UNCORRECTED_BIT, "UNCORRECTED".into());
    // Every documented bit is produced by some flag, and the table lists each bit once.
    for (bit, _, _) in FLAG_BITS {
        assert_ne!(seen & (1 << bit), 0, "documented bit {bit} never set");
    }
    assert_eq!(seen.count_ones() as usize, FLAG_BITS.len());
    // Stable numbers: the ones users' scripts rely on.
    assert_eq!(
        flags_bitmask(DetectionFlags::BLENDED, none.1, none.2),
        1 << 2
    );
    assert_eq!(
        flags_bitmask(none.0, CentroidFlags::DEGENERATE, none.2),
        1 << 12
    );
}

#[test]
fn bad_window_and_frame_size_are_typed_errors() {
    let sim = Simulator::new(SensorParams::default(), Vec::new());
    let bytes = sim.truth_table(TruthSections::NONE).unwrap();
    let g = sim.params.geometry;
    let raw = vec![1000u16; usize::from(g.lines) * g.line_len()];
    for n in [0, 1, 2, 4, 33] {
        let table = CalibTable::parse(&bytes).unwrap();
        let cfg = PipelineConfig {
            window_px: n,
            ..PipelineConfig::default()
        };
        assert_eq!(process(table, &raw, &cfg), Err(PipelineError::Window(n)));
    }
    let table = CalibTable::parse(&bytes).unwrap();
    let e = process(table, &raw[1..], &PipelineConfig::default()).unwrap_err();
    assert!(matches!(e, PipelineError::FrameSize { .. }), "{e}");
    // A flat frame has no star and is not an error.
    let table = CalibTable::parse(&bytes).unwrap();
    let r = process(table, &raw, &PipelineConfig::default()).unwrap();
    assert!(r.stars.is_empty());
}
