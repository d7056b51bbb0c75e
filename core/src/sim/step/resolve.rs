//! Stage 6, resolution: impacts in time-of-impact order, each moving its pair to the contact
//! and answering by the rule for their classes (bounce, slide, stop, destroy, trigger); a body
//! whose path changes is searched again against everything its new path can reach.

use super::{response_of, Impact, PairRecord, Partner, StageStats, Stepper};
use crate::par::MIN_PIECE_HEAVY;
use crate::sim::world::{ClassId, Rule, World};
use glam::DVec3;
use impact_protocol::EntityId;

/// Extra fraction of the normal velocity removed by slide and inelastic contacts.
const SLIDE_OVERCLIP: f64 = 1.0e-3;

/// Most resolutions one body may take part in per tick before its motion for the rest of the
/// tick is frozen where it stands (never inside anything). Bounds pathological piles.
const MAX_RESOLUTIONS_PER_BODY: u32 = 16;

impl Stepper {
    /// Pops impacts in time-of-impact order and resolves those still current; then records the
    /// triggers.
    pub(super) fn resolve_impacts(&mut self, w: &mut World, stats: &mut StageStats) {
        let cfg = w.config.clone();
        // 5. Resolve in time-of-impact order; a body whose path changes is re-tested against
        //    everything its new path can reach.
        self.records.clear();
        let mut resolutions = 0u32;
        while let Some(q) = self.heap.pop() {
            let imp = self.impacts[q.index as usize];
            let i = imp.a as usize;
            if self.dead[i] || matches!(imp.b, Partner::Body(j) if self.dead[j as usize]) {
                continue;
            }
            if !self.is_current(&imp) {
                // A path changed since this was computed: test again from the later change.
                if let Some(again) = self.impact(w, imp.a, imp.b, self.search_from(&imp), &mut stats.toi_tests) {
                    self.schedule(w, again);
                }
                continue;
            }
            if imp.started_inside && imp.contact.depth <= cfg.contact_slop_m {
                // Touching within the slop and already moving apart: nothing to resolve. Nor
                // when it closes no faster than a resting contact (no rebound would follow) and
                // cannot sink past the slop by the end of the tick: that is a body lying on
                // another, held by the resting-contact solver; resolving the rounding left of
                // its approach would only set off micro-impacts through a pile.
                let closing = closing_speed(w, &imp);
                let sink = imp.contact.depth + closing * (1.0 - imp.t) * cfg.dt;
                if closing <= 0.0 || (closing <= cfg.bounce_threshold_mps && sink <= cfg.contact_slop_m) {
                    continue;
                }
            }
            if !imp.started_inside && closing_speed(w, &imp) * (1.0 - imp.t) * cfg.dt <= 0.5 * cfg.contact_slop_m {
                // A resting contact: even unresolved, the pair cannot sink deeper than half the
                // slop by the end of the tick, and the next tick starts by pushing it apart.
                // Resolving it would only set off a chain of micro-impacts through a pile.
                continue;
            }
            if resolutions >= cfg.max_resolutions_per_tick {
                stats.resolution_cap_hits += 1;
                break;
            }
            resolutions += 1;
            self.count[i] += 1;
            if let Partner::Body(j) = imp.b {
                self.count[j as usize] += 1;
            }
            let over = |this: &Stepper, k: usize| this.count[k] > MAX_RESOLUTIONS_PER_BODY;
            if over(self, i) || matches!(imp.b, Partner::Body(j) if over(self, j as usize)) {
                for k in
                    [Some(i), if let Partner::Body(j) = imp.b { Some(j as usize) } else { None }].into_iter().flatten()
                {
                    if over(self, k) && self.t0[k] < 1.0 {
                        self.base[k] = self.pos_at(w, k, imp.t);
                        self.t0[k] = 1.0;
                        self.version[k] += 1;
                        stats.frozen += 1;
                    }
                }
                continue;
            }
            let changed = self.resolve(w, &imp);
            for body in changed.into_iter().flatten() {
                self.requery(w, body, &mut stats.toi_tests);
            }
        }
        // Triggers: record those whose bodies kept their paths; search again those that changed.
        // Recording changes no path, so this is a map over the triggers, cut over the pool.
        let triggers = std::mem::take(&mut self.triggers);
        let mut records = std::mem::take(&mut self.records);
        // The overlap tests spent searching again: an integer sum, the same in any order.
        let tests = std::sync::atomic::AtomicU32::new(0);
        let this = &*self;
        this.pool.extend(triggers.len(), MIN_PIECE_HEAVY, &mut records, |range, out| {
            for imp in &triggers[range] {
                if this.dead[imp.a as usize] || matches!(imp.b, Partner::Body(j) if this.dead[j as usize]) {
                    continue;
                }
                if this.is_current(imp) {
                    out.push(this.record(w, imp));
                } else {
                    let mut spent = 0;
                    let again = this.impact(w, imp.a, imp.b, this.search_from(imp), &mut spent);
                    tests.fetch_add(spent, std::sync::atomic::Ordering::Relaxed);
                    out.extend(again.map(|again| this.record(w, &again)));
                }
            }
        });
        stats.toi_tests += tests.into_inner();
        self.records = records;
        self.triggers = triggers;
        self.triggers.clear();
        stats.resolutions = resolutions;
    }

