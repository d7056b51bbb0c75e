//! Stage 7, settle: what time-of-impact resolution left overlapping in piles and stacks.

use super::{Cand, Partner, Stepper};
use crate::par::MIN_PIECE;
use crate::sim::world::World;
use glam::DVec3;

/// Gauss-Seidel passes of the end-of-tick settle.
const SETTLE_PASSES: u32 = 16;

impl Stepper {
    /// Whether a settle pass may push candidate `k`'s pair apart: both alive, and a rule that
    /// stops them.
    fn pushable_pair(&self, w: &World, k: usize) -> bool {
        let Cand { a, b: p } = self.candidates[k];
        let alive = !self.dead[a as usize] && !matches!(p, Partner::Body(j) if self.dead[j as usize]);
        let (ca, cb) = self.class_pair(w, a, p);
        alive && w.config.classes.rule(ca, cb).stops()
    }

    /// A body a pass pushed out of one contact may have been pushed into something that was not
    /// a partner this tick: gives each the partners its new position reaches.
    fn partners_of_pushed(&mut self, w: &World, slop: f64) {
        let mut pushed = std::mem::take(&mut self.settled);
        pushed.sort_unstable();
        pushed.dedup();
        for &body in &pushed {
            let i = body as usize;
            let here = w.bodies.shape[i].world_aabb(w.bodies.pos[i], w.bodies.rot[i]).inflated(slop);
            let mut buf = std::mem::take(&mut self.query_buf);
            self.query_bodies(&here, &mut buf);
            for &j in &buf {
                if j != body && !self.dead[j as usize] {
                    self.add_candidate(body.min(j), Partner::Body(body.max(j)));
                }
            }
            self.query_buf = buf;
            if self.plan.statics || self.plan.terrain {
                self.static_partners_buf(w, body, here);
                for k in 0..self.partner_buf.len() {
                    self.add_candidate(body, self.partner_buf[k]);
                }
                self.aabbs[i] = self.aabbs[i].union(&here);
            }
        }
        pushed.clear();
        self.settled = pushed;
    }

    /// Moves every body to the end of its path, then settles what the time-of-impact resolution
    /// left overlapping: a few Gauss-Seidel passes over the tick's pairs push apart any pair deeper than the contact slop (back to half the
    /// slop, in proportion to the inverse masses) and remove its approaching normal velocity
    /// (inelastic). Impacts are resolved exactly, in time order, before this; what remains is
    /// resting contact in piles and stacks, which sequential impacts alone cannot hold (each push
    /// drives a body into its other neighbours). Bounded: `SETTLE_PASSES` passes.
    pub(super) fn settle(&mut self, w: &mut World) {
        // Every body to the end of its path.
        let dt = w.config.dt;
        let (base, t0, vel) = (&self.base, &self.t0, &w.bodies.vel);
        self.pool.for_each_mut(&mut w.bodies.pos, MIN_PIECE, |first, pos| {
            for (k, p) in pos.iter_mut().enumerate() {
                let i = first + k;
                *p = base[i] + vel[i] * ((1.0 - t0[i]) * dt);
            }
        });
        if !w.config.classes.any_stopping() {
            // No rule pushes anything (a world of triggers): no pair is pushable, and no pass
            // would move a body or find a new pair.
            self.pushable.clear();
            return;
        }
        let slop = w.config.contact_slop_m;
        // The pairs a pass can push: alive, and with a rule that stops them. Neither changes
        // during the passes, so each candidate is asked once (a filter, cut over the pool), and
        // the passes walk these in candidate order, as they would walk every candidate.
        let mut pushable = std::mem::take(&mut self.pushable);
        pushable.clear();
        let this = &*self;
        this.pool.extend(this.candidates.len(), MIN_PIECE, &mut pushable, |range, out| {
            out.extend(range.filter(|&k| this.pushable_pair(w, k)).map(|k| k as u32));
        });
        let mut asked = self.candidates.len();
        // A check that needed no push stays true until one of the pair is pushed: each push
        // takes the next sequence number, and a pair whose bodies were last pushed before its
        // last such check is skipped. The passes do exactly what they would with every pair
        // checked every pass, without the checks that could only find nothing to do (in a
        // landing pile, 98 % of them).
        let mut last_push = std::mem::take(&mut self.last_push);
        last_push.clear();
        last_push.resize(w.bodies.len(), 0);
        let mut checked_at = std::mem::take(&mut self.checked_at);
        checked_at.clear();
        let mut seq: u64 = 1;
        for _ in 0..SETTLE_PASSES {
            let mut moved = false;
            // Pairs found by the last pass join this one (a pass never walks what it adds).
            for k in asked..self.candidates.len() {
                if self.pushable_pair(w, k) {
                    pushable.push(k as u32);
                }
            }
            asked = self.candidates.len();
            checked_at.resize(pushable.len(), 0);
            for (entry, &k) in pushable.iter().enumerate() {
                let k = k as usize;
                let Cand { a, b: p } = self.candidates[k];
                let i = a as usize;
                let at = checked_at[entry];
                let pushed_since =
                    at == 0 || last_push[i] >= at || matches!(p, Partner::Body(j) if last_push[j as usize] >= at);
                if !pushed_since {
                    continue;
                }
                // Until one of the pair is pushed, what follows finds nothing to do.
                checked_at[entry] = seq + 1;
                // A pair neither of whose paths changed keeps the end contact found with its time
                // of impact (same positions, same kernel): clear of the slop there, nothing to do.
                if let Some(end) = self.end_if_unchanged(k) {
                    if end.is_none_or(|c| c.depth <= slop) {
                        continue;
                    }
                }
                let pa = w.bodies.pos[i];
                let (pb, inv_mb) = match p {
                    Partner::Body(j) => (w.bodies.pos[j as usize], w.bodies.inv_mass[j as usize]),
                    Partner::Static(s) => (w.statics.pos[s as usize], 0.0),
                    Partner::Terrain => (DVec3::ZERO, 0.0),
                };
                let Some(c) = self.contact(w, i, pa, p, pb, 0.0) else { continue };
                if c.depth <= slop {
                    continue;
                }
                let inv_ma = w.bodies.inv_mass[i];
                let inv_sum = inv_ma + inv_mb;
                if inv_sum == 0.0 {
                    continue;
                }
                let push = c.normal * (c.depth - 0.5 * slop);
                w.bodies.pos[i] -= push * (inv_ma / inv_sum);
                let vb = match p {
                    Partner::Body(j) => {
                        w.bodies.pos[j as usize] += push * (inv_mb / inv_sum);
                        w.bodies.vel[j as usize]
                    }
                    _ => DVec3::ZERO,
                };
                let closing = -(vb - w.bodies.vel[i]).dot(c.normal);
                if closing > 0.0 {
                    let jn = closing / inv_sum;
                    w.bodies.vel[i] -= c.normal * (jn * inv_ma);
                    if let Partner::Body(j) = p {
                        w.bodies.vel[j as usize] += c.normal * (jn * inv_mb);
                    }
                }
                seq += 1;
                last_push[i] = seq;
                if let Partner::Body(j) = p {
                    last_push[j as usize] = seq;
                }
                // Their end-of-tick contacts must be recomputed for events.
                self.version[i] += 1;
                self.settled.push(a);
                if let Partner::Body(j) = p {
                    self.version[j as usize] += 1;
                    self.settled.push(j);
                }
                moved = true;
            }
            if !moved {
                break;
            }
            self.partners_of_pushed(w, slop);
        }
        self.pushable = pushable;
        self.last_push = last_push;
        self.checked_at = checked_at;
    }
}
