//! `docs/hardware.md` against `host-tests/pil-figures.csv`, the figures of the processor in
//! the loop (`startrack pil --frames 4 --sky --compare --figures host-tests/pil-figures.csv`).

use super::helpers::{read, table};

#[test]
fn pil_table_is_the_committed_run() {
    let (header, body) = table("docs/hardware.md", "pil-figures");
    assert_eq!(header, ["figure", "value", "what"]);
    let csv = read("host-tests/pil-figures.csv");
    let mut rows = csv.lines();
    assert_eq!(rows.next(), Some("name,value"));
    let figures: Vec<(&str, &str)> = rows.filter_map(|l| l.split_once(',')).collect();
    assert_eq!(body.len(), figures.len(), "one row per figure");
    for (r, (name, value)) in body.iter().zip(&figures) {
        assert_eq!(r[0].replace('`', ""), *name);
        assert_eq!(r[1].replace(',', ""), *value, "{name}");
    }
    let value = |name: &str| -> f64 {
        figures
            .iter()
            .find(|(n, _)| *n == name)
            .and_then(|(_, v)| v.parse().ok())
            .unwrap_or_else(|| panic!("{name} missing"))
    };
    // The seconds beside the instructions: at 480 MHz, one instruction a cycle.
    let boot = format!(
        "{:.4} s at 480 MHz",
        value("boot_to_first_attitude_instructions") / 480e6
    );
    let frame = format!(
        "{:.1} ms at 480 MHz",
        value("tracking_frame_instructions_min") / 480e3
    );
    let doc = read("docs/hardware.md");
    assert!(doc.contains(&boot), "{boot}");
    assert!(doc.contains(&frame), "{frame}");
    // The run compared every star and attitude with the SIL's, and they were equal.
    assert_eq!(value("stars_identical"), value("stars_compared"));
    assert_eq!(value("attitudes_identical"), value("attitudes_compared"));
}