    /// The class, id and inverse mass of an impact's partner.
    fn partner_props(w: &World, p: Partner) -> (ClassId, EntityId, f64) {
        match p {
            Partner::Body(j) => (w.bodies.class[j as usize], w.bodies.id[j as usize], w.bodies.inv_mass[j as usize]),
            Partner::Static(s) => (w.statics.class[s as usize], w.statics.id[s as usize], 0.0),
            Partner::Terrain => {
                let t = w.statics.terrain.as_ref().expect("terrain partner implies terrain");
                (t.class, t.id, 0.0)
            }
        }
    }

    /// What events will tell of an impact: where, along which normal, how fast it closed and
    /// the response its classes' rule gives.
    pub(super) fn record(&self, w: &World, imp: &Impact) -> PairRecord {
        let i = imp.a as usize;
        let (class_b, id_b, _) = Self::partner_props(w, imp.b);
        let rule = w.config.classes.rule(w.bodies.class[i], class_b);
        let (_, vb) = self.partner_at(w, imp.b, imp.t);
        let n = imp.contact.normal;
        PairRecord {
            key: (w.bodies.id[i], id_b),
            slots: [imp.a, imp.b.slot()],
            t: imp.t,
            point: self.pos_at(w, i, imp.t) + imp.contact.point,
            normal_lo_hi: n,
            depth: imp.contact.depth,
            closing: -(vb - w.bodies.vel[i]).dot(n),
            response: response_of(rule),
        }
    }

    /// Applies the response for one impact. Returns the bodies whose paths changed.
    pub(super) fn resolve(&mut self, w: &mut World, imp: &Impact) -> [Option<u32>; 2] {
        // The settings are shared (`Arc`); hold them through a second handle only where a
        // body's path changes, not for every recorded trigger.
        let i = imp.a as usize;
        let t = imp.t;
        let (class_b, _, inv_mb) = Self::partner_props(w, imp.b);
        let rule = w.config.classes.rule(w.bodies.class[i], class_b);
        let pa = self.pos_at(w, i, t);
        let (pb, vb) = self.partner_at(w, imp.b, t);
        let va = w.bodies.vel[i];
        let n = imp.contact.normal;
        let closing = -(vb - va).dot(n);
        let inv_ma = w.bodies.inv_mass[i];
        let record = self.record(w, imp);
        self.records.push(record);
        let mut changed = [None, None];
        if matches!(rule, Rule::Ignore | Rule::Trigger) {
            return changed;
        }
        let cfg = w.config.clone();
        let j = match imp.b {
            Partner::Body(j) => Some(j as usize),
            _ => None,
        };
        let mut set_path =
            |this: &mut Stepper, w: &mut World, body: usize, new_pos: DVec3, new_vel: DVec3, slot: usize| {
                // A change too small to move the body by half the slop over the rest of the tick
                // does not need its new path searched again.
                let shift = (new_pos - this.pos_at(w, body, t)).length()
                    + (new_vel - w.bodies.vel[body]).length() * (1.0 - t) * w.config.dt;
                this.base[body] = new_pos;
                this.t0[body] = t;
                w.bodies.vel[body] = new_vel;
                this.version[body] += 1;
                this.moving[body] = true;
                if shift > 0.5 * w.config.contact_slop_m {
                    changed[slot] = Some(body as u32);
                }
            };
        match rule {
            Rule::Ignore | Rule::Trigger => {}
            Rule::Destroy { first, second, restitution } => {
                if first {
                    self.dead[i] = true;
                    self.version[i] += 1;
                }
                if let (true, Some(j)) = (second, j) {
                    self.dead[j] = true;
                    self.version[j] += 1;
                }
                // The survivor bounces off the destroyed body as off a wall, if asked to.
                if let (Some(e), true) = (restitution, closing > 0.0) {
                    if !first && inv_ma > 0.0 {
                        set_path(self, w, i, pa, va - n * ((1.0 + e) * va.dot(n).max(0.0)), 0);
                    } else if let (false, Some(j)) = (second, j) {
                        if inv_mb > 0.0 {
                            set_path(self, w, j, pb, vb - n * ((1.0 + e) * vb.dot(n).min(0.0)), 1);
                        }
                    }
                }
            }
            Rule::Bounce { .. } | Rule::Slide | Rule::Stop => {
                let inv_sum = inv_ma + inv_mb;
                if inv_sum == 0.0 {
                    return changed; // two immovable bodies
                }
                // Push apart what overlaps deeper than the slop, in proportion to the inverse
                // masses, back to half the slop: a pile then rests within the slop instead of
                // each push driving a body into its other neighbours (and with a tiny slop this
                // is a hair short of exact separation, which rounding could not keep anyway).
                let excess = imp.contact.depth - 0.5 * cfg.contact_slop_m;
                let push =
                    if imp.started_inside && imp.contact.depth > cfg.contact_slop_m { n * excess } else { DVec3::ZERO };
                let new_pa = pa - push * (inv_ma / inv_sum);
                let new_pb = pb + push * (inv_mb / inv_sum);
                let (mut new_va, mut new_vb) = (va, vb);
                if closing > 0.0 {
                    match rule {
                        Rule::Bounce { restitution } => {
                            // Impulse along n: dv = -(1 + e) (v.n) n, shared by inverse mass.
                            // Below the bounce threshold the contact is resting: no rebound, so a
                            // body on the ground under gravity settles instead of hopping.
                            let e = if closing > cfg.bounce_threshold_mps { restitution } else { 0.0 };
                            // Only a resting (e = 0) contact is overclipped; an elastic bounce must
                            // conserve energy exactly.
                            let over = if e == 0.0 { 1.0 + SLIDE_OVERCLIP } else { 1.0 };
                            let jn = (1.0 + e) * closing * over / inv_sum;
                            new_va = va - n * (jn * inv_ma);
                            new_vb = vb + n * (jn * inv_mb);
                            // Coulomb friction at the impact: a tangential impulse against the
                            // slip, at most friction times the normal one (what stops a body
                            // landing on a slope or on another body from skidding off it).
                            if cfg.friction > 0.0 {
                                let rel = new_va - new_vb;
                                let slip = rel - n * rel.dot(n);
                                let speed = slip.length();
                                if speed > 0.0 {
                                    let jt = (speed / inv_sum).min(cfg.friction * jn);
                                    let dir = slip / speed;
                                    new_va -= dir * (jt * inv_ma);
                                    new_vb += dir * (jt * inv_mb);
                                }
                            }
                            if e == 0.0 && inv_mb == 0.0 {
                                // A resting contact with static geometry slides like a player: in
                                // a crease (a valley of the terrain) it keeps to the crease.
                                new_va = self.clip_slide(i, -n, new_va);
                            }
                        }
                        Rule::Slide => {
                            // Remove the approaching normal velocity and a hair more (as Quake's
                            // overclip does), so rounding cannot leave the body creeping into the
                            // wall and re-resolving the same contact.
                            let jn = closing * (1.0 + SLIDE_OVERCLIP) / inv_sum;
                            new_va = va - n * (jn * inv_ma);
                            new_vb = vb + n * (jn * inv_mb);
                            if inv_mb == 0.0 {
                                new_va = self.clip_slide(i, -n, new_va);
                            }
                        }
                        Rule::Stop => {
                            if inv_ma > 0.0 {
                                new_va = DVec3::ZERO;
                            }
                            if inv_mb > 0.0 {
                                new_vb = DVec3::ZERO;
                            }
                        }
                        _ => {}
                    }
                }
                if inv_ma > 0.0 {
                    set_path(self, w, i, new_pa, new_va, 0);
                }
                if let (Some(j), true) = (j, inv_mb > 0.0) {
                    set_path(self, w, j, new_pb, new_vb, 1);
                }
            }
        }
        changed
    }

