//! The core's fuzz targets: what the tracker does with bytes it did not make (a calibration
//! table or a catalog read from flash, telecommands from the link), on any bytes. Each
//! public function is one target's whole body; libFuzzer runs it through
//! `fuzz_targets/<target>.rs` (`cargo fuzz run`, nightly) and `tests/replay.rs` runs it on
//! the committed corpus `corpus/<target>/` (`cargo test`, stable).
//!
//! A target fails by panicking: the core itself must never panic on any input, and every
//! invariant checked here is an `assert!` on what the core returned.
//!
//! Cost of one run, release build: [`table`] parses (a CRC pass over the bytes), reads at
//! most 259 x 259 pixels of each map and, for sensors of at most [`FRAME_SAMPLES_MAX`]
//! samples, runs two tracker frames over the table; [`catalog`] parses and makes
//! [`CATALOG_QUERIES`] cone and pair-range queries; [`link_receive`] and [`link_standby`]
//! feed the link service (17 KB, boxed afresh each run) and drain its telemetry. The
//! tracker's 68 KB of buffers are allocated once per process and set up again by every
//! tracker made over them, so no run depends on the ones before it.

use startrack_core::catalog::{Catalog, NRAD_PER_RAD};
use startrack_core::geometry::{Output, ReadoutGeometry};
use startrack_core::link::framing::{Deframer, Pushed, encode, encoded_len_max};
use startrack_core::link::protocol::{MAX_TC_LEN, MAX_TM_LEN, TABLE_KIND_CALIBRATION};
use startrack_core::link::telemetry::LinkCounters;
use startrack_core::link::{
    LinkService, NoWindows, TableInfo, TableUpload, Targets, UploadRefusal,
};
use startrack_core::table::CalibTable;
use startrack_core::table::camera::COLOUR_RANGE_BV_MAG;
use startrack_core::tracker::{
    FrameInputs, StarRecord, TelemetrySink, Tracker, TrackerBuffers, TrackerConfig,
};
use startrack_core::units::{FlatInv, GainEPerAdu, Kelvin};
use std::sync::Mutex;

/// Largest raw frame (lines x line length) [`table`] runs the tracker over: the small
/// sensors of the corpus' tables, not the CCD47-20's million samples, so a run stays
/// well under a millisecond.
pub const FRAME_SAMPLES_MAX: usize = 1 << 14;

/// Cone and pair-range queries [`catalog`] makes of a catalog that parsed.
pub const CATALOG_QUERIES: usize = 16;

/// Largest table [`MemoryTables`] takes (the board's slot is 192 KB; a fuzz input is far
/// smaller).
const UPLOAD_MAX: u32 = 1 << 16;

/// The tracker's buffers, allocated once per process.
static BUFFERS: Mutex<Option<&'static mut TrackerBuffers>> = Mutex::new(None);

/// Runs `f` with the process's tracker buffers (made on first use).
fn with_buffers<R>(f: impl FnOnce(&mut TrackerBuffers) -> R) -> R {
    // A panic in one run (a finding) must not hide the next ones behind a poisoned lock.
    let mut slot = BUFFERS.lock().unwrap_or_else(|e| e.into_inner());
    let buffers = slot.get_or_insert_with(|| Box::leak(Box::new(TrackerBuffers::new())));
    f(buffers)
}

/// A telemetry sink that counts what it is given.
#[derive(Default)]
struct Count {
    stars: usize,
    frames: usize,
}

impl TelemetrySink for Count {
    fn star(&mut self, _frame: u32, _star: &StarRecord) {
        self.stars += 1;
    }

    fn frame(&mut self, _summary: &startrack_core::tracker::FrameSummary) {
        self.frames += 1;
    }

    fn event(&mut self, _event: &startrack_core::tracker::Event) {}
}

// ---------------------------------------------------------------------------------------------
// The calibration table
// ---------------------------------------------------------------------------------------------

