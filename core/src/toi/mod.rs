//! Time of impact within a step.
//!
//! - [`analytic`]: the swept-sphere formula, exact; the reference every other method is
//!   measured against, and the kernel a spheres-only plan uses.
//! - [`bisect`]: overlap testing moved back in time by bisection, with fine sampling for pairs
//!   that move farther than their smallest extent (so they cannot tunnel).

pub mod analytic;
pub mod bisect;
