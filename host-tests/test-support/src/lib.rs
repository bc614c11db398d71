//! What the host test binaries share: the f64 references of the centroid tests (`psf`), the
//! tracker tests' scene (`field`), the command tests' helpers (`cli`) and the calibration-table
//! fixtures (`table_fixtures`), and where the property tests keep their regression cases
//! ([`regressions_beside_source`]). A library of its own so that each test binary links it as a
//! dependency instead of compiling a copy; it is never published and has no logic the product
//! uses.

pub mod cli;
pub mod field;
pub mod psf;
pub mod table_fixtures;

use proptest::test_runner::{Config as ProptestConfig, FileFailurePersistence};

/// `config` with its failing cases kept beside the test module's source file, as
/// `<module>.proptest-regressions`, where the committed cases are replayed from. (proptest's
/// default puts them in a `proptest-regressions/` directory next to the directory of the
/// nearest `main.rs`, which for a module of a test binary is not beside the module.)
pub fn regressions_beside_source(config: ProptestConfig) -> ProptestConfig {
    ProptestConfig {
        failure_persistence: Some(Box::new(FileFailurePersistence::WithSource(
            "proptest-regressions",
        ))),
        ..config
    }
}
