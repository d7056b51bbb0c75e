//! Stage 5, narrowphase and time of impact: for every candidate pair, the first contact over
//! the step (the analytic swept sphere for two spheres, conservative advancement then sampling
//! and bisection for the rest) and the contact at the end of the step on the current paths.

use super::{Cand, Found, Impact, Partner, Queued, StageStats, Stepper};
use crate::geometry::Shape;
use crate::narrow::{self, Contact};
use crate::par::MIN_PIECE_HEAVY;
use crate::sim::world::{Rule, World};
use crate::toi::analytic::{swept_sphere, SweptSphere};
use crate::toi::bisect::first_contact;
use glam::DVec3;

/// Most conservative-advancement steps for one fast pair before sampling takes over.
const CA_MAX_STEPS: u32 = 16;

impl Stepper {
    /// Time of impact and end-of-step contact for every candidate; impacts are queued.
    pub(super) fn narrowphase(&mut self, w: &World, stats: &mut StageStats) {
        // 4. Narrowphase and time of impact for every candidate, and whether it touches at the
        //    end of the step on its current path (reused for events if nothing changes it).
        //    Triggers change no path, so they wait outside the heap and are settled after it.
        stats.pairs_tested = self.candidates.len() as u32;
        stats.toi_tests = 0;
        self.heap.clear();
        self.impacts.clear();
        self.triggers.clear();
        // Each pair's answer depends on the world as the stage found it only: a map over the
        // candidates, cut over the pool; the impacts are then queued in candidate order.
        let mut found = std::mem::take(&mut self.found);
        found.clear();
        let this = &*self;
        this.pool.map_into(this.candidates.len(), MIN_PIECE_HEAVY, &mut found, |k| {
            let Cand { a, b: p, .. } = this.candidates[k];
            let mut tests = 0;
            let (imp, end) = match this.sphere_pair(w, a, p) {
                Some(fast) => fast,
                None => (this.impact(w, a, p, 0.0, &mut tests), this.end_contact(w, a, p)),
            };
            Found { imp, end, tests }
        });
        for f in &found {
            stats.toi_tests += f.tests;
            if let Some(imp) = f.imp {
                self.schedule(w, imp);
            }
        }
        self.found = found;
    }

    pub(super) fn is_trigger(&self, w: &World, imp: &Impact) -> bool {
        let (ca, cb) = self.class_pair(w, imp.a, imp.b);
        matches!(w.config.classes.rule(ca, cb), Rule::Trigger | Rule::Ignore)
    }

    /// Contact at the end of the step on the current paths, within the slop.
    pub(super) fn end_contact(&self, w: &World, a: u32, p: Partner) -> Option<Contact> {
        let pa = self.pos_at(w, a as usize, 1.0);
        let (pb, _) = self.partner_at(w, p, 1.0);
        self.contact(w, a as usize, pa, p, pb, w.config.contact_slop_m)
    }

    /// The fast path for two spheres at the start of a tick (the bulk of most scenes): start
    /// overlap, the analytic time of impact and the end-of-step contact from one relative
    /// position and displacement. `None` when the pair is not two spheres (or the plan says
    /// no).
    #[inline]
    pub(super) fn sphere_pair(&self, w: &World, a: u32, p: Partner) -> Option<(Option<Impact>, Option<Contact>)> {
        if !self.plan.analytic_spheres {
            return None;
        }
        let b = &w.bodies;
        let i = a as usize;
        let Shape::Sphere { radius: r1 } = b.shape[i] else { return None };
        let (r2, pb, vb, ver_b) = match p {
            Partner::Body(j) => match b.shape[j as usize] {
                Shape::Sphere { radius } => (radius, b.pos[j as usize], b.vel[j as usize], 0),
                _ => return None,
            },
            Partner::Static(s) => match w.statics.shape[s as usize] {
                Shape::Sphere { radius } => (radius, w.statics.pos[s as usize], DVec3::ZERO, 0),
                _ => return None,
            },
            Partner::Terrain => return None,
        };
        let r = r1 + r2;
        let d0 = pb - b.pos[i];
        let rel = (vb - b.vel[i]) * w.config.dt;
        let d1 = d0 + rel;
        let slop = w.config.contact_slop_m;
        let end = if d1.length_squared() < (r + slop) * (r + slop) {
            narrow::sphere_sphere::contact(r1, r2, d1)
        } else {
            None
        };
        let mk = |t: f64, contact: Contact, started_inside: bool| Impact {
            t,
            a,
            b: p,
            ver_a: 0,
            ver_b,
            contact,
            started_inside,
        };
        let imp = if d0.length_squared() < r * r {
            narrow::sphere_sphere::contact(r1, r2, d0).map(|c| mk(0.0, c, true))
        } else {
            match swept_sphere(-d0, -rel, r) {
                SweptSphere::Hit(s) => narrow::sphere_sphere::contact(r1, r2, d0 + rel * s)
                    .map(|c| mk(s, Contact { depth: c.depth.max(0.0), ..c }, false)),
                _ => None,
            }
        };
        Some((imp, end))
    }

