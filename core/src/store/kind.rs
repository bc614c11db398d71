//! The kinds of table the store holds, and the code each carries in its slot header. A
//! plain enum: no storage, no cost beyond a match.

/// What a table is for. The code is the byte the slot header carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TableKind {
    /// The calibration table ([`crate::table::CalibTable`]).
    Calibration,
    /// The star catalog (the store keeps its bytes like any table's and checks their CRC).
    Catalog,
}

impl TableKind {
    /// Number of kinds.
    pub const COUNT: usize = 2;
    /// Every kind, in index order.
    pub const ALL: [TableKind; Self::COUNT] = [TableKind::Calibration, TableKind::Catalog];

    /// The code in a slot header (1 calibration, 2 catalog).
    pub const fn code(self) -> u8 {
        match self {
            Self::Calibration => 1,
            Self::Catalog => 2,
        }
    }

    /// The kind of a header code, `None` for an unknown one.
    pub const fn from_code(code: u8) -> Option<Self> {
        match code {
            1 => Some(Self::Calibration),
            2 => Some(Self::Catalog),
            _ => None,
        }
    }

    /// Position in [`TableKind::ALL`] and in the store's per-kind arrays.
    pub const fn index(self) -> usize {
        match self {
            Self::Calibration => 0,
            Self::Catalog => 1,
        }
    }
}
