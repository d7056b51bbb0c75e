//! Stage 2, integration: sleeping bodies that were given a velocity wake, characters follow
//! their ground and are held off walls ([`character::control`]), gravity applies to awake bodies
//! that are not standing characters; after the resting contacts are solved, each body's swept bounds (the box
//! around its start and end poses, padded by the contact slop) are computed.

use super::Stepper;
use crate::geometry::Aabb;
use crate::par::MIN_PIECE;
use crate::sim::character;
use crate::sim::world::World;
use glam::DVec3;

impl Stepper {
    /// Wakes what inputs set moving and applies gravity. Leaves the number of awake bodies in
    /// `self.awake`.
    pub(super) fn integrate(&mut self, w: &mut World) {
        // A sleeping body an input (or a spawn's push) gave a velocity wakes with its island.
        // (Most worlds in motion have no sleeper: one fast scan of the flags settles that.)
        self.wake_seeds.clear();
        let b = &w.bodies;
        let any_asleep = b.asleep.contains(&true);
        if any_asleep {
            self.wake_seeds.extend((0..b.len()).filter(|&i| b.asleep[i] && b.vel[i] != DVec3::ZERO).map(|i| i as u32));
        }
        if !self.wake_seeds.is_empty() {
            self.islands.wake(w, &self.wake_seeds);
        }
        if self.plan.characters {
            character::control(w, &mut self.characters);
        }
        let cfg = &w.config;
        let dt = cfg.dt;
        let n = w.bodies.len();
        let b = &mut w.bodies;
        self.awake = if any_asleep { b.asleep.iter().filter(|a| !**a).count() } else { n };
        if self.plan.gravity {
            let grounded = |i: usize| self.plan.characters && self.characters.grounded[i];
            for i in 0..n {
                if !b.asleep[i]
                    && b.inv_mass[i] > 0.0
                    && cfg.classes.props[b.class[i].0 as usize].gravity
                    && !grounded(i)
                {
                    b.vel[i] += cfg.gravity * dt;
                }
            }
        }
    }

    /// Resets the per-tick buffers for `w`'s bodies and computes their swept bounds.
    pub(super) fn swept_bounds(&mut self, w: &World, first_new: u32) {
        let first_tick = w.tick.0 == 0;
        let n = w.bodies.len();
        let cfg = &w.config;
        let dt = cfg.dt;
        let b = &w.bodies;
        let slop = cfg.contact_slop_m;
        // Plain indexed writes into buffers sized once: this loop runs for every body every tick.
        self.aabbs.resize(n, Aabb::EMPTY);
        self.base.clear();
        self.base.extend_from_slice(&b.pos);
        self.t0.clear();
        self.t0.resize(n, 0.0);
        self.version.clear();
        self.version.resize(n, 0);
        self.moving.clear();
        // A body at rest is not re-tested against another at rest, except on its first tick:
        // the scene's bodies at tick 0 and bodies spawned this tick may have been placed
        // overlapping something, and nothing else would ever separate them. A sleeping body's
        // velocity is zero, so it never moves.
        self.moving.extend(b.vel.iter().zip(&b.id).map(|(v, id)| *v != DVec3::ZERO || first_tick || id.0 >= first_new));
        self.dead.clear();
        self.dead.resize(n, false);
        self.count.clear();
        self.count.resize(n, 0);
        self.clip_len.clear();
        self.clip_len.resize(n, 0);
        self.clip.resize(n, [DVec3::ZERO; 3]);
        let pad = DVec3::splat(slop);
        self.pool.for_each_mut(&mut self.aabbs, MIN_PIECE, |first, boxes| {
            for (k, out) in boxes.iter_mut().enumerate() {
                let i = first + k;
                let p0 = b.pos[i];
                let p1 = p0 + b.vel[i] * dt;
                *out = Aabb { min: p0.min(p1) + b.aabb_lo[i] - pad, max: p0.max(p1) + b.aabb_hi[i] + pad };
            }
        });
    }
}
