//! `README.md`: it stays short, with reference material in `docs/`.

use super::helpers::read;

#[test]
fn readme_stays_short() {
    // The README says what the project is and links the reference pages in docs/, which hold
    // the rest.
    let n = read("README.md").lines().count();
    assert!(
        n <= 150,
        "README.md has {n} lines: move reference material to docs/"
    );
}
