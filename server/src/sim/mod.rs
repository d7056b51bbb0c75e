//! The simulation core: pure and deterministic. No clock reaches a result, no network, no
//! threads: [`Stepper::step`] is a function of (world, inputs) -> (world, events), and tests,
//! benchmarks, rollback and the network runtime all drive it.

pub mod input;
pub mod island;
pub mod output;
pub mod plan;
pub mod ray;
pub mod step;
pub mod world;

pub use input::{SystemAction, TickInput};
pub use output::TickOutput;
pub use plan::Plan;
pub use step::{StageStats, Stepper};
pub use world::World;
