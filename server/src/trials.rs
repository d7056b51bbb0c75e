//! Collisions with known answers, for measuring accuracy: each trial is a pair (two spheres, a
//! sphere and a box, a sphere and the terrain, a bullet and a thin wall) constructed backwards
//! from a chosen contact (time, point, normal), so the truth is exact by construction, in f64.
//! Near misses (closest approach just over the radius sum) measure false collisions.
//!
//! Trials are laid out 1 km apart in one world, so one tick runs them all and its time is the
//! cost of the method at that scale. Used by `impact-bench accuracy` and `impact-bench
//! stability`, and by the stability tests.

use glam::{DQuat, DVec3};
use impact_core::scene::random::SplitMix64;
use impact_core::scene::Scene;
use impact_core::sim::{Plan, Stepper, TickOutput, World};
use impact_core::toi::bisect::BisectConfig;
use impact_protocol::{EntityId, Phase};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

/// Which known-answer scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Two moving spheres.
    SpherePairs,
    /// A sphere against a face of a rotated static box.
    SphereBox,
    /// A sphere against a tilted planar height field.
    SphereTerrain,
    /// A small fast sphere against a 1 cm wall, head on.
    BulletWall,
}

impl Kind {
    /// Short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Kind::SpherePairs => "sphere_pairs",
            Kind::SphereBox => "sphere_box",
            Kind::SphereTerrain => "sphere_terrain",
            Kind::BulletWall => "bullet_wall",
        }
    }
}

/// How a trial set is built.
#[derive(Clone, Copy, Debug)]
pub struct Setup {
    /// The scene.
    pub kind: Kind,
    /// Trials (contacts) and as many near misses for sphere pairs.
    pub count: u32,
    /// Ticks per second.
    pub tick_hz: u32,
    /// Sphere radius range, m.
    pub radius: (f64, f64),
    /// Speed range, m/s.
    pub speed: (f64, f64),
    /// Added to every position (far-from-origin tests), m.
    pub offset: DVec3,
    /// Generator seed.
    pub seed: u64,
}

impl Default for Setup {
    fn default() -> Self {
        Setup {
            kind: Kind::SpherePairs,
            count: 500,
            tick_hz: 64,
            radius: (0.1, 0.1),
            speed: (1.0, 200.0),
            offset: DVec3::ZERO,
            seed: 1,
        }
    }
}

/// A method: how the core finds the time of impact.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    /// Overlap at the end of the step only; no search (reports the start of the step).
    Discrete,
    /// Bisection with exactly this many halvings (sampling on).
    Bisect(u32),
    /// The default: bisection to the tolerance (2^-15 of a tick and 0.1 mm).
    Default,
    /// The swept-sphere formula (sphere pairs; other shapes fall back to the default).
    Analytic,
}

impl Method {
    /// Name and setting for tables and JSON.
    pub fn label(self) -> (&'static str, String) {
        match self {
            Method::Discrete => ("discrete", "-".into()),
            Method::Bisect(k) => ("bisection", format!("{k} iterations")),
            Method::Default => ("bisection", "default tolerance".into()),
            Method::Analytic => ("analytic", "-".into()),
        }
    }

    /// The plan and bisection settings for this method on `w`.
    pub fn apply(self, w: &mut World) -> Plan {
        let base = Plan::for_world(w);
        let cfg = Arc::make_mut(&mut w.config);
        match self {
            Method::Discrete => {
                cfg.bisect = BisectConfig { max_iterations: 0, ..BisectConfig::default() };
                Plan { analytic_spheres: false, ccd_sampling: false, ..base }
            }
            Method::Bisect(k) => {
                cfg.bisect =
                    BisectConfig { tolerance: 0.0, tolerance_m: 0.0, max_iterations: k, ..BisectConfig::default() };
                Plan { analytic_spheres: false, ccd_sampling: true, ..base }
            }
            Method::Default => {
                cfg.bisect = BisectConfig::default();
                Plan { analytic_spheres: false, ccd_sampling: true, ..base }
            }
            Method::Analytic => {
                cfg.bisect = BisectConfig::default();
                Plan { analytic_spheres: true, ccd_sampling: true, ..base }
            }
        }
    }
}

/// The truth for one trial.
#[derive(Clone, Copy, Debug)]
pub struct Truth {
    /// Lower entity id.
    pub a: EntityId,
    /// Higher entity id.
    pub b: EntityId,
    /// Contact time, fraction of the first tick; `None` for a near miss.
    pub toi: Option<f64>,
    /// Contact point, world frame, m.
    pub point: DVec3,
    /// Unit normal from `a` to `b`.
    pub normal: DVec3,
}

