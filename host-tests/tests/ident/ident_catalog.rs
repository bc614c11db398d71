//! The on-board catalog format: a built catalog parses and answers its queries; any changed
//! byte, any truncation, any random input gets a typed error and never a panic.

use proptest::prelude::*;
use startrack_core::catalog::{Catalog, CatalogError};
use startrack_sim::sky::build::{BuildSpec, build};
use startrack_sim::sky::{default_list_path, read_list};
use std::sync::OnceLock;

/// A small catalog (Hp <= 4, about 500 stars) so each case parses in microseconds.
fn small() -> &'static [u8] {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| {
        let list = read_list(&default_list_path()).unwrap_or_else(|e| panic!("{e}"));
        let mut spec = BuildSpec::fov_15deg();
        spec.mag_limit = 4.0;
        build(&list, &spec).unwrap_or_else(|e| panic!("{e}")).bytes
    })
}

#[test]
fn built_catalog_parses_and_its_queries_agree_with_brute_force() {
    let cat = Catalog::parse(small()).unwrap_or_else(|e| panic!("{e}"));
    assert!(cat.star_count() > 400 && cat.pair_count() > 1000);
    // Pair range against a scan.
    for (lo, hi) in [(0.01, 0.02), (0.1, 0.1005), (0.0, 0.001), (0.2, 0.5)] {
        let r = cat.pairs_between(lo, hi);
        let scan: Vec<usize> = (0..cat.pair_count())
            .filter(|&i| {
                let s = f64::from(cat.pair(i).map_or(0, |p| p.separation_nrad)) / 1e9;
                s >= lo && s <= hi
            })
            .collect();
        assert_eq!(r.clone().collect::<Vec<_>>(), scan, "[{lo}, {hi}]");
    }
    // Cone search against a scan.
    let mut found = 0;
    for (dir, radius) in [
        ([0.0, 0.0, 1.0], 0.2),
        ([0.6, 0.0, -0.8], 0.25),
        ([0.0, 1.0, 0.0], 0.3),
    ] {
        let got: Vec<usize> = cat.cone(dir, radius).map(|(i, _)| i).collect();
        let want: Vec<usize> = (0..cat.star_count())
            .filter(|&i| {
                let d = cat.dir(i).unwrap_or_default();
                d[0] * dir[0] + d[1] * dir[1] + d[2] * dir[2] >= radius.cos()
            })
            .collect();
        found += got.len();
        assert_eq!(got, want);
    }
    assert!(found > 10, "{found}");
}

#[test]
fn erased_flash_and_truncation_are_named() {
    assert_eq!(
        Catalog::parse(&[0xFF; 4096]).err(),
        Some(CatalogError::BadMagic)
    );
    let b = small();
    assert_eq!(
        Catalog::parse(&b[..40]).err(),
        Some(CatalogError::TooShort { got: 40 })
    );
    assert!(matches!(
        Catalog::parse(&b[..b.len() - 1]),
        Err(CatalogError::LengthMismatch { .. })
    ));
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(512)))]

    #[test]
    fn any_changed_byte_is_rejected(pos in 0usize..1_000_000, flip in 1u8..=255) {
        let mut b = small().to_vec();
        let pos = pos % b.len();
        b[pos] ^= flip;
        prop_assert!(Catalog::parse(&b).is_err());
    }

    #[test]
    fn any_truncation_is_rejected(len in 0usize..1_000_000) {
        let b = small();
        let len = len % b.len();
        prop_assert!(Catalog::parse(&b[..len]).is_err());
    }

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512), magic in any::<bool>()) {
        let mut bytes = bytes;
        if magic && bytes.len() >= 6 {
            bytes[..4].copy_from_slice(b"STCG");
            bytes[4..6].copy_from_slice(&1u16.to_le_bytes());
        }
        let _ = Catalog::parse(&bytes);
    }
}

/// The committed catalog that the Cortex-M7 bench links (`firmware/src/bin/m7bench/ident.rs`)
/// is the one `startrack catalog build` makes from the committed list.
#[test]
fn committed_catalog_is_the_build_of_the_committed_list() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/catalog-15deg.bin");
    let committed = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let built = startrack_sim::sky::build::default_catalog()
        .unwrap_or_else(|e| panic!("{e}"))
        .bytes;
    assert!(
        committed == built,
        "{} is stale: startrack catalog build --out {}",
        path.display(),
        path.display()
    );
}
