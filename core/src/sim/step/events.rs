//! Stage 8, events: the touching set at the end of the tick, merged with the one before it and
//! the tick's impacts into begin and end events.

use super::{ordered, response_of, Cand, PairRecord, Partner, Stepper, TickOutput};
use crate::par::MIN_PIECE_HEAVY;
use crate::sim::world::{Touch, TouchHint, World};
use glam::DVec3;
use impact_protocol::{CollisionEvent, EntityId, EventStatus, Phase, Response};

impl Stepper {
    /// Builds the touching set at the end of the tick and turns the tick's story into begin,
    /// end and destroy events, and removes the destroyed bodies.
    pub(super) fn finish_events(&mut self, w: &mut World, out: &mut TickOutput) {
        let tick = w.tick;
        // Touching at the end: every candidate pair still alive, within the slop (a map over
        // the candidates, cut over the pool). Pairs found twice mid-step give duplicate
        // entries, removed below.
        self.touching_now.clear();
        let mut end_records = std::mem::take(&mut self.end_records);
        end_records.clear();
        let this = &*self;
        this.pool.extend(this.candidates.len(), MIN_PIECE_HEAVY, &mut end_records, |range, out| {
            for k in range {
                out.extend(this.end_record(w, k));
            }
        });
        // Three sorted lists, walked together by pair key: P, the pairs touching before; E, the
        // pairs touching now that were tested (`end_records`); R, this tick's impacts (the
        // first per pair). A linear merge instead of a lookup per pair keeps this stage O(n).
        // E is sorted as 16-byte (packed key, index) entries rather than 88-byte records; of
        // a pair tested twice, the first tested stays.
        let key_of = |r: &PairRecord| ordered(r.key.0, r.key.1);
        let pack = |(a, b): (EntityId, EntityId)| u64::from(a.0) << 32 | u64::from(b.0);
        let unpack = |k: u64| (EntityId((k >> 32) as u32), EntityId(k as u32));
        let mut end_order = std::mem::take(&mut self.end_order);
        end_order.clear();
        end_order.extend(end_records.iter().enumerate().map(|(k, r)| (pack(key_of(r)), k as u32)));
        self.pool.sort_unstable(&mut end_order);
        end_order.dedup_by_key(|e| e.0);
        // R likewise, by (pair, time of impact, index): of a pair's impacts the earliest stays
        // (the first recorded among equal times).
        let mut record_order = std::mem::take(&mut self.record_order);
        record_order.clear();
        record_order
            .extend(self.records.iter().enumerate().map(|(k, r)| (pack(key_of(r)), ordered_bits(r.t), k as u32)));
        self.pool.sort_unstable(&mut record_order);
        record_order.dedup_by_key(|e| e.0);
        // Resting pairs were not candidates: they keep touching while both ends stay put.
        let still = |slot: Option<u32>| match slot {
            Some(s) => !self.dead[s as usize] && !self.moving[s as usize],
            None => true, // static or terrain
        };
        let prev = &w.touching;
        let mut hints = std::mem::take(&mut self.touch_hints_next);
        hints.clear();
        let (mut ip, mut ie, mut ir) = (0, 0, 0);
        // Packed keys, with `u64::MAX` for a list that has run out (no pair packs to it: its
        // two ids would be equal): the smallest of three is then two branch-free minimums.
        const DONE: u64 = u64::MAX;
        loop {
            let kp = prev.get(ip).map_or(DONE, |t| pack(t.key()));
            let ke = end_order.get(ie).map_or(DONE, |e| e.0);
            let kr = record_order.get(ir).map_or(DONE, |e| e.0);
            let packed = kp.min(ke).min(kr);
            if packed == DONE {
                break;
            }
            let key = unpack(packed);
            let was = kp == packed;
            let tested = ke == packed;
            let impact = if kr == packed { Some(self.records[record_order[ir].2 as usize]) } else { None };
            let end = if tested { Some(end_records[end_order[ie].1 as usize]) } else { None };
            let now = tested || (was && impact.is_none() && self.touch_slots[ip].iter().all(|s| still(*s)));
            if now {
                // The contact cache: a tested pair's normal from this tick, a resting pair's
                // from when it was last tested. Normals point from the lower id to the higher.
                let (normal, depth, slots) = match end {
                    Some(e) if e.key.0 <= e.key.1 => (e.normal_lo_hi, e.depth, e.slots),
                    Some(e) => (-e.normal_lo_hi, e.depth, [e.slots[1], e.slots[0]]),
                    None => (
                        prev[ip].normal,
                        prev[ip].depth,
                        self.touch_slots[ip].map(|s| s.unwrap_or(TouchHint::NOT_A_BODY)),
                    ),
                };
                hints.push(TouchHint { key, slots });
                // The resting solver's impulse carries over while the contact lasts.
                let (impulse, friction_impulse) =
                    if was { self.contact_impulse.get(ip).copied().unwrap_or_default() } else { Default::default() };
                self.touching_now.push(Touch { a: key.0, b: key.1, normal, depth, impulse, friction_impulse });
            }
            match (was, impact) {
                (false, Some(r)) => {
                    // A new contact: it begins at its time of impact, and ends in the same tick
                    // if the pair bounced apart.
                    out.events.push(event(tick, &r, Phase::Begin));
                    if !now {
                        out.events.push(event(tick, &r, Phase::End));
                    }
                }
                (false, None) => {
                    if let Some(e) = end {
                        // Touching now with no impact (slid or grew into contact).
                        out.events.push(event(tick, &e, Phase::Begin));
                    }
                }
                (true, Some(r)) => {
                    // A continuing contact: only its end is news (destroyed, or bounced apart).
                    if r.response == Response::Destroy || !now {
                        out.events.push(event(tick, &r, Phase::End));
                    }
                }
                (true, None) => {
                    if !now {
                        out.events.push(end_without_contact(w, tick, key, &self.dead));
                    }
                }
            }
            ip += usize::from(was);
            ie += usize::from(tested);
            ir += usize::from(impact.is_some());
        }
        sort_events(&mut out.events);
        // The new touching list becomes the world's; the old one's buffer is reused next tick.
        std::mem::swap(&mut w.touching, &mut self.touching_now);
        if self.dead.contains(&true) {
            hints.clear(); // the removals below move slots
        }
        self.touch_hints_next = std::mem::replace(&mut self.touch_hints, hints);
        self.end_records = end_records;
        self.end_order = end_order;
        self.record_order = record_order;
        if self.dead.contains(&true) {
            w.bodies.remove_flagged(&self.dead);
        }
    }