    /// Slides body `i` along every wall plane it touched this tick (up to three): its velocity
    /// keeps no component into any of them. Two planes leave motion along their crease; three
    /// stop it. `wall_normal` points out of the wall, towards the body.
    pub(super) fn clip_slide(&mut self, i: usize, wall_normal: DVec3, v: DVec3) -> DVec3 {
        let len = self.clip_len[i] as usize;
        if len < 3 {
            self.clip[i][len] = wall_normal;
            self.clip_len[i] += 1;
        }
        let planes = &self.clip[i][..self.clip_len[i] as usize];
        let mut out = v;
        for (k, n) in planes.iter().enumerate() {
            let vn = out.dot(*n);
            if vn < 0.0 {
                out -= *n * vn;
                // Clipping against this plane may push back into an earlier one: then only the
                // crease between them is free.
                for m in planes.iter().take(k) {
                    if out.dot(*m) < -1e-12 {
                        let crease = n.cross(*m).normalize_or_zero();
                        out = crease * crease.dot(v);
                        if planes.len() >= 3 {
                            return DVec3::ZERO;
                        }
                    }
                }
            }
        }
        out
    }

    /// The first contact of body `a` with `p` in `[from, 1]`, if any.
    /// Whether neither body's path changed since `imp` was computed.
    pub(super) fn is_current(&self, imp: &Impact) -> bool {
        let ver_b = match imp.b {
            Partner::Body(j) => self.version[j as usize],
            _ => 0,
        };
        imp.ver_a == self.version[imp.a as usize] && imp.ver_b == ver_b
    }

    /// The time from which a stale impact must be searched again: the later path change.
    pub(super) fn search_from(&self, imp: &Impact) -> f64 {
        match imp.b {
            Partner::Body(j) => self.t0[imp.a as usize].max(self.t0[j as usize]),
            _ => self.t0[imp.a as usize],
        }
    }
}

/// Approach speed of an impact's pair along its normal (positive when closing), m/s.
fn closing_speed(w: &World, imp: &Impact) -> f64 {
    let vb = match imp.b {
        Partner::Body(j) => w.bodies.vel[j as usize],
        _ => DVec3::ZERO,
    };
    -(vb - w.bodies.vel[imp.a as usize]).dot(imp.contact.normal)
}