/// The calibration table on any bytes, as they are and with [`reseal_table`] applied (so
/// that a mutation reaches the structural checks behind the CRCs): [`CalibTable::parse`] (and
/// [`CalibTable::parse_prefix`], the flash store's read of a slot) never panics, and a
/// table that parses keeps the parser's promises everywhere a frame reads it: a valid
/// geometry, no zero gain or inverse flat, sorted defect lists whose every entry is found
/// again and lies in the active area, finite pixel-phase corrections, a PSF width in
/// (0, 256) px, a camera model that maps every corner and colour to a unit vector. Then two
/// tracker frames (acquisition, then what it decides) run over it when the sensor is small.
pub fn table(data: &[u8]) {
    let _ = table_run(data);
    let mut sealed = data.to_vec();
    reseal_table(&mut sealed);
    if sealed != data {
        let _ = table_run(&sealed);
    }
}

/// What [`table`] reached: for the replay's checks that the corpus goes past the parser.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TableRun {
    /// The bytes parsed as a table.
    pub parsed: bool,
    /// Tracker frames run over it (0 or 2).
    pub frames: usize,
    /// Stars those frames reported.
    pub stars: usize,
}

/// One pass of [`table`]'s body over `data` as it is, returning what it reached.
pub fn table_run(data: &[u8]) -> TableRun {
    if let Ok(t) = CalibTable::parse_prefix(data) {
        assert!(t.len_bytes() <= data.len());
        // The prefix is a table of its own length.
        let whole = data.get(..t.len_bytes()).unwrap_or_default();
        assert!(CalibTable::parse(whole).is_ok());
    }
    let Ok(t) = CalibTable::parse(data) else {
        return TableRun::default();
    };
    assert_eq!(t.len_bytes(), data.len());
    read_table(&t);
    let (frames, stars) = run_frames(t);
    TableRun {
        parsed: true,
        frames,
        stars,
    }
}

/// Makes a table's length field and CRCs agree with its bytes, as far as its header and
/// directory are present: every in-bounds section's CRC, then the header's (which covers
/// the section CRCs). What is left for the parser are the structural checks.
pub fn reseal_table(b: &mut [u8]) {
    use startrack_core::table::{DIR_ENTRY_LEN, HEADER_LEN};
    if b.len() < HEADER_LEN {
        return;
    }
    let len = u32::try_from(b.len()).unwrap_or(u32::MAX);
    put32(b, 8, len);
    let n = usize::from(get16(b, 6)).min(16);
    for i in 0..n {
        let e = HEADER_LEN + i * DIR_ENTRY_LEN;
        let (off, len) = (get32(b, e + 4) as usize, get32(b, e + 8) as usize);
        if let Some(sec) = off.checked_add(len).and_then(|end| b.get(off..end)) {
            let c = CRC32.checksum(sec);
            put32(b, e + 12, c);
        }
    }
    let dir_end = (HEADER_LEN + DIR_ENTRY_LEN * n).min(b.len());
    let mut d = CRC32.digest();
    d.update(b.get(..28).unwrap_or_default());
    d.update(b.get(HEADER_LEN..dir_end).unwrap_or_default());
    put32(b, 28, d.finalize());
}

/// Makes a catalog's length field and CRCs agree with its bytes: the three sections' CRCs
/// when the counts give sections that end at the catalog's end, then the header's.
pub fn reseal_catalog(b: &mut [u8]) {
    use startrack_core::catalog::{HEADER_LEN, KVEC_ENTRY_LEN, PAIR_LEN, STAR_LEN};
    if b.len() < HEADER_LEN {
        return;
    }
    let len = u32::try_from(b.len()).unwrap_or(u32::MAX);
    put32(b, 8, len);
    let stars = (get32(b, 12) as usize).saturating_mul(STAR_LEN);
    let pairs = (get32(b, 16) as usize).saturating_mul(PAIR_LEN);
    let kvec = (get32(b, 20) as usize)
        .saturating_add(1)
        .saturating_mul(KVEC_ENTRY_LEN);
    let s_end = HEADER_LEN.saturating_add(stars);
    let p_end = s_end.saturating_add(pairs);
    if p_end.saturating_add(kvec) == b.len() {
        let crcs = [HEADER_LEN..s_end, s_end..p_end, p_end..b.len()]
            .map(|r| CRC32.checksum(b.get(r).unwrap_or_default()));
        for (k, c) in crcs.into_iter().enumerate() {
            put32(b, 40 + 4 * k, c);
        }
    }
    let c = CRC32.checksum(b.get(..56).unwrap_or_default());
    put32(b, 56, c);
}

