//! Spawning the application's and the boards' tasks: a task that cannot be spawned (spawned
//! twice, its pool full) is logged and reported, never a panic. Cost: one executor call.

use embassy_executor::{SpawnError, SpawnToken, Spawner};

/// Spawns a task, or logs why it could not be (a task spawned twice); `false` then.
pub(crate) fn spawn_or_log<S>(
    spawner: Spawner,
    name: &str,
    token: Result<SpawnToken<S>, SpawnError>,
) -> bool {
    match token {
        Ok(token) => {
            spawner.spawn(token);
            true
        }
        Err(e) => {
            defmt::error!("cannot spawn {=str}: {}", name, e);
            false
        }
    }
}
