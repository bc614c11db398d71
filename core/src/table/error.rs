//! Why a calibration table was rejected or could not be written.

/// The sections a table can hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u16)]
pub enum SectionKind {
    /// Per-output gains, e-/ADU.
    Gains = 1,
    /// Per-column bias offsets, ADU.
    ColumnBias = 2,
    /// Relative dark map.
    DarkRel = 3,
    /// Inverse flat-field map.
    FlatInv = 4,
    /// Hot-pixel list.
    HotPixels = 5,
    /// Telegraph-pixel list.
    Telegraph = 6,
    /// Pixel-phase correction curves of the centre of gravity.
    PixCorr = 7,
    /// Charge-transfer (CTI) centroid-shift coefficients.
    Cti = 8,
    /// Field PSF model (width against position).
    PsfModel = 9,
    /// The camera model: focal length, principal point, distortion, lateral colour.
    CameraModel = 10,
    /// The covered pixels' dark law: rate at a reference temperature, doubling, band.
    DarkLaw = 11,
}

impl SectionKind {
    /// Every kind, in directory order.
    pub const ALL: [SectionKind; 11] = [
        Self::Gains,
        Self::ColumnBias,
        Self::DarkRel,
        Self::FlatInv,
        Self::HotPixels,
        Self::Telegraph,
        Self::PixCorr,
        Self::Cti,
        Self::PsfModel,
        Self::CameraModel,
        Self::DarkLaw,
    ];

    /// The kind with this code, if any.
    pub fn from_code(code: u16) -> Option<Self> {
        Self::ALL.into_iter().find(|k| *k as u16 == code)
    }

    /// A short lower-case name.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Gains => "gains",
            Self::ColumnBias => "column bias",
            Self::DarkRel => "relative dark",
            Self::FlatInv => "inverse flat",
            Self::HotPixels => "hot pixels",
            Self::Telegraph => "telegraph pixels",
            Self::PixCorr => "pixel-phase correction",
            Self::Cti => "CTI coefficients",
            Self::PsfModel => "field PSF model",
            Self::CameraModel => "camera model",
            Self::DarkLaw => "dark law",
        }
    }
}

/// Why a table is not used. Every rejection names what is wrong; a table that fails any check
/// is never partly used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum TableError {
    /// Fewer bytes than the header (or the directory) needs.
    TooShort {
        /// Bytes needed.
        needed: u32,
        /// Bytes given.
        got: u32,
    },
    /// The first four bytes are not `STCT` (erased flash reads as 0xFF).
    BadMagic,
    /// A version this firmware does not read.
    UnsupportedVersion(u16),
    /// The header's total length disagrees with the bytes given (or is shorter than the
    /// header and directory).
    LengthMismatch {
        /// Length the header states.
        header: u32,
        /// Bytes given.
        actual: u32,
    },
    /// The header or directory fails its CRC.
    HeaderCrc,
    /// A reserved field is not zero.
    Reserved,
    /// More sections than the format allows.
    TooManySections(u16),
    /// The geometry in the header is not valid.
    Geometry(crate::geometry::GeometryError),
    /// A directory entry's kind is not known to this version.
    UnknownSection(u16),
    /// Two directory entries have the same kind.
    DuplicateSection(SectionKind),
    /// A required section is absent.
    MissingSection(SectionKind),
    /// A section lies (partly) outside the table or over the header.
    SectionOutOfBounds(SectionKind),
    /// Sections do not follow the directory back to back: this one leaves a gap before it
    /// (bytes no CRC covers) or overlaps another, or the last one does not end the table.
    SectionLayout(SectionKind),
    /// A section's bytes fail their CRC.
    SectionCrc(SectionKind),
    /// A section's length does not match what the geometry or its own count implies.
    SectionLength(SectionKind),
    /// A map's header (tile size, element format, tile counts) does not fit the geometry.
    MapFormat(SectionKind),
    /// An entry holds a value outside its documented range (a zero gain or flat, a defect
    /// outside the active area, an unsorted or repeated defect, an unknown policy); `index`
    /// is the entry's position in its section.
    OutOfRange {
        /// The section.
        section: SectionKind,
        /// The entry's index within the section.
        index: u32,
    },
    /// A section's own format field (the PSF model's degree) is not one this version reads.
    SectionFormat(SectionKind),
    /// A pixel-phase correction curve is malformed: `index` is the curve's position in the
    /// section (the curve count when the curves do not fill the section exactly).
    PixCorrCurve {
        /// The curve's index.
        index: u32,
        /// What is wrong with it.
        error: super::pixcorr::PixCorrError,
    },
    /// The camera model (section 10) is not usable: a value out of its range, or a
    /// distortion that has no inverse over the active area.
    CameraModel(crate::attitude::CameraError),
}

impl core::fmt::Display for TableError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooShort { needed, got } => {
                write!(
                    f,
                    "calibration table too short: {got} bytes, needs {needed}"
                )
            }
            Self::BadMagic => f.write_str("not a calibration table (bad magic)"),
            Self::UnsupportedVersion(v) => write!(f, "calibration table version {v} not supported"),
            Self::LengthMismatch { header, actual } => {
                write!(
                    f,
                    "calibration table length: header says {header}, have {actual} bytes"
                )
            }
            Self::HeaderCrc => f.write_str("calibration table header CRC mismatch"),
            Self::Reserved => f.write_str("calibration table: reserved field not zero"),
            Self::TooManySections(n) => write!(f, "calibration table: {n} sections, at most 16"),
            Self::Geometry(e) => write!(f, "calibration table {e}"),
            Self::UnknownSection(k) => write!(f, "calibration table: unknown section kind {k}"),
            Self::DuplicateSection(k) => write!(f, "calibration table: {} twice", k.name()),
            Self::MissingSection(k) => write!(f, "calibration table: no {} section", k.name()),
            Self::SectionOutOfBounds(k) => {
                write!(f, "calibration table: {} section out of bounds", k.name())
            }
            Self::SectionLayout(k) => write!(
                f,
                "calibration table: {} section leaves a gap or overlaps another",
                k.name()
            ),
            Self::SectionCrc(k) => {
                write!(f, "calibration table: {} section CRC mismatch", k.name())
            }
            Self::SectionLength(k) => {
                write!(f, "calibration table: {} section length wrong", k.name())
            }
            Self::MapFormat(k) => write!(f, "calibration table: {} map header invalid", k.name()),
            Self::OutOfRange { section, index } => write!(
                f,
                "calibration table: {} entry {index} out of range",
                section.name()
            ),
            Self::SectionFormat(k) => {
                write!(f, "calibration table: {} format not supported", k.name())
            }
            Self::PixCorrCurve { index, error } => {
                write!(f, "calibration table: curve {index}: {error}")
            }
            Self::CameraModel(e) => write!(f, "calibration table: {e}"),
        }
    }
}

impl core::error::Error for TableError {}

/// Why a table could not be written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum WriteError {
    /// The output buffer is smaller than [`crate::table::TableSpec::encoded_len`].
    BufferTooSmall {
        /// Bytes needed.
        needed: usize,
    },
    /// The spec would not pass the parser's checks; the error says which one.
    Invalid(TableError),
}

impl core::fmt::Display for WriteError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::BufferTooSmall { needed } => write!(f, "table needs a {needed}-byte buffer"),
            Self::Invalid(e) => write!(f, "cannot write table: {e}"),
        }
    }
}

impl core::error::Error for WriteError {}