/// The CRC of both formats' sections and headers: CRC-32/ISO-HDLC.
const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

fn get16(b: &[u8], at: usize) -> u16 {
    b.get(at..at + 2)
        .map_or(0, |s| u16::from_le_bytes([s[0], s[1]]))
}

fn get32(b: &[u8], at: usize) -> u32 {
    b.get(at..at + 4)
        .map_or(0, |s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

fn put32(b: &mut [u8], at: usize, v: u32) {
    if let Some(s) = b.get_mut(at..at + 4) {
        s.copy_from_slice(&v.to_le_bytes());
    }
}

/// Every accessor of a parsed table, over the active area (capped at 256 x 256) and beyond.
fn read_table(t: &CalibTable<'_>) {
    let g = *t.geometry();
    assert_eq!(g.validate(), Ok(()));
    for o in 0..=3u8 {
        assert_ne!(t.gain(Output(o)), GainEPerAdu::ZERO);
    }
    for c in (0..g.line_len().saturating_add(3)).chain([usize::MAX]) {
        let _ = t.column_bias(c);
    }
    for m in [t.dark_map(), t.flat_map()].into_iter().flatten() {
        let h = m.header();
        assert!(h.tile_log2 <= startrack_core::table::MAX_TILE_LOG2);
        let want =
            startrack_core::table::MapHeader::for_area(g.active_cols, g.active_rows, h.tile_log2);
        assert_eq!(h, want);
    }
    let cols = g.active_cols.min(256);
    let rows = g.active_rows.min(256);
    let edges = [(u16::MAX, u16::MAX), (u16::MAX, 0), (0, u16::MAX)];
    let far = [
        (g.active_cols - 1, g.active_rows - 1),
        (g.active_cols, g.active_rows - 1),
    ];
    let grid =
        (0..rows.saturating_add(2)).flat_map(|y| (0..cols.saturating_add(2)).map(move |x| (x, y)));
    for (x, y) in grid.chain(edges).chain(far) {
        let _ = t.dark_rel(x, y);
        let f = t.flat_inv(x, y);
        if x < g.active_cols && y < g.active_rows {
            assert_ne!(f, FlatInv::ZERO, "zero inverse flat at ({x}, {y})");
        }
        if let Some(h) = t.hot_pixels().find(x, y) {
            assert_eq!((h.x, h.y), (x, y));
        }
        assert!(t.hot_pixels().lower_bound(x, y) <= t.hot_pixels().len());
        assert!(t.telegraph_pixels().lower_bound(x, y) <= t.telegraph_pixels().len());
        let _ = t.telegraph_pixels().contains(x, y);
    }
    let hot = t.hot_pixels();
    let _ = hot.reference_temperature_k();
    let mut prev = None;
    for i in 0..hot.len() {
        let Some(h) = hot.get(i) else {
            panic!("listed hot pixel {i} does not decode");
        };
        assert!(h.x < g.active_cols && h.y < g.active_rows);
        assert_ne!(h.doubling_k.to_bits(), 0);
        assert!(prev < Some((h.y, h.x)), "hot list not strictly sorted");
        prev = Some((h.y, h.x));
        assert_eq!(hot.find(h.x, h.y), Some(h));
        assert_eq!(hot.lower_bound(h.x, h.y), i);
    }
    assert_eq!(hot.get(hot.len()), None);
    let tg = t.telegraph_pixels();
    let mut prev = None;
    for i in 0..tg.len() {
        let Some((x, y)) = tg.get(i) else {
            panic!("listed telegraph pixel {i} does not decode");
        };
        assert!(x < g.active_cols && y < g.active_rows);
        assert!(prev < Some((y, x)), "telegraph list not strictly sorted");
        prev = Some((y, x));
        assert!(tg.contains(x, y));
    }
    assert_eq!(tg.get(tg.len()), None);
    let set = t.pixcorr();
    assert_eq!(set.iter().count(), set.len());
    for c in set.iter() {
        let h = c.header();
        assert!(h.knots >= 5 && h.box_side % 2 == 1);
        let found = set.find(h.power, h.box_side, h.background, h.a_px.to_num());
        assert_eq!(found.map(|f| f.header().a_px), Some(h.a_px));
        for m in [
            -1.5f32,
            -0.5,
            -0.25,
            0.0,
            0.1,
            0.5,
            0.75,
            1.5,
            f32::NAN,
            f32::INFINITY,
        ] {
            let (v, s) = c.correction(m);
            assert!(
                m.is_nan() || (v.is_finite() && s.is_finite()),
                "correction({m}) = {v}, {s}"
            );
        }
    }
    let _ = t.cti();
    if let Some(cti) = startrack_core::calib::cti::CtiCorrection::from_table(t, 0.7) {
        let corners = [
            (0.0, 0.0),
            (f32::from(g.active_cols), f32::from(g.active_rows)),
        ];
        for (x, y) in corners {
            for flux in [f32::NAN, -1.0, 0.0, 1e-9, 1.0, 1e4, 1e12, f32::INFINITY] {
                let (dx, dy) = cti.shift_px(flux, x, y);
                assert!(dx.is_finite() && dy.is_finite(), "CTI shift at {flux} e-");
            }
        }
    }
    if let Some(m) = t.psf_model() {
        let (w, h) = (f32::from(g.active_cols - 1), f32::from(g.active_rows - 1));
        for (x, y) in [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h), (w / 2.0, h / 2.0)] {
            let a = m.a_px(x, y, g.active_cols, g.active_rows);
            assert!(a > 0.0 && a < 256.0, "PSF width {a} px at ({x}, {y})");
        }
    }
    if let Some(cam) = t.camera_model() {
        let (w, h) = (f64::from(g.active_cols - 1), f64::from(g.active_rows - 1));
        let [lo, hi] = COLOUR_RANGE_BV_MAG;
        for (x, y) in [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)] {
            for bv in [lo, 0.0f64.clamp(lo, hi), hi] {
                let d = cam.direction_of(x, y, bv);
                let Ok(d) = d else {
                    panic!("camera model fails at ({x}, {y}), B-V {bv}: {d:?}");
                };
                let n = d.iter().map(|c| c * c).sum::<f64>();
                assert!((n - 1.0).abs() < 1e-9, "direction of norm^2 {n}");
            }
        }
    }
    if let Some(l) = t.dark_law() {
        assert_eq!(l.out_of_range_field(), None, "dark law out of range: {l:?}");
        let p = l.predicted_e(Kelvin::from_num(253), 1000);
        assert!(
            p.is_some_and(|p| p.is_finite() && p > 0.0),
            "dark law predicts {p:?}"
        );
    }
}

