//! Stage 4, broadphase: the pairs that may touch during the step, from swept bounds, and the
//! static geometry and terrain each moving body can reach; bodies whose paths change mid-step
//! are queried again.

use super::{Cand, Partner, Stepper};
use crate::geometry::Aabb;
use crate::par::MIN_PIECE;
use crate::sim::world::{Rule, World};

impl Stepper {
    /// The tick's candidate pairs: dynamic pairs from the swept bounds (two bodies at rest are
    /// never a pair), then the static geometry and terrain each moving body can reach. A
    /// sleeping body that a moving body's swept box reaches wakes with its island; it is tested
    /// this tick where it lies, like static geometry, and integrated from the next.
    pub(super) fn find_candidates(&mut self, w: &mut World) {
        self.candidates.clear();
        if !self.moving.contains(&true) {
            // Awake but all at rest (held by their supports): no pair can change.
            self.pairs.clear();
            return;
        }
        self.dynamic_pairs(w);
        let cfg = &w.config;
        let b = &w.bodies;
        let n = b.len();
        // A map and a filter over the pairs, then over the moving bodies: cut over the pool.
        let (pairs, moving) = (&self.pairs, &self.moving);
        self.pool.extend(pairs.len(), MIN_PIECE, &mut self.candidates, |range, out| {
            for &(i, j) in &pairs[range] {
                if !moving[i as usize] && !moving[j as usize] {
                    continue; // both resting: nothing can change between them
                }
                if cfg.classes.rule(b.class[i as usize], b.class[j as usize]) == Rule::Ignore {
                    continue;
                }
                out.push(Cand::new(i, Partner::Body(j)));
            }
        });
        self.wake_seeds.clear();
        if b.asleep.contains(&true) {
            // A sleeper wakes when a body faster than the sleep speed may reach it. One slower
            // than that counts as still: it meets the sleeper as it would static geometry (the
            // contact solver holds it, an impact gives the sleeper a velocity and so wakes it
            // next tick), so a resting body beside a sleeping island does not wake it every
            // tick and keep both from ever sleeping.
            let still2 = cfg.sleep_speed_mps * cfg.sleep_speed_mps;
            let stirs = |k: u32| !b.asleep[k as usize] && b.vel[k as usize].length_squared() > still2;
            for c in &self.candidates {
                let Partner::Body(j) = c.b else { continue };
                if b.asleep[c.a as usize] && stirs(j) {
                    self.wake_seeds.push(c.a);
                } else if b.asleep[j as usize] && stirs(c.a) {
                    self.wake_seeds.push(j);
                }
            }
        }
        if self.plan.statics || self.plan.terrain {
            let mut found = std::mem::take(&mut self.static_cands);
            found.clear();
            let this = &*self;
            this.pool.extend(n, MIN_PIECE, &mut found, |range, out| {
                let (mut statics, mut partners) = (Vec::new(), Vec::new());
                for i in range {
                    if this.moving[i] {
                        this.static_partners(w, i as u32, this.aabbs[i], &mut statics, &mut partners);
                        out.extend(partners.iter().map(|&p| Cand::new(i as u32, p)));
                    }
                }
            });
            self.candidates.append(&mut found);
            self.static_cands = found;
        }
        if !self.wake_seeds.is_empty() {
            self.islands.wake(w, &self.wake_seeds);
        }
    }

    /// Every pair of dynamic bodies whose swept boxes overlap, sorted, into `pairs`.
    ///
    /// Sleeping bodies (that nothing set moving this tick) do not move, so they stay out of the
    /// broadphase method: they sit in `sleepers`, a grid rebuilt only when a body falls asleep
    /// or wakes, and each moving body looks itself up there. Pairs of
    /// two sleepers, or of a sleeper and a body at rest, could not change anyway. The pairs are
    /// the same, in the same order, as from one broadphase over every body.
    fn dynamic_pairs(&mut self, w: &World) {
        let b = &w.bodies;
        let n = b.len();
        let resting_sleeper = |i: usize| b.asleep[i] && !self.moving[i];
        self.split = (0..n).any(resting_sleeper);
        if !self.split {
            self.broadphase.pairs(&self.aabbs, &mut self.pairs, &self.pool);
            return;
        }
        self.bp_slots.clear();
        self.bp_boxes.clear();
        self.sleeper_scratch.clear();
        for i in 0..n {
            if resting_sleeper(i) {
                self.sleeper_scratch.push((self.aabbs[i], i as u32));
            } else {
                self.bp_slots.push(i as u32);
                self.bp_boxes.push(self.aabbs[i]);
            }
        }
        // The index answers for exactly these boxes: rebuilt whenever they differ (a body fell
        // asleep or woke, or a rollback restored other sleepers), so it never holds a result.
        if self.sleeper_scratch != self.sleeper_boxes {
            std::mem::swap(&mut self.sleeper_scratch, &mut self.sleeper_boxes);
            self.sleeper_only.clear();
            self.sleeper_only.extend(self.sleeper_boxes.iter().map(|(b, _)| *b));
            self.sleepers.index(&self.sleeper_only);
        }
        self.broadphase.pairs(&self.bp_boxes, &mut self.pairs, &self.pool);
        // Local indices to slots: `bp_slots` ascends, so the pairs stay `(lo, hi)` and sorted.
        for p in &mut self.pairs {
            *p = (self.bp_slots[p.0 as usize], self.bp_slots[p.1 as usize]);
        }
        let before = self.pairs.len();
        let mut buf = std::mem::take(&mut self.query_buf);
        for (k, &i) in self.bp_slots.iter().enumerate() {
            if self.moving[i as usize] {
                buf.clear();
                self.query_sleepers(&self.bp_boxes[k], &mut buf);
                self.pairs.extend(buf.iter().map(|&s| (i.min(s), i.max(s))));
            }
        }
        self.query_buf = buf;
        if self.pairs.len() > before {
            self.pairs.sort_unstable();
        }
    }

