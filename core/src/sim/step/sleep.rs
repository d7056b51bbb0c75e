//! Stage 9, sleep: still timers, islands, and the islands that fall asleep. The rules are in
//! [`crate::sim::island`]; this stage only runs them at the end of the tick.

use super::Stepper;
use crate::sim::world::World;

impl Stepper {
    /// Updates every awake body's still timer and puts to sleep the islands that are ready.
    pub(super) fn sleep(&mut self, w: &mut World) {
        self.islands.fall_asleep(w);
    }
}
