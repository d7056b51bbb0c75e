//! Terrain: a regular height field ([`heightfield`]) and irregular triangulated terrain
//! ([`tin`]), as in DESIGN.md ("Terrain"). Both are static and solid below their surface.

pub mod heightfield;
pub mod tin;