/// Two tracker frames over the table, on a sensor small enough: a flat bias with one bright
/// spot, so that acquisition calibrates every row and finds something to measure.
fn run_frames(t: CalibTable<'_>) -> (usize, usize) {
    let g = *t.geometry();
    let line_len = g.line_len();
    if line_len.saturating_mul(usize::from(g.lines)) > FRAME_SAMPLES_MAX {
        return (0, 0);
    }
    with_buffers(|buffers| {
        let Ok(mut tracker) = Tracker::<32>::new(TrackerConfig::FLIGHT, g, buffers) else {
            // A geometry the tracker refuses (a typed error) is not a finding.
            return (0, 0);
        };
        let mut sink = Count::default();
        let mut line = vec![0u16; line_len];
        let (cx, cy) = (g.active_cols / 2, g.active_rows / 2);
        for frame in 0..2u64 {
            let inputs = FrameInputs {
                table: Some(t),
                temperature_k: Some(Kelvin::from_num(253)),
                start_us: frame * 100_000,
            };
            tracker.begin_frame(inputs, &mut sink);
            for l in 0..g.lines {
                for (c, s) in line.iter_mut().enumerate() {
                    *s = 1_000;
                    let (x, y) = (
                        c.abs_diff(g.raw_col_of_x(usize::from(cx))),
                        usize::from(l).abs_diff(g.raw_line_of_y(usize::from(cy))),
                    );
                    if x <= 1 && y <= 1 {
                        *s = 20_000 >> (x + y);
                    }
                }
                let _ = tracker.push_line(l, &line, &mut sink);
            }
            let _ = tracker.end_frame(&mut sink);
        }
        assert_eq!(sink.frames, 2);
        assert!(sink.stars <= 2 * 32);
        (sink.frames, sink.stars)
    })
}