    /// Every dynamic body whose box, as given to the broadphase this tick, overlaps `q`, ascending
    /// by slot (sleepers included).
    pub(super) fn query_bodies(&self, q: &Aabb, out: &mut Vec<u32>) {
        if !self.split {
            self.broadphase.query(&self.aabbs, q, out);
            return;
        }
        self.broadphase.query(&self.bp_boxes, q, out);
        for x in out.iter_mut() {
            *x = self.bp_slots[*x as usize];
        }
        let before = out.len();
        self.query_sleepers(q, out);
        if out.len() > before {
            out.sort_unstable();
        }
    }

    /// Appends the slot of every sleeper in the index whose box overlaps `q`.
    fn query_sleepers(&self, q: &Aabb, out: &mut Vec<u32>) {
        let before = out.len();
        self.sleepers.query(&self.sleeper_only, q, out);
        for k in &mut out[before..] {
            *k = self.sleeper_boxes[*k as usize].1;
        }
    }

    /// The static bodies and terrain body `i` can meet within `aabb`, into `partners` (cleared;
    /// `statics` is scratch).
    pub(super) fn static_partners(
        &self,
        w: &World,
        i: u32,
        aabb: Aabb,
        statics: &mut Vec<u32>,
        partners: &mut Vec<Partner>,
    ) {
        let b = &w.bodies;
        partners.clear();
        if self.plan.statics {
            w.statics.index.query(&aabb, statics);
            for &s in statics.iter() {
                if w.config.classes.rule(b.class[i as usize], w.statics.class[s as usize]) != Rule::Ignore {
                    partners.push(Partner::Static(s));
                }
            }
        }
        if let Some(t) = &w.statics.terrain {
            if t.field.aabb().overlaps(&aabb) && w.config.classes.rule(b.class[i as usize], t.class) != Rule::Ignore {
                partners.push(Partner::Terrain);
            }
        }
    }

    /// [`Stepper::static_partners`] into the stepper's own buffer, `partner_buf`.
    pub(super) fn static_partners_buf(&mut self, w: &World, i: u32, aabb: Aabb) {
        let (mut statics, mut partners) = (std::mem::take(&mut self.static_buf), std::mem::take(&mut self.partner_buf));
        self.static_partners(w, i, aabb, &mut statics, &mut partners);
        self.static_buf = statics;
        self.partner_buf = partners;
    }

    /// Adds a pair found mid-step to `candidates`. A pair found again is listed again, on
    /// purpose: the settle passes walk this list, and the repeats (pairs around bodies that were
    /// pushed or re-routed) give the busiest contacts more Gauss-Seidel iterations. Removing them
    /// made a 1,000-ball pile 1.5x faster but left 1.6 % of a radius of penetration instead of
    /// 0.02 %, and four times the passes did not recover it (0.43 %).
    pub(super) fn add_candidate(&mut self, a: u32, b: Partner) {
        self.candidates.push(Cand::new(a, b));
    }

    /// A body's path changed mid-step: test its new path against everything it can reach.
    pub(super) fn requery(&mut self, w: &World, body: u32, tests: &mut u32) {
        let i = body as usize;
        if self.dead[i] {
            return;
        }
        let b = &w.bodies;
        let t = self.t0[i];
        let p_now = self.base[i];
        let p_end = self.pos_at(w, i, 1.0);
        let a0 = b.shape[i].world_aabb(p_now, b.rot[i]);
        let swept = a0.union(&a0.translated(p_end - p_now)).inflated(w.config.contact_slop_m);
        // Other dynamic bodies: their full-step boxes still bound them unless they changed too,
        // in which case they were (or will be) re-queried themselves.
        let mut buf = std::mem::take(&mut self.query_buf);
        self.query_bodies(&swept, &mut buf);
        for &j in &buf {
            if j == body || self.dead[j as usize] {
                continue;
            }
            if w.config.classes.rule(b.class[i], b.class[j as usize]) == Rule::Ignore {
                continue;
            }
            let (lo, hi) = (body.min(j), body.max(j));
            let from = t.max(self.t0[j as usize]);
            if let Some(imp) = self.impact(w, lo, Partner::Body(hi), from, tests) {
                self.schedule(w, imp);
            }
        }
        self.query_buf = buf;
        self.aabbs[i] = self.aabbs[i].union(&swept);
        if self.plan.statics || self.plan.terrain {
            self.static_partners_buf(w, body, swept);
            for k in 0..self.partner_buf.len() {
                let p = self.partner_buf[k];
                if let Some(imp) = self.impact(w, body, p, t, tests) {
                    self.schedule(w, imp);
                }
                self.add_candidate(body, p);
            }
        }
        // Make sure the pair list used for end-of-tick touching includes new partners.
        for k in 0..self.query_buf.len() {
            let j = self.query_buf[k];
            if j != body && !self.dead[j as usize] {
                self.add_candidate(body.min(j), Partner::Body(body.max(j)));
            }
        }
    }
}