/// A trial world and its truths.
#[derive(Debug, Clone)]
pub struct TrialSet {
    /// The world at tick 0.
    pub world: World,
    /// One per trial.
    pub truths: Vec<Truth>,
}

/// What a method got right and wrong on a trial set.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Errors {
    /// Largest time-of-impact error, s.
    pub toi_err_max_s: f64,
    /// Mean time-of-impact error, s.
    pub toi_err_mean_s: f64,
    /// Largest contact point error, m.
    pub point_err_max_m: f64,
    /// Largest normal angle error, rad.
    pub normal_err_max_rad: f64,
    /// Collisions with no begin event, % of collisions.
    pub missed_pct: f64,
    /// Near misses reported as collisions, % of near misses.
    pub false_pct: f64,
    /// Median time of the tick, ms.
    pub ms_per_tick: f64,
    /// Whether any state or event held a NaN or an infinity.
    pub non_finite: bool,
}

fn unit(rng: &mut SplitMix64) -> DVec3 {
    let z = 2.0 * rng.unit() - 1.0;
    let a = std::f64::consts::TAU * rng.unit();
    let q = (1.0 - z * z).max(0.0).sqrt();
    DVec3::new(q * a.cos(), z, q * a.sin())
}

fn range(rng: &mut SplitMix64, r: (f64, f64)) -> f64 {
    r.0 + (r.1 - r.0) * rng.unit()
}

/// A trial before entity ids exist: (body index, other body index, toi, point, normal from the
/// body to the other).
type Pending = (usize, Option<usize>, Option<f64>, DVec3, DVec3);

/// A trial set on its way: the scene text of its statics and terrain, and its balls with what
/// each must do, drawn from one seeded generator in a fixed order.
struct Draft<'a> {
    s: &'a Setup,
    rng: SplitMix64,
    /// The tick, s.
    dt: f64,
    /// `[[body]]` entries of the static walls.
    statics: String,
    /// The `[terrain]` entry and its class.
    terrain: String,
    /// Balls: position, velocity, radius.
    bodies: Vec<(DVec3, DVec3, f64)>,
    pending: Vec<Pending>,
}

impl Draft<'_> {
    /// Where trial `k` takes place: 1 km apart, so trials never meet.
    fn slot(&self, k: u32) -> DVec3 {
        self.s.offset + DVec3::new(f64::from(k) * 1000.0, 0.0, 0.0)
    }
}

/// Builds a trial set.
pub fn build(s: &Setup) -> TrialSet {
    let mut d = Draft {
        s,
        rng: SplitMix64::new(s.seed),
        dt: 1.0 / f64::from(s.tick_hz),
        statics: String::new(),
        terrain: String::new(),
        bodies: Vec::new(),
        pending: Vec::new(),
    };
    match s.kind {
        Kind::SpherePairs => sphere_pairs(&mut d),
        Kind::SphereBox | Kind::BulletWall => spheres_at_boxes(&mut d),
        Kind::SphereTerrain => spheres_at_terrain(&mut d),
    }
    let Draft { statics, terrain, bodies, pending, .. } = d;
    let text = format!(
        "[world]\nname = \"trials\"\ntick_hz = {}\ndefault_response = \"trigger\"\ncontact_slop_m = 1e-9\nmax_bodies = 2000000\n[[class]]\nname = \"ball\"\ngravity = false\nmax_speed_mps = 1e5\n[[class]]\nname = \"wall\"\nstatic = true\n{terrain}{statics}",
        s.tick_hz
    );
    let mut scene = Scene::parse(&text, "<trials>").expect("trial scenes are valid");
    let ball = scene.world.config.classes.by_name("ball").expect("ball class");
    let mut ids = Vec::new();
    for (p, v, r) in &bodies {
        let body = impact_core::sim::world::NewBody {
            class: ball,
            shape: impact_core::geometry::Shape::Sphere { radius: *r },
            pos: *p,
            vel: *v,
            rot: DQuat::IDENTITY,
            inv_mass: 1.0,
            owner: None,
        };
        ids.push(scene.world.spawn(body).expect("room"));
    }
    let statics = &scene.world.statics;
    let truths = pending
        .into_iter()
        .enumerate()
        .map(|(k, (ib, other, toi, point, n))| {
            let b = ids[ib];
            let (a, normal) = match other {
                Some(io) => (ids[io], n),
                None if s.kind == Kind::SphereTerrain => (statics.terrain.as_ref().map_or(EntityId(0), |t| t.id), n),
                None => (statics.id[k], n),
            };
            // Events name the lower id first, normal from it to the other.
            let (a, b, normal) = if a < b {
                (a, b, if other.is_some() { -normal } else { normal })
            } else {
                (b, a, if other.is_some() { normal } else { -normal })
            };
            Truth { a, b, toi, point, normal }
        })
        .collect();
    TrialSet { world: scene.world, truths }
}