// ---------------------------------------------------------------------------------------------
// The catalog
// ---------------------------------------------------------------------------------------------

/// The star catalog on any bytes, as they are and with [`reseal_catalog`] applied:
/// [`Catalog::parse`] never panics, and in a catalog that
/// parses every star and pair reads, pairs are sorted with in-range indices, and the
/// identification's queries keep their promises: [`Catalog::pairs_between`] is a range of
/// pairs whose separations lie in the interval, [`Catalog::cone`] yields stars in index
/// order that lie within its radius, and a cone of more than 0.01 rad about a star holds
/// that star. The query directions come from the catalog's own stars, the radii and
/// intervals from the input's last bytes.
pub fn catalog(data: &[u8]) {
    catalog_once(data);
    let mut sealed = data.to_vec();
    reseal_catalog(&mut sealed);
    if sealed != data {
        catalog_once(&sealed);
    }
}

/// [`catalog`] on the bytes as they are.
fn catalog_once(data: &[u8]) {
    let Ok(cat) = Catalog::parse(data) else {
        return;
    };
    let (n_s, n_p) = (cat.star_count(), cat.pair_count());
    assert!(n_s >= 1);
    for i in 0..n_s {
        let (Some(s), Some(d)) = (cat.star(i), cat.dir(i)) else {
            panic!("star {i} of {n_s} does not read");
        };
        assert_eq!(s.dir, d);
        let norm = d.iter().map(|c| c * c).sum::<f64>().sqrt();
        assert!((norm - 1.0).abs() < 1e-5, "star {i} of norm {norm}");
    }
    assert!(cat.star(n_s).is_none() && cat.dir(n_s).is_none());
    let max_sep = cat.max_separation_rad();
    let mut prev = 0;
    for i in 0..n_p {
        let Some(p) = cat.pair(i) else {
            panic!("pair {i} of {n_p} does not read");
        };
        assert!(p.a < p.b && usize::from(p.b) < n_s, "pair {i}: {p:?}");
        assert!(p.separation_nrad >= prev, "pairs not sorted at {i}");
        prev = p.separation_nrad;
    }
    assert!(cat.pair(n_p).is_none());
    let _ = (
        cat.field_radius_rad(),
        cat.max_field_stars(),
        cat.epoch_centi_jy(),
    );

    // Queries: about stars of the catalog and about the input's own numbers.
    let tail = data
        .get(data.len().saturating_sub(2 * CATALOG_QUERIES)..)
        .unwrap_or_default();
    for q in 0..CATALOG_QUERIES {
        let b = |k: usize| {
            tail.get((2 * q + k) % tail.len().max(1))
                .copied()
                .unwrap_or(0)
        };
        let r = f64::from(b(0)) / 255.0;
        let star = (usize::from(b(1)) * 257 + q * 7919) % n_s;
        let dir = match q % 4 {
            0 => cat.dir(star).unwrap_or([0.0, 0.0, 1.0]),
            1 => {
                // Between two stars: not a unit vector, as a measured direction may be.
                let a = cat.dir(star).unwrap_or([1.0, 0.0, 0.0]);
                let c = cat.dir((star + 1) % n_s).unwrap_or([0.0, 1.0, 0.0]);
                [a[0] + c[0], a[1] + c[1], a[2] + c[2]]
            }
            2 => [f64::NAN, 0.0, 1.0],
            _ => [0.0, 0.0, -1.0],
        };
        let radius = match q % 3 {
            0 => cat.field_radius_rad() * r,
            1 => r * core::f64::consts::PI,
            _ => [f64::NAN, -1.0, f64::INFINITY, 0.0][q % 4],
        };
        let found = check_cone(&cat, dir, radius, star);
        if q % 4 == 0 && radius > 0.01 {
            // A star's own direction is within any cone about it (its norm is within 2^-20
            // of 1, which 0.01 rad of cosine covers).
            assert!(found, "a cone of {radius} rad about star {star} misses it");
        }
        let lo = max_sep * r;
        let hi = match q % 3 {
            0 => lo + max_sep / 64.0,
            1 => lo,
            _ => [f64::NAN, -1.0, f64::INFINITY, 2.0 * max_sep][q % 4],
        };
        check_pairs_between(&cat, lo, hi);
    }
    check_pairs_between(&cat, 0.0, max_sep);
    check_pairs_between(&cat, max_sep, 0.0);
}

