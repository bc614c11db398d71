//! `docs/formats.md`'s bit tables against the code: the star flags, provenance and
//! obstruction bits.

use super::helpers::table;
use startrack_core::tracker::{Obstructions, Provenance, StarFlags};

/// The bit table under `marker` in docs/formats.md against `bits` (name, value), in order:
/// one row each, its bit, value and name.
fn check_bit_table(marker: &str, columns: &[&str], bits: &[(&str, u32)]) {
    let (header, body) = table("docs/formats.md", marker);
    assert_eq!(header, columns, "{marker}: columns");
    assert_eq!(body.len(), bits.len(), "{marker}: one row per bit");
    for (r, (name, value)) in body.iter().zip(bits) {
        let bit = value.trailing_zeros();
        assert_eq!(r[0], bit.to_string(), "{name}'s bit");
        assert_eq!(r[1], value.to_string(), "{name}'s value");
        assert_eq!(r[2].replace('`', ""), *name, "bit {bit}'s name");
    }
}

#[test]
fn star_flag_table_is_star_flags() {
    let flags: Vec<(&str, u32)> = StarFlags::all()
        .iter_names()
        .map(|(n, f)| (n, f.bits()))
        .collect();
    check_bit_table(
        "star-flags",
        &["bit", "value", "flag", "from", "meaning"],
        &flags,
    );
}

#[test]
fn star_provenance_table_is_the_provenance_bits() {
    let bits: Vec<(&str, u32)> = Provenance::all()
        .iter_names()
        .map(|(n, f)| (n, u32::from(f.bits())))
        .collect();
    check_bit_table(
        "star-provenance",
        &["bit", "value", "flag", "meaning"],
        &bits,
    );
}

#[test]
fn obstruction_table_is_the_obstruction_bits() {
    let bits: Vec<(&str, u32)> = Obstructions::all()
        .iter_names()
        .map(|(n, f)| (n, u32::from(f.bits())))
        .collect();
    check_bit_table(
        "frame-obstructions",
        &["bit", "value", "flag", "meaning"],
        &bits,
    );
}
