//! impact client sim.
