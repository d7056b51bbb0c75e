//! World queries that are not part of the tick: ray casts for picking and hitscan.

pub mod ray;