/// Pairs of spheres, every other one meeting at a drawn time within the tick, the rest missing
/// by 1 % of their radius sum.
fn sphere_pairs(d: &mut Draft<'_>) {
    let (s, dt) = (d.s, d.dt);
    for k in 0..2 * s.count {
        let c = d.slot(k);
        let (ra, rb) = (range(&mut d.rng, s.radius), range(&mut d.rng, s.radius));
        let n = unit(&mut d.rng);
        let tc = 0.05 + 0.9 * d.rng.unit();
        let va = unit(&mut d.rng) * range(&mut d.rng, s.speed) * 0.5;
        let hit = k % 2 == 0;
        let (vb, pb_c) = if hit {
            // Approach along -n with a random tangential part.
            let w = (-n * (0.3 + 0.7 * d.rng.unit()) + unit(&mut d.rng).reject_from(n) * 0.5).normalize()
                * range(&mut d.rng, s.speed);
            (va + w, c + n * (ra + rb))
        } else {
            // Closest approach 1 % over the radius sum, with relative motion across n.
            let w =
                unit(&mut d.rng).reject_from(n).normalize_or(n.any_orthonormal_vector()) * range(&mut d.rng, s.speed);
            (va + w, c + n * (ra + rb) * 1.01)
        };
        let ia = d.bodies.len();
        d.bodies.push((c - va * (tc * dt), va, ra));
        d.bodies.push((pb_c - vb * (tc * dt), vb, rb));
        d.pending.push((ia, Some(ia + 1), hit.then_some(tc), c + n * ra, n));
    }
}

/// Spheres meeting rotated boxes (or, for bullets, thin walls head on) at a drawn time.
fn spheres_at_boxes(d: &mut Draft<'_>) {
    let (s, dt) = (d.s, d.dt);
    for k in 0..s.count {
        let c = d.slot(k);
        let bullet = s.kind == Kind::BulletWall;
        let (h, rot) = if bullet {
            (DVec3::new(0.005, 5.0, 5.0), DQuat::IDENTITY)
        } else {
            let axis = unit(&mut d.rng);
            (
                DVec3::new(0.5 + d.rng.unit(), 1.0 + d.rng.unit(), 1.0 + d.rng.unit()),
                DQuat::from_axis_angle(axis, 3.0 * d.rng.unit()),
            )
        };
        let r = range(&mut d.rng, s.radius);
        let (u, v) = if bullet {
            (0.0, 0.0)
        } else {
            ((h.y - r) * (2.0 * d.rng.unit() - 1.0) * 0.9, (h.z - r) * (2.0 * d.rng.unit() - 1.0) * 0.9)
        };
        let face = rot * DVec3::new(h.x, u, v) + c;
        let out = rot * DVec3::X;
        let centre_c = face + out * r;
        let speed = range(&mut d.rng, s.speed);
        let dir = if bullet {
            -out
        } else {
            (-out * (0.4 + 0.6 * d.rng.unit())
                + (rot * DVec3::new(0.0, 2.0 * d.rng.unit() - 1.0, 2.0 * d.rng.unit() - 1.0)) * 0.5)
                .normalize()
        };
        let vel = dir * speed;
        let tc = 0.05 + 0.9 * d.rng.unit();
        let (ax, ay, az) = {
            let q = rot.to_euler(glam::EulerRot::ZYX);
            (q.2.to_degrees(), q.1.to_degrees(), q.0.to_degrees())
        };
        d.statics += &format!(
            "[[body]]\nclass = \"wall\"\nshape = {{ type = \"cuboid\", half_extents_m = [{}, {}, {}] }}\nposition = [{}, {}, {}]\nrotation_deg = [{ax}, {ay}, {az}]\n",
            h.x, h.y, h.z, c.x, c.y, c.z
        );
        let ib = d.bodies.len();
        d.bodies.push((centre_c - vel * (tc * dt), vel, r));
        // The sphere is the second entity (statics come first): normal from box to sphere.
        d.pending.push((ib, None, Some(tc), face, out));
    }
}