    /// A candidate's record if it touches at the end of the tick (alive, within the slop). A
    /// pair whose paths never changed reuses the end contact found with its time of impact.
    fn end_record(&self, w: &World, k: usize) -> Option<PairRecord> {
        let b = &w.bodies;
        let Cand { a, b: p } = self.candidates[k];
        let i = a as usize;
        if self.dead[i] || matches!(p, Partner::Body(j) if self.dead[j as usize]) {
            return None;
        }
        let (id_b, class_b) = match p {
            Partner::Body(j) => (b.id[j as usize], b.class[j as usize]),
            Partner::Static(s) => (w.statics.id[s as usize], w.statics.class[s as usize]),
            Partner::Terrain => {
                let t = w.statics.terrain.as_ref().expect("terrain");
                (t.id, t.class)
            }
        };
        let pa = b.pos[i];
        let pb = match p {
            Partner::Body(j) => b.pos[j as usize],
            Partner::Static(s) => w.statics.pos[s as usize],
            Partner::Terrain => DVec3::ZERO,
        };
        let c = match self.end_if_unchanged(k) {
            Some(end) => end,
            None => self.contact(w, i, pa, p, pb, w.config.contact_slop_m),
        }?;
        let vb = match p {
            Partner::Body(j) => b.vel[j as usize],
            _ => DVec3::ZERO,
        };
        Some(PairRecord {
            key: (b.id[i], id_b),
            slots: [a, p.slot()],
            t: 1.0,
            point: pa + c.point,
            normal_lo_hi: c.normal,
            depth: c.depth.max(0.0),
            closing: -(vb - b.vel[i]).dot(c.normal),
            response: response_of(w.config.classes.rule(b.class[i], class_b)),
        })
    }
}

/// `t` as an integer in `f64::total_cmp`'s order.
fn ordered_bits(t: f64) -> i64 {
    let bits = t.to_bits() as i64;
    bits ^ ((((bits >> 63) as u64) >> 1) as i64)
}

/// The order events are published in, `(toi, a, b, phase)`, one per key.
pub(super) fn sort_events(events: &mut Vec<CollisionEvent>) {
    events.sort_by(|x, y| x.toi.total_cmp(&y.toi).then(x.a.cmp(&y.a)).then(x.b.cmp(&y.b)).then(x.phase.cmp(&y.phase)));
    events.dedup_by(|x, y| x.key() == y.key());
}

fn event(tick: impact_protocol::Tick, r: &PairRecord, phase: Phase) -> CollisionEvent {
    // Events name the lower id first, with the normal pointing from it to the other.
    let (a, b, normal) =
        if r.key.0 <= r.key.1 { (r.key.0, r.key.1, r.normal_lo_hi) } else { (r.key.1, r.key.0, -r.normal_lo_hi) };
    CollisionEvent {
        tick,
        toi: r.t.clamp(0.0, 1.0),
        a,
        b,
        point: r.point.to_array(),
        normal: normal.to_array(),
        depth_m: r.depth,
        closing_speed_mps: r.closing,
        phase,
        response: r.response,
        status: EventStatus::Provisional,
    }
}

/// An end event for a pair that moved apart so far this tick that it was not even a broadphase
/// candidate: the point is between the two centres, the normal along them.
fn end_without_contact(
    w: &World,
    tick: impact_protocol::Tick,
    key: (EntityId, EntityId),
    dead: &[bool],
) -> CollisionEvent {
    let pos = |id: EntityId| -> DVec3 {
        if let Some(s) = w.bodies.slot(id) {
            return w.bodies.pos[s];
        }
        match w.statics.id.binary_search(&id) {
            Ok(s) => w.statics.pos[s],
            Err(_) => DVec3::ZERO,
        }
    };
    let (pa, ca) = (pos(key.0), w.class_of(key.0));
    let (pb, cb) = (pos(key.1), w.class_of(key.1));
    let destroyed = [key.0, key.1].iter().any(|id| w.bodies.slot(*id).is_some_and(|s| dead[s]));
    let response = match (ca, cb) {
        _ if destroyed => Response::Destroy,
        (Some(a), Some(b)) => response_of(w.config.classes.rule(a, b)),
        _ => Response::Trigger,
    };
    CollisionEvent {
        tick,
        toi: 1.0,
        a: key.0,
        b: key.1,
        point: ((pa + pb) * 0.5).to_array(),
        normal: (pb - pa).normalize_or(DVec3::Y).to_array(),
        depth_m: 0.0,
        closing_speed_mps: 0.0,
        phase: Phase::End,
        response,
        status: EventStatus::Provisional,
    }
}
