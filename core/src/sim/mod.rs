//! The simulation core: pure and deterministic. No clock reaches a result, no network, and the
//! thread count never does: [`Stepper::step`] is a function of (world, inputs) -> (world,
//! events), and tests, benchmarks, rollback and the network runtime all drive it. Stages that
//! are maps over bodies or pairs run on a [`Pool`] ([`crate::par`] says why their output cannot depend
//! on how many threads it has).

pub mod character;
pub mod input;
pub mod island;
pub mod output;
pub mod overlaps;
pub mod plan;
pub mod ray;
pub mod ray_index;
pub mod step;
pub mod world;

pub use crate::par::Pool;
pub use input::{SystemAction, TickInput};
pub use output::TickOutput;
pub use plan::Plan;
pub use step::{StageStats, Stepper};
pub use world::World;