/// Spheres meeting a tilted height field at a drawn time.
fn spheres_at_terrain(d: &mut Draft<'_>) {
    let (s, dt) = (d.s, d.dt);
    // A tilted plane y = 0.2 x - 0.1 z as a height field, 2 m cells, big enough for all.
    let cells = (s.count as f64).sqrt().ceil() as u32 * 4 + 4;
    let size = f64::from(cells) * 2.0;
    let o = s.offset + DVec3::new(-size / 2.0, 0.0, -size / 2.0);
    let rows: Vec<String> = (0..=cells)
        .map(|z| {
            let row: Vec<String> = (0..=cells)
                .map(|x| {
                    format!("{}", 0.2 * (f64::from(x) * 2.0 - size / 2.0) - 0.1 * (f64::from(z) * 2.0 - size / 2.0))
                })
                .collect();
            format!("[{}]", row.join(", "))
        })
        .collect();
    d.terrain = format!("[[class]]\nname = \"ground\"\nstatic = true\n[terrain]\nclass = \"ground\"\norigin = [{}, {}, {}]\ncell_m = [2.0, 2.0]\nheights = [{}]\n", o.x, o.y, o.z, rows.join(", "));
    let up = DVec3::new(-0.2, 1.0, 0.1).normalize();
    let side = (s.count as f64).sqrt().ceil() as u32;
    for k in 0..s.count {
        let (gx, gz) = (f64::from(k % side), f64::from(k / side));
        let x = -size / 2.0 + 8.0 + gx * 8.0;
        let z = -size / 2.0 + 8.0 + gz * 8.0;
        let p = s.offset + DVec3::new(x, 0.2 * x - 0.1 * z, z);
        let r = range(&mut d.rng, s.radius);
        let centre_c = p + up * r;
        let dir = (-up + unit(&mut d.rng).reject_from(up) * 0.5 * d.rng.unit()).normalize();
        let vel = dir * range(&mut d.rng, s.speed).min(100.0);
        let tc = 0.05 + 0.9 * d.rng.unit();
        let ib = d.bodies.len();
        d.bodies.push((centre_c - vel * (tc * dt), vel, r));
        // The terrain is entity 0: normal from terrain to sphere.
        d.pending.push((ib, None, Some(tc), p, up));
    }
}

/// Runs `method` on `set`: the first tick's events against the truths, and the tick's time
/// (median of `repeats` runs from the same start).
pub fn measure(set: &TrialSet, method: Method, repeats: u32) -> Errors {
    let dt = set.world.config.dt;
    let mut times = Vec::new();
    let mut events = Vec::new();
    let mut non_finite = false;
    for _ in 0..repeats.max(1) {
        let mut w = set.world.clone();
        let plan = method.apply(&mut w);
        let mut st = Stepper::new(plan, false);
        let mut out = TickOutput::default();
        let t = Instant::now();
        st.step(&mut w, &[], &mut out);
        times.push(t.elapsed().as_secs_f64() * 1e3);
        non_finite |= !finite(&w, &out.events);
        events = out.events;
    }
    times.sort_by(f64::total_cmp);
    let begins: BTreeMap<(EntityId, EntityId), &impact_protocol::CollisionEvent> =
        events.iter().filter(|e| e.phase == Phase::Begin).map(|e| ((e.a, e.b), e)).collect();
    let mut e = Errors { ms_per_tick: times[times.len() / 2], non_finite, ..Errors::default() };
    let (mut hits, mut missed, mut misses, mut false_hits, mut sum) = (0u32, 0u32, 0u32, 0u32, 0.0);
    for t in &set.truths {
        let got = begins.get(&(t.a, t.b));
        match (t.toi, got) {
            (Some(toi), Some(ev)) => {
                hits += 1;
                let err = (ev.toi - toi).abs() * dt;
                sum += err;
                e.toi_err_max_s = e.toi_err_max_s.max(err);
                e.point_err_max_m = e.point_err_max_m.max((DVec3::from_array(ev.point) - t.point).length());
                let cos = DVec3::from_array(ev.normal).dot(t.normal).clamp(-1.0, 1.0);
                e.normal_err_max_rad = e.normal_err_max_rad.max(cos.acos());
            }
            (Some(_), None) => missed += 1,
            (None, Some(_)) => {
                misses += 1;
                false_hits += 1;
            }
            (None, None) => misses += 1,
        }
    }
    let collisions = hits + missed;
    e.toi_err_mean_s = if hits > 0 { sum / f64::from(hits) } else { 0.0 };
    e.missed_pct = if collisions > 0 { 100.0 * f64::from(missed) / f64::from(collisions) } else { 0.0 };
    e.false_pct = if misses > 0 { 100.0 * f64::from(false_hits) / f64::from(misses) } else { 0.0 };
    e
}

/// Whether every position, velocity and event field is finite.
pub fn finite(w: &World, events: &[impact_protocol::CollisionEvent]) -> bool {
    w.bodies.pos.iter().chain(&w.bodies.vel).all(|v| v.is_finite())
        && events.iter().all(|e| {
            e.toi.is_finite()
                && e.depth_m.is_finite()
                && e.closing_speed_mps.is_finite()
                && e.point.iter().chain(&e.normal).all(|x| x.is_finite())
        })
}
