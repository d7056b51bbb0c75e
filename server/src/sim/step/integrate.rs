//! Stage 2, integration: sleeping bodies that were given a velocity wake, gravity applies to
//! awake bodies, resting bodies are held up by their supports, and each body's swept bounds
//! (the box around its start and end poses, padded by the contact slop) are computed.
//!
//! Support. A body that ended the last tick touching something beneath it (a cached contact
//! whose normal is within [`SUPPORT_COS`] of straight up, against static geometry, terrain, a
//! sleeping body or a body already held up this tick) does not fall into it: the approaching
//! normal velocity gravity gave it is cancelled here, before the step, so a standing body needs
//! no impact, no bisection and no event. Supports are settled from the ground up (a box on a box
//! on the floor is held once the lower box is), and friction removes tangential speed in
//! proportion to the normal speed cancelled (Coulomb). Only a resting approach is cancelled
//! (at most one tick of gravity plus the bounce threshold); anything faster is an impact and
//! goes through the time-of-impact search as before.

use super::Stepper;
use crate::sim::shape::Aabb;
use crate::sim::world::World;
use glam::DVec3;

/// A contact supports a body when its normal (out of the support, towards the body) is within
/// 60 degrees of straight up: cos 60 = 0.5.
pub(super) const SUPPORT_COS: f64 = 0.5;

/// Passes of the bottom-up support settle: a stack this many bodies high is held in one tick.
const SUPPORT_PASSES: u32 = 32;

/// Most supports one body is held by (the first in contact-list order).
const MAX_SUPPORTS: usize = 6;

/// Gauss-Seidel passes over one body's supports (two or three planes converge in a few).
const SUPPORT_ITERATIONS: u32 = 4;

/// A resting contact seen from the body it holds up.
#[derive(Clone, Copy, Debug)]
pub(super) struct Support {
    /// The body held (slot).
    body: u32,
    /// The dynamic body holding it (slot), or `None` for static geometry and terrain.
    partner: Option<u32>,
    /// Unit normal out of the support, towards the body.
    normal: DVec3,
}

impl Stepper {
    /// Resets the per-tick buffers for `w`'s bodies, wakes what inputs set moving, applies
    /// gravity and support, and computes swept bounds. `first_new` is the first entity id
    /// spawned this tick. Leaves the number of awake bodies in `self.awake`.
    pub(super) fn integrate(&mut self, w: &mut World, first_new: u32) {
        // A sleeping body an input (or a spawn's push) gave a velocity wakes with its island.
        self.wake_seeds.clear();
        let b = &w.bodies;
        self.wake_seeds.extend((0..b.len()).filter(|&i| b.asleep[i] && b.vel[i] != DVec3::ZERO).map(|i| i as u32));
        if !self.wake_seeds.is_empty() {
            self.islands.wake(w, &self.wake_seeds);
        }
        let first_tick = w.tick.0 == 0;
        let cfg = &w.config;
        let dt = cfg.dt;
        let n = w.bodies.len();
        let b = &mut w.bodies;
        self.awake = b.asleep.iter().filter(|a| !**a).count();
        if self.plan.gravity {
            for i in 0..n {
                if !b.asleep[i] && b.inv_mass[i] > 0.0 && cfg.classes.props[b.class[i].0 as usize].gravity {
                    b.vel[i] += cfg.gravity * dt;
                }
            }
            if !w.touching.is_empty() && self.awake > 0 {
                self.support(w);
            }
        }
        let cfg = &w.config;
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
        for i in 0..n {
            let p0 = b.pos[i];
            let p1 = p0 + b.vel[i] * dt;
            self.aabbs[i] = Aabb { min: p0.min(p1) + b.aabb_lo[i] - pad, max: p0.max(p1) + b.aabb_hi[i] + pad };
        }
    }

