//! Host-side support: the simulated sensor and shared test helpers.