/// A cone yields distinct stars in increasing index order, each within the radius; returns
/// whether star `star` was among them.
fn check_cone(cat: &Catalog<'_>, dir: [f64; 3], radius: f64, star: usize) -> bool {
    let mut found = false;
    // The cone's own test is `dot >= cos(radius)`; a few ulps of slack for this crate's cos.
    let cos_r = radius.clamp(0.0, core::f64::consts::PI).cos() - 1e-12;
    let mut last = None;
    for (i, v) in cat.cone(dir, radius).take(cat.star_count() + 1) {
        assert!(i < cat.star_count());
        assert!(last < Some(i), "cone repeats or goes back at {i}");
        last = Some(i);
        assert_eq!(cat.dir(i), Some(v));
        let d = v[0] * dir[0] + v[1] * dir[1] + v[2] * dir[2];
        assert!(d >= cos_r || radius.is_nan(), "star {i} outside the cone");
        found |= i == star;
    }
    found
}

/// The pairs in an interval: within the pair list, and every separation inside the interval
/// (in nanoradians, as stored).
fn check_pairs_between(cat: &Catalog<'_>, lo: f64, hi: f64) {
    let r = cat.pairs_between(lo, hi);
    assert!(r.start <= r.end && r.end <= cat.pair_count(), "{r:?}");
    let lo_n = lo * NRAD_PER_RAD;
    let hi_n = hi * NRAD_PER_RAD;
    for i in r {
        let Some(p) = cat.pair(i) else {
            panic!("pair {i} of a range does not read");
        };
        let s = f64::from(p.separation_nrad);
        assert!(
            lo_n.is_nan() || s >= lo_n.floor(),
            "pair {i}: {s} below {lo_n}"
        );
        assert!(
            hi_n.is_nan() || s <= hi_n.ceil(),
            "pair {i}: {s} above {hi_n}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// The link
// ---------------------------------------------------------------------------------------------

/// A table store in memory that checks what a flash store checks: the kind, the length, the
/// order of the chunks, the CRC-32 of the whole, and that the bytes are a calibration table.
/// A committed table is kept (and read back for the in-flight defect commit).
#[derive(Default)]
pub struct MemoryTables {
    open: Option<(u32, u32, Vec<u8>)>,
    active: Option<(TableInfo, Vec<u8>)>,
    sequence: u32,
}

impl TableUpload for MemoryTables {
    fn begin(&mut self, kind: u8, total_len: u32, crc32: u32) -> Result<(), UploadRefusal> {
        if self.open.is_some() {
            return Err(UploadRefusal::Busy);
        }
        if kind != startrack_core::link::protocol::TABLE_KIND_CALIBRATION {
            return Err(UploadRefusal::UnknownKind);
        }
        if total_len > UPLOAD_MAX {
            return Err(UploadRefusal::TooLong);
        }
        self.open = Some((total_len, crc32, Vec::new()));
        Ok(())
    }

    fn chunk(&mut self, offset: u32, data: &[u8]) -> Result<(), UploadRefusal> {
        let (total, _, bytes) = self.open.as_mut().ok_or(UploadRefusal::NotStarted)?;
        let at = bytes.len() as u32;
        if offset != at {
            return Err(UploadRefusal::OutOfOrder { expected: at });
        }
        if at.saturating_add(data.len() as u32) > *total {
            return Err(UploadRefusal::TooLong);
        }
        bytes.extend_from_slice(data);
        Ok(())
    }

    fn commit(&mut self) -> Result<TableInfo, UploadRefusal> {
        let (total, crc32, bytes) = self.open.take().ok_or(UploadRefusal::NotStarted)?;
        if bytes.len() as u32 != total {
            return Err(UploadRefusal::Incomplete);
        }
        if CRC32.checksum(&bytes) != crc32 {
            return Err(UploadRefusal::CrcMismatch);
        }
        if CalibTable::parse(&bytes).is_err() {
            return Err(UploadRefusal::Invalid);
        }
        self.sequence = self.sequence.wrapping_add(1);
        let info = TableInfo {
            kind: startrack_core::link::protocol::TABLE_KIND_CALIBRATION,
            len_bytes: total,
            crc32,
            sequence: self.sequence,
        };
        self.active = Some((info, bytes));
        Ok(info)
    }

    fn abort(&mut self) {
        self.open = None;
    }

    fn active(&self, kind: u8) -> Option<TableInfo> {
        self.active.as_ref().map(|a| a.0).filter(|i| i.kind == kind)
    }

    fn read_active(&mut self, kind: u8, offset: u32, out: &mut [u8]) -> bool {
        let Some((_, bytes)) = self.active.as_ref().filter(|a| a.0.kind == kind) else {
            return false;
        };
        let start = offset as usize;
        match bytes.get(start..start.saturating_add(out.len())) {
            Some(src) => {
                out.copy_from_slice(src);
                true
            }
            None => false,
        }
    }
}

/// How the link targets turn the input into received bytes: the transmit buffer's size and
/// the pieces to receive, each followed by a drain of the telemetry. The first byte picks:
/// - even: a raw byte stream, fed in pieces whose sizes the stream's own bytes give (so
///   frames split anywhere); bit 1 set: in one piece;
/// - odd: a series of telecommands, each `len u16 (LE)` then `len` bytes, with the length
///   field and CRC-16 made right and COBS-framed, so the fuzzer reaches command parsing and
///   execution (table uploads, modes, parameters), which random bytes would almost never
///   pass the CRC to.
///
/// The second byte sets the size of the transmit buffer the telemetry is drained through
/// (1 to 256 bytes, a UART's FIFO to a DMA block).
fn link_input(data: &[u8]) -> (usize, Vec<Vec<u8>>) {
    let [mode, tx, rest @ ..] = data else {
        return (1, Vec::new());
    };
    let tx = usize::from(*tx) + 1;
    if mode & 1 == 0 {
        if mode & 2 != 0 {
            return (tx, vec![rest.to_vec()]);
        }
        let mut pieces = Vec::new();
        let mut sizes = rest.iter().copied().cycle();
        let mut at = 0;
        while at < rest.len() {
            let n = usize::from(sizes.next().unwrap_or(1)).max(1);
            let end = rest.len().min(at + n);
            pieces.push(rest.get(at..end).unwrap_or_default().to_vec());
            at = end;
        }
        return (tx, pieces);
    }
    let mut pieces = Vec::new();
    let mut rest = rest;
    while let [a, b, tail @ ..] = rest {
        let n = usize::from(u16::from_le_bytes([*a, *b])).min(tail.len());
        let (body, next) = tail.split_at(n);
        rest = next;
        pieces.extend(telecommand_frame(body));
    }
    (tx, pieces)
}

/// `body` as one telecommand frame: its length field and CRC-16 set, COBS-encoded and
/// delimited; `None` if it is too short to hold a header and a CRC, or longer than a
/// telecommand may be.
pub fn telecommand_frame(body: &[u8]) -> Option<Vec<u8>> {
    if body.len() < 13 || body.len() > MAX_TC_LEN {
        return None;
    }
    let mut pkt = body.to_vec();
    let n = pkt.len();
    let data_len = u16::try_from(n - 7).ok()?;
    pkt.get_mut(4..6)?.copy_from_slice(&data_len.to_be_bytes());
    let crc = spacepackets::crc::CRC_CCITT_FALSE.checksum(pkt.get(..n - 2)?);
    pkt.get_mut(n - 2..)?.copy_from_slice(&crc.to_be_bytes());
    let mut framed = vec![0u8; encoded_len_max(n)];
    let m = encode(&pkt, &mut framed)?;
    framed.truncate(m);
    Some(framed)
}

/// Drains the link's telemetry through `tx`-byte transmits and checks each: never more than
/// the buffer, the queue shrinks by what was sent, and what was sent is whole frames of
/// packets with a right CRC-16 (`frames` keeps the frame that spans two transmits).
fn drain_link(link: &mut LinkService, tx: usize, frames: &mut Deframer<{ MAX_TM_LEN + 16 }>) {
    let mut out = [0u8; 256];
    let Some(buf) = out.get_mut(..tx) else {
        return;
    };
    loop {
        let before = link.pending_tx();
        let n = link.transmit(buf);
        assert!(
            n <= buf.len(),
            "transmit wrote {n} bytes into {}",
            buf.len()
        );
        assert_eq!(link.pending_tx(), before - n);
        if n == 0 {
            assert_eq!(
                before, 0,
                "transmit sent nothing with {before} bytes queued"
            );
            return;
        }
        for &b in buf.get(..n).unwrap_or_default() {
            match frames.push(b) {
                Pushed::Pending => {}
                Pushed::Error => panic!("the link sent a frame that does not decode"),
                Pushed::Packet(len) => {
                    let pkt = frames.packet(len);
                    assert!(
                        pkt.len() <= MAX_TM_LEN && pkt.len() >= 8,
                        "telemetry packet of {} bytes",
                        pkt.len()
                    );
                    assert_eq!(
                        spacepackets::crc::CRC_CCITT_FALSE.checksum(pkt),
                        0,
                        "telemetry CRC-16"
                    );
                }
            }
        }
    }
}

/// The link with a tracker (the flight configuration, the CCD47-20 read through both
/// outputs, the board's 32 stars): any bytes into [`LinkService::receive`], then the
/// telemetry drained. Checked: no panic, every decoded packet gets exactly one verdict
/// (accepted + rejected = packets), and every transmit: never more than its buffer, the
/// queue shorter by what was sent, and what was sent whole frames of packets with a right
/// CRC-16.
pub fn link_receive(data: &[u8]) {
    let _ = link_receive_run(data);
}

/// What a link target left: the service's counters and the table in force.
pub type LinkRun = (LinkCounters, Option<TableInfo>);

/// [`link_receive`]'s body, returning what it left.
pub fn link_receive_run(data: &[u8]) -> LinkRun {
    let (tx, pieces) = link_input(data);
    with_buffers(|buffers| {
        let Ok(mut tracker) = Tracker::<32>::new(
            TrackerConfig::FLIGHT,
            ReadoutGeometry::CCD47_20_DUAL,
            buffers,
        ) else {
            panic!("the flight configuration is refused");
        };
        let mut tables = MemoryTables::default();
        let mut link = Box::new(LinkService::new());
        let mut frames = Box::new(Deframer::new());
        for piece in &pieces {
            let mut targets = Targets {
                tracker: &mut tracker,
                tables: &mut tables,
                windows: &mut NoWindows,
            };
            link.receive(piece, &mut targets);
            link.poll(&mut targets);
            drain_link(&mut link, tx, &mut frames);
        }
        let c = *link.counters();
        assert_eq!(c.accepted + c.rejected, c.packets, "{c:?}");
        (
            c,
            tables.active(startrack_core::link::protocol::TABLE_KIND_CALIBRATION),
        )
    })
}

/// The link in the safe standby (no tracker: a set-up fault at boot): any bytes into
/// [`LinkService::receive_standby`] with a [`MemoryTables`] store, housekeeping sent after
/// each piece, and the telemetry drained. Checked as [`link_receive`].
pub fn link_standby(data: &[u8]) {
    let _ = link_standby_run(data);
}

/// [`link_standby`]'s body, returning what it left.
pub fn link_standby_run(data: &[u8]) -> LinkRun {
    let (tx, pieces) = link_input(data);
    let mut tables = MemoryTables::default();
    let mut link = Box::new(LinkService::new());
    link.set_setup_faults(0b101);
    let mut frames = Box::new(Deframer::new());
    for piece in &pieces {
        link.receive_standby(piece, &mut tables);
        link.poll_standby(&mut tables);
        link.send_housekeeping(tables.active(TABLE_KIND_CALIBRATION));
        drain_link(&mut link, tx, &mut frames);
    }
    let c = *link.counters();
    assert_eq!(c.accepted + c.rejected, c.packets, "{c:?}");
    (
        c,
        tables.active(startrack_core::link::protocol::TABLE_KIND_CALIBRATION),
    )
}