    /// Cancels the resting approach of every supported awake body (see the module doc).
    fn support(&mut self, w: &mut World) {
        let cfg = &w.config;
        let up = -cfg.gravity.normalize();
        // One tick of gravity, plus what the bounce rule already treats as resting.
        let resting = cfg.gravity.length() * cfg.dt + cfg.bounce_threshold_mps;
        let friction = cfg.friction;
        let b = &mut w.bodies;
        let held = |i: usize| !b.asleep[i] && b.inv_mass[i] > 0.0 && cfg.classes.props[b.class[i].0 as usize].gravity;
        self.supports.clear();
        for t in &w.touching {
            let (sa, sb) = (b.slot(t.a), b.slot(t.b));
            if let Some(i) = sa.filter(|&i| held(i) && -t.normal.dot(up) >= SUPPORT_COS) {
                self.supports.push(Support { body: i as u32, partner: sb.map(|j| j as u32), normal: -t.normal });
            }
            if let Some(j) = sb.filter(|&j| held(j) && t.normal.dot(up) >= SUPPORT_COS) {
                self.supports.push(Support { body: j as u32, partner: sa.map(|i| i as u32), normal: t.normal });
            }
        }
        if self.supports.is_empty() {
            return;
        }
        // Grouped by body; within a body, contact-list order (a stable sort).
        self.supports.sort_by_key(|s| s.body);
        self.support_done.clear();
        self.support_done.resize(b.len(), false);
        for _ in 0..SUPPORT_PASSES {
            let mut progress = false;
            let mut k = 0;
            while k < self.supports.len() {
                let body = self.supports[k].body as usize;
                let end = k + self.supports[k..].iter().take_while(|s| s.body as usize == body).count();
                let group = k..end;
                k = end;
                if self.support_done[body] {
                    continue;
                }
                // The supports already holding still this tick: the ground, sleepers, settled
                // bodies. (n, partner velocity) pairs.
                let mut planes = [(DVec3::ZERO, DVec3::ZERO); MAX_SUPPORTS];
                let mut len = 0;
                for s in &self.supports[group] {
                    let ready = match s.partner {
                        None => Some(DVec3::ZERO),
                        Some(j) if b.asleep[j as usize] || self.support_done[j as usize] => Some(b.vel[j as usize]),
                        Some(_) => None,
                    };
                    if let (Some(u), true) = (ready, len < MAX_SUPPORTS) {
                        planes[len] = (s.normal, u);
                        len += 1;
                    }
                }
                if len == 0 {
                    continue;
                }
                self.support_done[body] = true;
                progress = true;
                b.vel[body] = held_velocity(b.vel[body], &planes[..len], up, resting, friction);
            }
            if !progress {
                break;
            }
        }
    }
}

/// The velocity of a body resting on `planes` (normal out of the support, support velocity):
/// its approach into each is removed, and friction takes tangential speed relative to the
/// most upright support, up to `friction` times the normal speed removed. A body approaching
/// any support faster than `resting` is left alone: that is an impact, not rest.
fn held_velocity(v0: DVec3, planes: &[(DVec3, DVec3)], up: DVec3, resting: f64, friction: f64) -> DVec3 {
    let approach = planes.iter().map(|(n, u)| -(v0 - *u).dot(*n)).fold(0.0, f64::max);
    if approach <= 0.0 || approach > resting {
        return v0;
    }
    let mut v = v0;
    let mut removed = 0.0;
    for _ in 0..SUPPORT_ITERATIONS {
        for (n, u) in planes {
            let vn = (v - *u).dot(*n);
            if vn < 0.0 {
                v -= *n * vn;
                removed -= vn;
            }
        }
    }
    if friction > 0.0 {
        let (n, u) =
            planes.iter().copied().fold(planes[0], |best, p| if p.0.dot(up) > best.0.dot(up) { p } else { best });
        let rel = v - u;
        let along = n * rel.dot(n);
        let tangent = rel - along;
        let speed = tangent.length();
        let cap = friction * removed;
        v = if speed <= cap { u + along } else { v - tangent * (cap / speed) };
    }
    v
}
