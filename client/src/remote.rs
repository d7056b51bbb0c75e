//! The remote world: the bodies a state stream shows, kept as samples of where each was and how
//! it moved, and drawn at a render time between them.
//!
//! Feed it every [`StateFrame`] of a stream in arrival order ([`RemoteWorld::apply`]); each frame
//! draws it ([`RemoteWorld::draw`]) at a render tick: the client clock's estimate of the server's
//! present less the interpolation delay (100 ms by default, [`RemoteConfig::delay_s`]), so that
//! the frames on either side of it have usually arrived.
//!
//! How a body is drawn at render tick `r`, from its samples (a tick, a position and a velocity,
//! from the frames that carried it):
//!
//! - between a sample `a` at or before `r` and the next one `b` after it: the body moved from `a`
//!   at `a`'s velocity until something changed it, and reached `b` at `b`'s. When nothing changed
//!   it, `a` carried forward and `b` carried back are the same point: the server's motion. When
//!   it bounced, the two carried paths meet where it collided (within [`CROSSING_M`]): drawn on
//!   `a`'s path before the meeting and `b`'s after, the server's motion again, corner and all.
//!   When they pass apart (pushed over several ticks), drawn at their blend weighted by where `r`
//!   lies between the samples: a continuous path instead of a jump. A frame carries a body only
//!   when its motion changed (the stream is dead-reckoned), so `a` may be many frames before
//!   `b`: up to the frame just before `b`'s, when that frame held nothing back for the budget,
//!   the stream vouched that the body was on `a`'s path, and it is drawn there; the meeting is
//!   looked for, and the blend made, after that frame only ([`Sample::vouched`]);
//! - after its last sample: carried forward at that sample's velocity. A delta carries a body
//!   when it is more than 1 mm from where its last sample, carried so, puts it (or its velocity
//!   changed by 1 mm/s), or later when the byte budget held it back, so after its last sample
//!   this is where the server has it, up to the stream's newest tick, however long ago the
//!   sample came; beyond that tick (frames late) it is extrapolated, for at most
//!   [`RemoteConfig::max_extrapolation_s`], and then held;
//! - before its first sample (it has just entered the view, moving): carried back at that sample's
//!   velocity, where the server had it (held at the sample instead, it would be drawn up to the
//!   interpolation delay ahead of where it was: 0.5 m at 5 m/s), unless game logic teleported it
//!   into the view ([`BodyInfo::teleported`]): before that tick it was elsewhere, and is not drawn;
//! - across a teleport (its samples either side name different ones): where it was before the
//!   teleport's tick and where it went from it on, never between.
//!
//! The stream's rules (PROTOCOL.md, state streams): a full frame replaces what is held, a delta
//! applies to the frame before it, and after a gap in the frame numbers deltas are ignored until
//! the next full frame ([`RemoteWorld::needs_full_frame`] says so meanwhile; the bodies held are
//! still drawn, extrapolated within the bound). A frame at a tick no newer than the newest
//! applied is a repeat, whatever its number: a stream numbered anew (after a reconnect or a
//! takeover) goes on at newer ticks. Everything held is bounded: at most
//! [`RemoteConfig::max_bodies`] bodies (more are counted and not shown) and
//! [`RemoteConfig::history`] samples each. Nothing a server or network sends panics it.

use impact_protocol::{BodyInfo, BodyMotion, EntityId, StateFrame, Tick};
use std::collections::{BTreeMap, VecDeque};

/// How the remote world interpolates and what it holds at most.
#[derive(Clone, Debug, PartialEq)]
pub struct RemoteConfig {
    /// The server's ticks per second (the world's `tick_hz`).
    pub tick_hz: u32,
    /// How far behind the server's present bodies are drawn, seconds (default 0.1, as Source's
    /// `cl_interp`): two frames of a 20 Hz stream, so one may be lost or late.
    pub delay_s: f64,
    /// How long a body is carried forward past the stream's newest frame, seconds (default
    /// 0.25); then it is held where it got to.
    pub max_extrapolation_s: f64,
    /// Most bodies held (default 65,536); bodies entering beyond it are counted and not shown.
    pub max_bodies: usize,
    /// Most samples held per body (default 32: at 20 frames a second, over a second and a half,
    /// far more than the delay needs).
    pub history: usize,
}

impl RemoteConfig {
    /// The defaults for a world ticking at `tick_hz`.
    pub fn new(tick_hz: u32) -> RemoteConfig {
        RemoteConfig { tick_hz, delay_s: 0.1, max_extrapolation_s: 0.25, max_bodies: 65_536, history: 32 }
    }

    /// The interpolation delay in ticks.
    pub fn delay_ticks(&self) -> f64 {
        self.delay_s * f64::from(self.tick_hz.max(1))
    }