    /// The first contact of body `a` with `p` in `[from, 1]`, if any.
    pub(super) fn impact(&self, w: &World, a: u32, p: Partner, from: f64, tests: &mut u32) -> Option<Impact> {
        let i = a as usize;
        let b = &w.bodies;
        let dt = w.config.dt;
        let pa = self.pos_at(w, i, from);
        let (pb, vb) = self.partner_at(w, p, from);
        let va = b.vel[i];
        let ver_a = self.version[i];
        let ver_b = match p {
            Partner::Body(j) => self.version[j as usize],
            _ => 0,
        };
        let mk = |t: f64, contact: Contact, started_inside: bool| Impact {
            t,
            a,
            b: p,
            ver_a,
            ver_b,
            contact,
            started_inside,
        };
        // Already overlapping at the start of the interval: depth and normal now.
        if let Some(c) = self.contact(w, i, pa, p, pb, 0.0).filter(|c| c.depth > 0.0) {
            return Some(mk(from, c, true));
        }
        let span = 1.0 - from;
        let rel = (vb - va) * (dt * span); // b's displacement relative to a over [from, 1]
        if rel == DVec3::ZERO {
            return None;
        }
        let d0 = pb - pa;
        // Spheres: the exact swept-sphere time of impact.
        if let (Partner::Body(_) | Partner::Static(_), true) = (p, self.plan.analytic_spheres) {
            let sb = match p {
                Partner::Body(j) => &b.shape[j as usize],
                Partner::Static(s) => &w.statics.shape[s as usize],
                Partner::Terrain => unreachable!(),
            };
            if let (Shape::Sphere { radius: r1 }, Shape::Sphere { radius: r2 }) = (&b.shape[i], sb) {
                // DESIGN.md's A = P1 - Q1 and B = (P2 - P1) - (Q2 - Q1), with P = a and Q = b.
                return match swept_sphere(-d0, -rel, r1 + r2) {
                    SweptSphere::Hit(s) => {
                        let d = d0 + rel * s;
                        let c = narrow::sphere_sphere::contact(*r1, *r2, d)?;
                        Some(mk(from + span * s, Contact { depth: c.depth.max(0.0), ..c }, false))
                    }
                    _ => None,
                };
            }
        }
        // Overlap testing with bisection; fast pairs are sampled so they cannot tunnel.
        let travel = rel.length();
        let extent_b = match p {
            Partner::Body(j) => b.shape[j as usize].min_extent(),
            Partner::Static(s) => w.statics.shape[s as usize].min_extent(),
            Partner::Terrain => 0.0,
        };
        let step_m = if self.plan.ccd_sampling { 0.5 * (b.shape[i].min_extent() + extent_b) } else { f64::INFINITY };
        let overlaps = |t: f64| {
            let qa = pa + va * ((t - from) * dt);
            let qb = pb + vb * ((t - from) * dt);
            self.contact(w, i, qa, p, qb, 0.0).is_some_and(|c| c.depth > 0.0)
        };
        // A fast convex pair first advances conservatively: the gap between two convex shapes
        // closes no faster than their relative speed, so stepping by gap / speed can never pass
        // the first contact. It brings a bullet to its wall in one or two exact distance queries
        // instead of hundreds of overlap samples; sampling and bisection finish from there.
        let mut start = from;
        let convex = match p {
            Partner::Body(_) => true,
            Partner::Static(s) => w.statics.shape[s as usize].is_convex(),
            Partner::Terrain => false,
        };
        if travel > step_m && convex {
            let per_t = travel / span; // relative distance per unit of step fraction
            for _ in 0..CA_MAX_STEPS {
                *tests += 1;
                let qa = pa + va * ((start - from) * dt);
                let qb = pb + vb * ((start - from) * dt);
                let Some(c) = self.contact(w, i, qa, p, qb, f64::INFINITY) else { break };
                let gap = -c.depth;
                if gap <= 0.5 * step_m {
                    break;
                }
                // 0.999: parry's GJK distance is approximate; never step on its last digits.
                start += 0.999 * gap / per_t;
                if start >= 1.0 {
                    return None;
                }
            }
        }
        let remaining = travel * (1.0 - start) / span;
        let bracket = first_contact(start, remaining, step_m, &w.config.bisect, overlaps)?;
        *tests += bracket.tests;
        // Report the pose just before contact (lo); the normal and point come from the first
        // overlapping pose (hi), where the contact is defined.
        let qa = pa + va * ((bracket.hi - from) * dt);
        let qb = pb + vb * ((bracket.hi - from) * dt);
        let c = self.contact(w, i, qa, p, qb, 0.0)?;
        let shift = va * ((bracket.hi - bracket.lo) * dt);
        Some(mk(bracket.lo, Contact { point: c.point + shift, depth: 0.0, ..c }, false))
    }

    /// Queues an impact: triggers aside (they change no path), the rest on the heap.
    pub(super) fn schedule(&mut self, w: &World, imp: Impact) {
        if self.is_trigger(w, &imp) {
            self.triggers.push(imp);
        } else {
            let index = self.impacts.len() as u32;
            self.heap.push(Queued { t: imp.t, a: imp.a, b: imp.b, ver_a: imp.ver_a, ver_b: imp.ver_b, index });
            self.impacts.push(imp);
        }
    }
}
