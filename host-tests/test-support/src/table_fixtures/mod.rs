//! Shared fixtures for the calibration-table tests (`table_format`, `table_fuzz`):
//!
//! - [`specs`]: owned table specs and the values they hold;
//! - [`encode`]: an independent encoder/decoder of the documented layout;
//! - [`bytes`]: the format's CRC, field access and byte patchers that re-seal the header and
//!   section CRCs (CRC-32/ISO-HDLC from the `crc` crate) so that the checks behind them are
//!   reached;
//! - [`checks`]: the parser's promises, checked on any parsed table.

pub mod bytes;
pub mod checks;
pub mod encode;
pub mod specs;

pub use bytes::*;
pub use checks::*;
pub use encode::*;
pub use specs::*;