    fn dt(&self) -> f64 {
        1.0 / f64::from(self.tick_hz.max(1))
    }
}

/// Where a body was at a tick and how it moved, as a frame said.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// The tick.
    pub tick: Tick,
    /// Centre, world frame, metres.
    pub position: [f64; 3],
    /// Velocity, m/s.
    pub velocity: [f64; 3],
    /// Asleep.
    pub asleep: bool,
    /// The tick of the body's last teleport as of this sample (see [`BodyInfo::teleported`]).
    pub teleported: Option<Tick>,
    /// Up to this tick the body was on the previous sample's path: the tick of the frame just
    /// before the one that carried this sample, when that frame held nothing back (`deferred`
    /// 0: every body whose motion changed went out in it); `None` when not known.
    pub vouched: Option<Tick>,
}

impl Sample {
    /// Carried at its velocity to tick `t` (earlier or later), `dt` seconds a tick.
    fn at(&self, t: f64, dt: f64) -> [f64; 3] {
        let s = (t - f64::from(self.tick.0)) * dt;
        std::array::from_fn(|k| self.position[k] + self.velocity[k] * s)
    }
}

/// A body as drawn at a render tick.
#[derive(Clone, Debug, PartialEq)]
pub struct DrawnBody {
    /// The body.
    pub entity: EntityId,
    /// Centre, world frame, metres.
    pub position: [f64; 3],
    /// Velocity at the sample it was carried from, m/s.
    pub velocity: [f64; 3],
    /// Carried past the stream's newest frame (frames are late).
    pub extrapolated: bool,
    /// Nothing changed its motion around the render tick (its samples either side carry the
    /// same velocity, or its last sample is followed by frames that did not carry it), so it is
    /// drawn where the server had it, up to the f32 of the stream.
    pub steady: bool,
    /// Asleep in the server's world at the last sample at or before the render tick.
    pub asleep: bool,
}

/// What [`RemoteWorld::apply`] did with a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Applied {
    /// Applied.
    Applied,
    /// A delta after a gap in the frame numbers (or before any full frame): ignored, and so is
    /// every delta until the next full frame.
    Gap,
    /// A frame at a tick no newer than the newest applied (a repeat, or one that came late):
    /// ignored.
    Stale,
}

/// What the remote world counted.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RemoteStats {
    /// Frames applied.
    pub frames: u64,
    /// Full frames applied.
    pub full_frames: u64,
    /// Gaps seen in the frame numbers.
    pub gaps: u64,
    /// Frames ignored: deltas waiting for a full frame, and repeats.
    pub ignored: u64,
    /// Bodies not shown because [`RemoteConfig::max_bodies`] were held.
    pub over_capacity: u64,
    /// Motions or departures of bodies the stream never introduced: skipped.
    pub unknown_bodies: u64,
}

#[derive(Debug)]
struct Remote {
    info: BodyInfo,
    samples: VecDeque<Sample>,
}

/// The bodies of one state stream, drawn at a render tick (see the module docs).
#[derive(Debug)]
pub struct RemoteWorld {
    cfg: RemoteConfig,
    bodies: BTreeMap<EntityId, Remote>,
    /// The frame number the next delta must carry; `None` until a full frame (or after a gap).
    expected: Option<u32>,
    newest: Option<Tick>,
    /// The tick of the last frame applied, when it held nothing back (see [`Sample::vouched`]).
    clean: Option<Tick>,
    stats: RemoteStats,
}

