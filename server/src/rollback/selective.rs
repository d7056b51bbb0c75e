//! Selective re-simulation (see resimulate).

use super::{Advance, Session};
use impact_protocol::Tick;

/// Re-simulates only what the late inputs can reach. Returns false when it cannot prove that
/// equal to a full re-simulation; the caller then does the full one.
pub fn resimulate(_s: &mut Session, _from: Tick, _adv: &mut Advance) -> bool {
    false
}
