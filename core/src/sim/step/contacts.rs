//! Stage 3, resting contacts: the pairs that ended the last tick touching (the contact cache,
//! `World::touching`) are held apart at the velocity level before anything moves, so a body
//! standing on the floor, a stack or a pile under gravity needs no impact, no bisection and no
//! event each tick.
//!
//! This is a small sequential-impulse solver (Box2D's and rapier's velocity solver, without
//! rotation, since impact's orientations are fixed): every cached contact gets a normal impulse
//! that is never negative (contacts push, never pull) and removes the pair's approach along the
//! normal, inelastically, and a Coulomb friction impulse bounded by `friction` times it.
//! Normal and friction impulses are warm-started from the ones the same contact needed the
//! tick before (stored in the cache, so they are world state like everything else), which is
//! what lets a pile hold its weight with a few iterations. Sleeping bodies, static geometry and terrain are
//! immovable here.
//!
//! Only a resting approach is solved: a pair closing faster than one tick of gravity plus the
//! bounce threshold is an impact and goes through the time-of-impact search and its response
//! (a bounce keeps its restitution). Overlap is not corrected here: the settle pass does that.
//! The stage runs when the scene has gravity (without it nothing rests on anything).

use super::Stepper;
use crate::sim::world::World;
use glam::DVec3;

/// Gauss-Seidel iterations over the contacts.
const ITERATIONS: u32 = 8;

/// Fraction of the overlap beyond half the slop that a contact's separating bias removes per
/// tick (Baumgarte's factor): a pile that sank a little rises back gently instead of being
/// pushed apart by the settle pass every tick.
const BIAS_FACTOR: f64 = 0.2;

/// A velocity this small (m/s) after solving is zero: what is left of a body that was exactly
/// held is rounding, and zero lets a body at rest be skipped by the pair tests at once.
const REST_SPEED_MPS: f64 = 1e-9;

/// One cached contact being solved.
#[derive(Clone, Copy, Debug)]
pub(super) struct Row {
    /// Index in `World::touching`.
    index: u32,
    /// Slot of the dynamic body at the normal's tail, if it can move.
    a: Option<u32>,
    /// Slot of the dynamic body at the normal's head, if it can move.
    b: Option<u32>,
    /// Unit normal from `a` to `b`.
    normal: DVec3,
    /// `1 / (inverse mass a + inverse mass b)`, kg.
    mass: f64,
    /// Separating speed the contact aims for, m/s (0, or a little to undo overlap).
    bias: f64,
    /// Accumulated normal impulse, N s, >= 0.
    normal_impulse: f64,
    /// Accumulated friction impulse, N s.
    friction_impulse: DVec3,
}

impl Stepper {
    /// Solves the cached contacts (see the module doc). Leaves each contact's normal and friction
    /// impulses in `self.contact_impulse`, by index in `w.touching`, for the contact cache of this tick.
    pub(super) fn solve_contacts(&mut self, w: &mut World) {
        if self.awake == 0 {
            return; // the tick ends before events: nothing here is read
        }
        // Contacts not solved this tick (between sleepers, say) keep their impulse.
        self.contact_impulse.clear();
        self.contact_impulse.extend(w.touching.iter().map(|t| (t.impulse, t.friction_impulse)));
        // The pairs' slots, for this stage and for events (no body comes or goes in between).
        w.touching_slots(&mut self.touch_slots, &self.touch_hints, &self.pool);
        if !self.plan.gravity || w.touching.is_empty() {
            return;
        }
        let cfg = &w.config;
        let resting = cfg.gravity.length() * cfg.dt + cfg.bounce_threshold_mps;
        let friction = cfg.friction;
        let slop = cfg.contact_slop_m;
        let dt = cfg.dt;
        let b = &w.bodies;
        // A side that can move: an awake body with mass.
        let movable = |slot: Option<u32>| slot.filter(|&s| !b.asleep[s as usize] && b.inv_mass[s as usize] > 0.0);
        self.rows.clear();
        for (k, (t, [sa, sb])) in w.touching.iter().zip(&self.touch_slots).enumerate() {
            let (a, bb) = (movable(*sa), movable(*sb));
            if a.is_none() && bb.is_none() {
                continue;
            }
            let inv = |s: Option<u32>| s.map_or(0.0, |s| b.inv_mass[s as usize]);
            let (va, vb) = (vel(b.vel.as_slice(), a), vel(b.vel.as_slice(), bb));
            if -(vb - va).dot(t.normal) > resting {
                continue; // an impact, not rest
            }
            let bias = BIAS_FACTOR * (t.depth - 0.5 * slop).max(0.0) / dt;
            self.rows.push(Row {
                index: k as u32,
                a,
                b: bb,
                normal: t.normal,
                mass: 1.0 / (inv(a) + inv(bb)),
                bias,
                normal_impulse: t.impulse,
                // Last tick's friction, in this tick's tangent plane.
                friction_impulse: t.friction_impulse - t.normal * t.friction_impulse.dot(t.normal),
            });
        }
        let (v, table) = w.bodies.vel_and_table();
        let inv_mass = &table.inv_mass;
        // Warm start: last tick's impulses first.
        for r in &self.rows {
            apply(v, inv_mass, r, r.normal * r.normal_impulse + r.friction_impulse);
        }
        for _ in 0..ITERATIONS {
            for r in self.rows.iter_mut() {
                let n = r.normal;
                let rel = vel(v, r.b) - vel(v, r.a);
                let total = (r.normal_impulse - (rel.dot(n) - r.bias) * r.mass).max(0.0);
                let dn = total - r.normal_impulse;
                r.normal_impulse = total;
                apply(v, inv_mass, r, n * dn);
                if friction > 0.0 {
                    let rel = vel(v, r.b) - vel(v, r.a);
                    let slip = rel - n * rel.dot(n);
                    let mut f = r.friction_impulse - slip * r.mass;
                    let cap = friction * r.normal_impulse;
                    let len = f.length();
                    if len > cap {
                        f *= cap / len;
                    }
                    let df = f - r.friction_impulse;
                    r.friction_impulse = f;
                    apply(v, inv_mass, r, df);
                }
            }
        }
        for r in &self.rows {
            self.contact_impulse[r.index as usize] = (r.normal_impulse, r.friction_impulse);
            for s in [r.a, r.b].into_iter().flatten() {
                let u = &mut v[s as usize];
                if u.length_squared() < REST_SPEED_MPS * REST_SPEED_MPS {
                    *u = DVec3::ZERO;
                }
            }
        }
    }
}

fn vel(v: &[DVec3], s: Option<u32>) -> DVec3 {
    s.map_or(DVec3::ZERO, |s| v[s as usize])
}

/// Applies impulse `j` (N s, along a to b) to the row's bodies: `a` is pushed back, `b` on.
fn apply(v: &mut [DVec3], inv_mass: &[f64], r: &Row, j: DVec3) {
    if let Some(a) = r.a {
        v[a as usize] -= j * inv_mass[a as usize];
    }
    if let Some(b) = r.b {
        v[b as usize] += j * inv_mass[b as usize];
    }
}
