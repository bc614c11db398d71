//! The tracker tests' scene: the default sensor with a seed, a seeded star field and the
//! sensor's true calibration table.

use startrack_homes::demo::star_field;
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator};

/// The sensor, a seeded field of `stars` stars and its true table (encoded).
pub fn field(seed: u64, stars: usize) -> (Simulator, Vec<u8>) {
    let params = SensorParams {
        seed,
        ..SensorParams::default()
    };
    let sim = Simulator::new(params.clone(), star_field(seed, stars, &params));
    let table = sim.truth_table(TruthSections::ALL).unwrap();
    (sim, table)
}