impl RemoteWorld {
    /// An empty remote world; it shows bodies from the first full frame on.
    pub fn new(cfg: RemoteConfig) -> RemoteWorld {
        RemoteWorld {
            cfg,
            bodies: BTreeMap::new(),
            expected: None,
            newest: None,
            clean: None,
            stats: RemoteStats::default(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &RemoteConfig {
        &self.cfg
    }

    /// What it counted.
    pub fn stats(&self) -> &RemoteStats {
        &self.stats
    }

    /// The newest tick a frame was applied at.
    pub fn newest_tick(&self) -> Option<Tick> {
        self.newest
    }

    /// Whether deltas are being ignored until a full frame comes (after a gap, or before the
    /// first): the moment to ask the server for one, where the transport can.
    pub fn needs_full_frame(&self) -> bool {
        self.expected.is_none()
    }

    /// What never changes about a body held.
    pub fn info(&self, entity: EntityId) -> Option<&BodyInfo> {
        self.bodies.get(&entity).map(|b| &b.info)
    }

    /// How many bodies are held.
    pub fn len(&self) -> usize {
        self.bodies.len()
    }

    /// Whether no body is held.
    pub fn is_empty(&self) -> bool {
        self.bodies.is_empty()
    }

    /// Applies the next frame of the stream, in arrival order.
    ///
    /// Ticks only go forward along a stream (one frame a tick at most), so a frame at a tick no
    /// newer than the newest applied is a repeat or late, whatever its number. The numbers tell
    /// gaps: the server numbers a stream from 0 again when it takes it up anew (the client back
    /// from a drop, a new owner after a takeover), and such a stream's first delta, its full
    /// frame lost, is a gap like any other.
    pub fn apply(&mut self, frame: &StateFrame) -> Applied {
        if Some(frame.tick) <= self.newest {
            self.stats.ignored += 1;
            return Applied::Stale;
        }
        // The frame before this one vouches for the paths up to its tick if it came just before
        // (no gap) and held nothing back.
        let vouched = self.clean.filter(|_| self.expected == Some(frame.frame));
        if !frame.full {
            match self.expected {
                Some(n) if frame.frame == n => {}
                Some(_) => {
                    self.stats.gaps += 1;
                    self.stats.ignored += 1;
                    self.expected = None;
                    return Applied::Gap;
                }
                None => {
                    self.stats.ignored += 1;
                    return Applied::Gap;
                }
            }
        } else {
            // Exactly the bodies it lists; those held before keep their samples.
            let listed: std::collections::BTreeSet<EntityId> =
                frame.moved.iter().map(|m| m.0).chain(frame.entered.iter().map(|i| i.entity)).collect();
            self.bodies.retain(|e, _| listed.contains(e));
            self.stats.full_frames += 1;
        }
        for info in &frame.entered {
            if let Some(b) = self.bodies.get_mut(&info.entity) {
                b.info = info.clone();
            } else if self.bodies.len() < self.cfg.max_bodies {
                self.bodies.insert(info.entity, Remote { info: info.clone(), samples: VecDeque::new() });
            } else {
                self.stats.over_capacity += 1;
            }
        }
        for m in &frame.moved {
            self.record(frame.tick, m, vouched);
        }
        for e in &frame.left {
            if self.bodies.remove(e).is_none() {
                self.stats.unknown_bodies += 1;
            }
        }
        self.expected = Some(frame.frame.wrapping_add(1));
        self.newest = self.newest.max(Some(frame.tick));
        self.clean = (frame.deferred == 0).then_some(frame.tick);
        self.stats.frames += 1;
        Applied::Applied
    }

    fn record(&mut self, tick: Tick, m: &BodyMotion, vouched: Option<Tick>) {
        let BodyMotion(entity, p, v, asleep) = *m;
        let Some(b) = self.bodies.get_mut(&entity) else {
            self.stats.unknown_bodies += 1;
            return;
        };
        let finite = p.iter().chain(&v).all(|x| x.is_finite());
        if !finite {
            self.stats.unknown_bodies += 1;
            return;
        }
        let teleported = b.info.teleported;
        let sample =
            Sample { tick, position: p.map(f64::from), velocity: v.map(f64::from), asleep, teleported, vouched };
        // Samples stay in tick order; one for a tick already held replaces it.
        while b.samples.back().is_some_and(|s| s.tick >= tick) {
            b.samples.pop_back();
        }
        b.samples.push_back(sample);
        while b.samples.len() > self.cfg.history.max(1) {
            b.samples.pop_front();
        }
    }

    /// Every body held, drawn at `render_tick` (fractional), by ascending id, into `out`
    /// (cleared first).
    pub fn draw(&self, render_tick: f64, out: &mut Vec<DrawnBody>) {
        out.clear();
        out.extend(self.bodies.iter().filter_map(|(e, b)| self.drawn(*e, b, render_tick)));
    }

    /// One body drawn at `render_tick`, if held.
    pub fn draw_one(&self, entity: EntityId, render_tick: f64) -> Option<DrawnBody> {
        self.drawn(entity, self.bodies.get(&entity)?, render_tick)
    }

    /// Body `b` drawn at `render_tick` (see the module docs).
    fn drawn(&self, entity: EntityId, b: &Remote, render_tick: f64) -> Option<DrawnBody> {
        let newest = f64::from(self.newest?.0);
        let first = b.samples.front()?;
        let dt = self.cfg.dt();
        let limit = newest + self.cfg.max_extrapolation_s * f64::from(self.cfg.tick_hz.max(1));
        let r = render_tick.min(limit);
        // The last sample at or before r, and the one after it.
        let after = b.samples.partition_point(|s| f64::from(s.tick.0) <= r);
        let (position, velocity, steady) = match (after.checked_sub(1).map(|k| &b.samples[k]), b.samples.get(after)) {
            // Before a teleport that brought it: it was elsewhere, not drawn.
            // A tick's inputs apply at its start, after the state of that tick: a body teleported
            // at tick T is where it was at T, and elsewhere after.
            (None, _) if first.teleported.is_some_and(|t| r <= f64::from(t.0)) => return None,
            (None, _) => (first.at(r, dt), first.velocity, false),
            // A teleport between the two: each side drawn on its own path, never between.
            (Some(a), Some(n)) if a.teleported != n.teleported => {
                if n.teleported.is_some_and(|t| r <= f64::from(t.0)) {
                    (a.at(r, dt), a.velocity, false)
                } else {
                    (n.at(r, dt), n.velocity, false)
                }
            }
            // Up to the stream's newest frame, the stream vouches that nothing changed it.
            (Some(a), None) => (a.at(r, dt), a.velocity, r <= newest),
            (Some(a), Some(n)) if a.velocity == n.velocity => {
                // Nothing changed it: both carry to the same point (up to the stream's f32).
                let (ta, tn) = (f64::from(a.tick.0), f64::from(n.tick.0));
                let f = (r - ta) / (tn - ta);
                let (pa, pn) = (a.at(r, dt), n.at(r, dt));
                (std::array::from_fn(|k| pa[k] + (pn[k] - pa[k]) * f), a.velocity, true)
            }
            (Some(a), Some(n)) => {
                // Up to the frame before `n`'s, the stream vouched for `a`'s path.
                let (lo, tn) = (changed_after(a, n), f64::from(n.tick.0));
                let (pa, pn) = (a.at(r, dt), n.at(r, dt));
                if r <= lo {
                    (pa, a.velocity, true)
                } else {
                    match crossing(a, n, lo, dt) {
                        // The two carried paths meet where it collided: each drawn on its side.
                        Some(tc) if r <= tc => (pa, a.velocity, false),
                        Some(_) => (pn, n.velocity, false),
                        // They pass apart (pushed, not bounced): blended from where the stream
                        // last vouched for `a`'s path, a continuous path.
                        None => {
                            let f = (r - lo) / (tn - lo);
                            (std::array::from_fn(|k| pa[k] + (pn[k] - pa[k]) * f), a.velocity, false)
                        }
                    }
                }
            }
        };
        let asleep = after.checked_sub(1).map_or(first.asleep, |k| b.samples[k].asleep);
        Some(DrawnBody { entity, position, velocity, extrapolated: render_tick > newest, steady, asleep })
    }
}

/// Carried paths closer than this where they pass are taken to meet (a collision between the
/// samples; the stream's f32 and gravity's curve keep them a few millimetres apart): the body is
/// drawn on each path on its side of the meeting, a step of at most this.
pub const CROSSING_M: f64 = 0.01;

/// The tick after which the motion changed between samples `a` and `n`: the last the stream
/// vouched for `a`'s path ([`Sample::vouched`]), or `a`'s own.
fn changed_after(a: &Sample, n: &Sample) -> f64 {
    let ta = f64::from(a.tick.0);
    n.vouched.map_or(ta, |v| f64::from(v.0).clamp(ta, f64::from(n.tick.0)))
}

/// The tick between `from` and sample `n` (samples `a` and `n` have different velocities) at
/// which `a` carried forward and `n` carried back come closest, if they come within
/// [`CROSSING_M`] there.
fn crossing(a: &Sample, n: &Sample, from: f64, dt: f64) -> Option<f64> {
    let (ta, tn) = (from, f64::from(n.tick.0));
    let (pa, pn) = (a.at(ta, dt), n.at(ta, dt));
    // The gap between the two paths, linear in the tick: d(t) = d0 + dv (t - ta).
    let d0: [f64; 3] = std::array::from_fn(|k| pa[k] - pn[k]);
    let dv: [f64; 3] = std::array::from_fn(|k| (a.velocity[k] - n.velocity[k]) * dt);
    let vv: f64 = dv.iter().map(|x| x * x).sum();
    if vv == 0.0 {
        return None;
    }
    let t = (ta - d0.iter().zip(&dv).map(|(x, y)| x * y).sum::<f64>() / vv).clamp(ta, tn);
    let gap = (0..3).map(|k| (d0[k] + dv[k] * (t - ta)).powi(2)).sum::<f64>().sqrt();
    (gap <= CROSSING_M).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use impact_protocol::BodyShape;

    const HZ: u32 = 64;

    fn info(e: u32) -> BodyInfo {
        BodyInfo {
            entity: EntityId(e),
            class: "ball".into(),
            owner: None,
            shape: BodyShape::Sphere,
            half_extents_m: [0.5; 3],
            offset_m: [0.0; 3],
            fixed: false,
            rotation: None,
            local_shape: None,
            state: Default::default(),
            teleported: None,
        }
    }

    fn frame(frame: u32, tick: u32, full: bool, moved: &[(u32, [f32; 3], [f32; 3])]) -> StateFrame {
        StateFrame {
            tick: Tick(tick),
            frame,
            full,
            entered: if full { moved.iter().map(|m| info(m.0)).collect() } else { Vec::new() },
            moved: moved.iter().map(|&(e, p, v)| BodyMotion(EntityId(e), p, v, false)).collect(),
            left: Vec::new(),
            deferred: 0,
            centre: None,
            avatar: None,
        }
    }

    fn x_at(w: &RemoteWorld, e: u32, r: f64) -> f64 {
        w.draw_one(EntityId(e), r).unwrap().position[0]
    }

    /// A body moving at constant velocity, carried in a full frame and never again (deltas carry
    /// only changes), is drawn where the server has it, at any fractional tick.
    #[test]
    fn a_body_moving_as_it_was_is_drawn_exactly() {
        let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
        assert_eq!(w.apply(&frame(0, 10, true, &[(1, [0.0, 1.0, 0.0], [2.0, 0.0, 0.0])])), Applied::Applied);
        assert_eq!(w.apply(&frame(1, 13, false, &[])), Applied::Applied);
        for r in [10.0, 11.25, 12.5, 13.0] {
            assert!(w.draw_one(EntityId(1), r).unwrap().steady);
            let want = 2.0 * (r - 10.0) / 64.0;
            assert!((x_at(&w, 1, r) - want).abs() < 1e-12, "at {r}: {} vs {want}", x_at(&w, 1, r));
        }
    }

    /// A body that enters the view moving is drawn, before its first sample, where the server
    /// had it then: carried back, not held ahead of itself.
    #[test]
    fn a_body_entering_is_carried_back_before_its_first_sample() {
        let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
        w.apply(&frame(0, 10, true, &[]));
        let mut entering = frame(1, 16, false, &[(1, [1.0, 0.0, 0.0], [6.4, 0.0, 0.0])]);
        entering.entered.push(info(1));
        assert_eq!(w.apply(&entering), Applied::Applied);
        // Six ticks before it entered (a 100 ms delay at 64 Hz): 0.6 m back.
        assert!((x_at(&w, 1, 10.0) - 0.4).abs() < 1e-6, "{}", x_at(&w, 1, 10.0));
        assert!((x_at(&w, 1, 16.0) - 1.0).abs() < 1e-12);
    }

    /// A body game logic teleported (its info says since when): drawn on its old path before
    /// the teleport's tick and on its new one from it, never sliding between; one teleported
    /// into the view is not drawn before it came.
    #[test]
    fn a_teleport_is_drawn_as_a_jump_at_its_tick() {
        let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
        w.apply(&frame(0, 10, true, &[(1, [0.0, 0.0, 0.0], [6.4, 0.0, 0.0])]));
        // Teleported at tick 12 to x = 50, standing: the frame at 13 says so.
        let mut jumped = frame(1, 13, false, &[(1, [50.0, 0.0, 0.0], [0.0, 0.0, 0.0])]);
        jumped.entered.push(BodyInfo { teleported: Some(Tick(12)), ..info(1) });
        // And another body teleported into the view at tick 12.
        jumped.entered.push(BodyInfo { teleported: Some(Tick(12)), ..info(2) });
        jumped.moved.push(BodyMotion(EntityId(2), [-5.0, 0.0, 0.0], [0.0; 3], false));
        w.apply(&jumped);
        // The state at tick 12 is before its inputs: still on the old path.
        assert!((x_at(&w, 1, 11.5) - 0.15).abs() < 1e-6, "old path: {}", x_at(&w, 1, 11.5));
        assert!((x_at(&w, 1, 12.0) - 0.2).abs() < 1e-6, "old path: {}", x_at(&w, 1, 12.0));
        assert_eq!(x_at(&w, 1, 12.5), 50.0);
        assert!(!w.draw_one(EntityId(1), 11.5).unwrap().steady);
        assert_eq!(w.draw_one(EntityId(2), 12.0), None, "not here before its teleport");
        assert_eq!(x_at(&w, 2, 12.5), -5.0);
    }

    /// A bounce between two frames: drawn exactly at each frame's tick, and continuously between
    /// (no jump larger than the motion itself).
    #[test]
    fn a_collision_between_frames_is_drawn_as_a_continuous_path() {
        let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
        w.apply(&frame(0, 0, true, &[(1, [0.0, 0.0, 0.0], [6.4, 0.0, 0.0])]));
        // Bounced back at tick 2 (x = 0.2): at tick 4 it is at 0.0 moving at -6.4.
        w.apply(&frame(1, 4, false, &[(1, [0.0, 0.0, 0.0], [-6.4, 0.0, 0.0])]));
        assert!(x_at(&w, 1, 0.0).abs() < 1e-12 && x_at(&w, 1, 4.0).abs() < 1e-12);
        assert!(!w.draw_one(EntityId(1), 2.0).unwrap().steady, "a bounce between the frames");
        // The two carried paths (0.1 r and 0.1 (4 - r) metres) meet at the bounce, tick 2: drawn
        // on each on its side, at the body's own speed, so no frame shows a jump.
        assert!((x_at(&w, 1, 2.0) - 0.2).abs() < 1e-8, "{}", x_at(&w, 1, 2.0)); // 6.4 as f32
        let mut last = x_at(&w, 1, 0.0);
        for k in 1..=40 {
            let x = x_at(&w, 1, f64::from(k) * 0.1);
            assert!((x - last).abs() <= 2.0 * 0.1 * 6.4 / 64.0 + 1e-9, "jump at {k}: {last} -> {x}");
            last = x;
        }
    }

    /// A bounce a quarter of the way between two frames is drawn where the server had the body
    /// at every tick (the corner, not a curve cutting it); a push that leaves the carried paths
    /// apart is drawn on their blend, continuous.
    #[test]
    fn a_bounce_is_drawn_on_the_server_path_and_a_push_blended() {
        let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
        // At 6.4 m/s (0.1 m a tick) from x = 0, bounced at tick 1 (x = 0.1): at tick 4, x = -0.2.
        w.apply(&frame(0, 0, true, &[(1, [0.0, 0.0, 0.0], [6.4, 0.0, 0.0]), (2, [0.0, 5.0, 0.0], [6.4, 0.0, 0.0])]));
        // Body 2 was pushed sideways, its path offset by 1 m: no meeting.
        w.apply(&frame(1, 4, false, &[(1, [-0.2, 0.0, 0.0], [-6.4, 0.0, 0.0]), (2, [0.4, 6.0, 0.0], [6.4, 6.4, 0.0])]));
        for (r, server) in [(0.5, 0.05), (1.0, 0.1), (2.0, 0.0), (3.0, -0.1), (3.5, -0.15)] {
            assert!((x_at(&w, 1, r) - server).abs() < 1e-6, "tick {r}: {} against {server}", x_at(&w, 1, r));
        }
        let y = |r: f64| w.draw_one(EntityId(2), r).unwrap().position[1];
        let mut last = y(0.0);
        for k in 1..=40 {
            let now = y(f64::from(k) * 0.1);
            assert!((now - last).abs() < 0.05, "a continuous blend: {last} -> {now} at {k}");
            last = now;
        }
    }

    /// A dead-reckoned stream: a body flying straight is not carried again until something
    /// changes it, so its samples may be many frames apart. Up to the frame before the one that
    /// carried the change (when that frame held nothing back) it is drawn on its old path, where
    /// the server had it; the change is drawn between that frame and the next sample.
    #[test]
    fn a_change_is_drawn_after_the_last_frame_that_vouched_for_the_old_path() {
        let push = |deferred: u32| {
            let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
            // 6.4 m/s along x (0.1 m a tick); frames at ticks 4 and 8 do not carry it; by tick 12
            // it was pushed along y (after tick 8 its paths are 0.4 m apart or more: no meeting).
            w.apply(&frame(0, 0, true, &[(1, [0.0; 3], [6.4, 0.0, 0.0])]));
            w.apply(&frame(1, 4, false, &[]));
            w.apply(&StateFrame { deferred, ..frame(2, 8, false, &[]) });
            w.apply(&frame(3, 12, false, &[(1, [1.2, 0.8, 0.0], [6.4, 6.4, 0.0])]));
            w
        };
        let w = push(0);
        for r in [1.0, 5.0, 8.0] {
            let d = w.draw_one(EntityId(1), r).unwrap();
            let old = [0.1 * r, 0.0, 0.0];
            assert!((0..3).all(|k| (d.position[k] - old[k]).abs() < 1e-6), "tick {r}: {:?}", d.position);
            assert!(d.steady, "tick {r}: the stream vouched for it");
        }
        // Between ticks 8 and 12, blended from the old path onto the new: half way at tick 10.
        let d = w.draw_one(EntityId(1), 10.0).unwrap();
        let (old, new) = ([1.0, 0.0], [1.0, 0.8 - 6.4 * 2.0 / 64.0]);
        for k in 0..2 {
            assert!((d.position[k] - (old[k] + new[k]) / 2.0).abs() < 1e-6, "{:?}", d.position);
        }
        assert!(!d.steady);
        // The frame at tick 8 held bodies back: the change may have come any time after tick 0
        // (and the two paths cross at tick 4: taken for a bounce there).
        let w = push(1);
        let d = w.draw_one(EntityId(1), 5.0).unwrap();
        assert!(!d.steady && (d.position[1] - 0.1).abs() < 1e-6, "on the new path: {:?}", d.position);
    }

    /// Frames late: carried forward by velocity up to the bound, then held; the flag says so.
    #[test]
    fn extrapolation_is_bounded() {
        let mut cfg = RemoteConfig::new(HZ);
        cfg.max_extrapolation_s = 0.25; // 16 ticks
        let mut w = RemoteWorld::new(cfg);
        w.apply(&frame(0, 100, true, &[(1, [0.0; 3], [1.0, 0.0, 0.0])]));
        let d = w.draw_one(EntityId(1), 108.0).unwrap();
        assert!(d.extrapolated && !d.steady && (d.position[0] - 8.0 / 64.0).abs() < 1e-12);
        assert!((x_at(&w, 1, 200.0) - 16.0 / 64.0).abs() < 1e-12, "held at the bound");
        assert!(!w.draw_one(EntityId(1), 99.0).unwrap().extrapolated);
    }

    /// A gap in the frame numbers: deltas are ignored until the next full frame, which replaces
    /// what is held; a repeat is stale.
    #[test]
    fn a_gap_waits_for_a_full_frame() {
        let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
        assert_eq!(w.apply(&frame(5, 10, false, &[])), Applied::Gap, "a delta before any full frame");
        assert!(w.needs_full_frame());
        w.apply(&frame(6, 10, true, &[(1, [0.0; 3], [0.0; 3]), (2, [1.0, 0.0, 0.0], [0.0; 3])]));
        assert!(!w.needs_full_frame() && w.len() == 2);
        assert_eq!(w.apply(&frame(6, 10, false, &[])), Applied::Stale);
        assert_eq!(w.apply(&frame(8, 14, false, &[(1, [5.0, 0.0, 0.0], [0.0; 3])])), Applied::Gap);
        assert!(w.needs_full_frame());
        assert_eq!(w.apply(&frame(9, 16, false, &[(1, [5.0, 0.0, 0.0], [0.0; 3])])), Applied::Gap);
        assert_eq!(x_at(&w, 1, 16.0), 0.0, "ignored deltas moved nothing");
        // The full frame lists body 1 only: body 2 goes, body 1 keeps its history.
        w.apply(&frame(10, 18, true, &[(1, [0.0, 0.0, 0.0], [0.0; 3])]));
        assert_eq!((w.len(), w.stats().gaps, w.stats().full_frames), (1, 1, 2));
        assert!(w.info(EntityId(2)).is_none());
    }

    /// Frame numbers go on past `u32::MAX` at 0: the deltas across the wrap apply, a repeat of
    /// one before it is stale (not a gap that would ask for a full frame).
    #[test]
    fn frames_go_on_across_the_wrap() {
        let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
        w.apply(&frame(u32::MAX - 1, 10, true, &[(1, [0.0; 3], [1.0, 0.0, 0.0])]));
        for (n, tick) in [(u32::MAX, 11), (0, 12), (1, 13)] {
            assert_eq!(w.apply(&frame(n, tick, false, &[])), Applied::Applied, "frame {n}");
        }
        assert_eq!(w.apply(&frame(u32::MAX, 11, false, &[])), Applied::Stale);
        assert_eq!(w.apply(&frame(u32::MAX - 1, 10, true, &[])), Applied::Stale, "an older full frame");
        assert_eq!(w.apply(&frame(2, 14, false, &[(1, [4.0, 0.0, 0.0], [1.0, 0.0, 0.0])])), Applied::Applied);
        assert!(!w.needs_full_frame() && w.stats().gaps == 0);
        assert!((x_at(&w, 1, 14.0) - 4.0).abs() < 1e-12);
    }

    /// A stream taken up anew (the client back after a drop, a new owner after a takeover)
    /// numbers its frames from 0 again: its frames carry newer ticks, so they are not repeats. Its
    /// full frame applies; a delta of it (the full frame lost) is a gap that asks for one, not
    /// a repeat that would leave the bodies frozen until the numbers caught up.
    #[test]
    fn a_stream_numbered_anew_is_not_taken_for_repeats() {
        let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
        w.apply(&frame(80, 100, true, &[(1, [0.0; 3], [0.0; 3])]));
        assert_eq!(w.apply(&frame(81, 103, false, &[])), Applied::Applied);
        assert_eq!(
            w.apply(&frame(1, 140, false, &[(1, [9.0, 0.0, 0.0], [0.0; 3])])),
            Applied::Gap,
            "its full frame lost"
        );
        assert!(w.needs_full_frame());
        assert_eq!(w.apply(&frame(2, 143, false, &[])), Applied::Gap);
        w.apply(&frame(3, 146, true, &[(1, [5.0, 0.0, 0.0], [0.0; 3])]));
        assert!(!w.needs_full_frame());
        assert_eq!(w.apply(&frame(4, 149, false, &[(1, [6.0, 0.0, 0.0], [0.0; 3])])), Applied::Applied);
        assert_eq!(x_at(&w, 1, 149.0), 6.0);
        // Again, its full frame first this time: applied at once.
        assert_eq!(w.apply(&frame(0, 200, true, &[(1, [7.0, 0.0, 0.0], [0.0; 3])])), Applied::Applied);
        assert_eq!(w.apply(&frame(1, 203, false, &[])), Applied::Applied);
        // Repeats are still repeats, and a late frame of the old numbering changes nothing.
        assert_eq!(w.apply(&frame(0, 200, true, &[])), Applied::Stale);
        assert_eq!(w.apply(&frame(1, 203, false, &[])), Applied::Stale);
        assert_eq!(
            w.apply(&frame(82, 106, true, &[(1, [0.0; 3], [0.0; 3])])),
            Applied::Stale,
            "late, of the old numbering"
        );
        assert_eq!(w.apply(&frame(2, 190, false, &[])), Applied::Stale, "the next number, at an old tick");
        assert_eq!((w.stats().gaps, w.stats().full_frames), (1, 3));
    }

    /// Bounds: bodies past `max_bodies` are counted and not shown; samples per body are capped;
    /// motions of unknown bodies and non-finite values are counted and skipped.
    #[test]
    fn what_it_holds_is_bounded() {
        let mut cfg = RemoteConfig::new(HZ);
        cfg.max_bodies = 2;
        cfg.history = 4;
        let mut w = RemoteWorld::new(cfg);
        w.apply(&frame(0, 0, true, &[(1, [0.0; 3], [0.0; 3]), (2, [0.0; 3], [0.0; 3]), (3, [0.0; 3], [0.0; 3])]));
        assert_eq!((w.len(), w.stats().over_capacity), (2, 1));
        assert_eq!(w.stats().unknown_bodies, 1, "body 3's motion");
        for k in 1..20u32 {
            w.apply(&frame(k, k, false, &[(1, [k as f32, 0.0, 0.0], [0.0; 3])]));
        }
        assert_eq!(w.bodies[&EntityId(1)].samples.len(), 4);
        w.apply(&frame(20, 20, false, &[(1, [f32::NAN, 0.0, 0.0], [0.0; 3])]));
        assert_eq!(x_at(&w, 1, 20.0), 19.0, "the NaN was skipped");
        let mut left = frame(21, 21, false, &[]);
        left.left = vec![EntityId(9)];
        w.apply(&left);
        assert_eq!(w.stats().unknown_bodies, 3);
    }

    proptest::proptest! {
        /// Bodies on straight paths, carried at random frames (a full frame, then deltas that
        /// sometimes repeat a body's unchanged motion): drawn at any tick up to the newest, each is
        /// where its path puts it, within the f32 rounding of the stream.
        #[test]
        fn straight_paths_are_drawn_on_them(
            starts in proptest::collection::vec((-50.0..50.0f32, -10.0..10.0f32), 1..8),
            frames in proptest::collection::vec((1u32..6, proptest::bool::ANY), 1..12),
            at in 0.0..1.0f64,
        ) {
            let mut w = RemoteWorld::new(RemoteConfig::new(HZ));
            let path = |k: usize, t: u32| -> [f32; 3] {
                let (x0, v) = starts[k];
                [(f64::from(x0) + f64::from(v) * f64::from(t) / 64.0) as f32, 0.0, 0.0]
            };
            let all = |t: u32| -> Vec<(u32, [f32; 3], [f32; 3])> {
                (0..starts.len()).map(|k| (k as u32, path(k, t), [starts[k].1, 0.0, 0.0])).collect()
            };
            w.apply(&frame(0, 0, true, &all(0)));
            let mut tick = 0;
            for (n, (step, resend)) in frames.iter().enumerate() {
                tick += step;
                let moved = if *resend { all(tick) } else { Vec::new() };
                proptest::prop_assert_eq!(w.apply(&frame(n as u32 + 1, tick, false, &moved)), Applied::Applied);
            }
            let r = at * f64::from(tick);
            for (k, &(x0, v)) in starts.iter().enumerate() {
                let want = f64::from(x0) + f64::from(v) * r / 64.0;
                let got = x_at(&w, k as u32, r);
                proptest::prop_assert!((got - want).abs() < 1e-4, "body {k} at {r}: {got} vs {want}");
            }
        }
    }
}
