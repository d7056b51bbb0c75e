//! Numerical stress cases. Each returns whether it passed and the figures it measured; the same
//! functions run in `impact-bench stability` (full size, with a table and JSON lines) and in the
//! CI tests (`tests/stability.rs`, with the same bounds). Every case checks every tick that no
//! position, velocity or event field is NaN or infinite.

use crate::rollback::{RollbackConfig, Session};
use crate::trials::{self, Kind, Method, Setup};
use glam::DVec3;
use impact_core::scene::Scene;
use impact_core::sim::{Plan, Stepper, TickOutput, World};
use impact_protocol::{Action, ClientId, ClientInput, EntityId, Tick};

/// One case's outcome.
#[derive(Clone, Debug)]
pub struct CaseResult {
    /// Case name.
    pub case: &'static str,
    /// Whether every bound held.
    pub pass: bool,
    /// Figures measured, `(name, value)`.
    pub figures: Vec<(String, f64)>,
    /// What failed, if anything.
    pub detail: String,
}

impl CaseResult {
    fn new(case: &'static str) -> CaseResult {
        CaseResult { case, pass: true, figures: Vec::new(), detail: String::new() }
    }
    fn fig(&mut self, name: impl Into<String>, v: f64) {
        self.figures.push((name.into(), v));
    }
    fn require(&mut self, ok: bool, what: impl Into<String>) {
        if !ok {
            self.pass = false;
            if !self.detail.is_empty() {
                self.detail.push_str("; ");
            }
            self.detail.push_str(&what.into());
        }
    }
}

/// The same collisions at 0, 1e3, 1e5, 1e6 and 1e7 m from the origin: time-of-impact errors at
/// 1e6 m at most twice those at the origin, and nothing missed anywhere, for the default search
/// (bisection) on sphere pairs and on spheres against boxes.
///
/// The analytic swept-sphere path is measured too but not held to the ratio: its error is
/// already at the limit of representing the scene (4e-11 s at the origin, 1.2e-10 s at 1e6 m,
/// where one ulp of a position is 1.2e-10 m), so the ratio of two rounding residues says
/// nothing about the method. Its figures are reported beside the bounded ones.
pub fn far_from_origin(trials_per_set: u32) -> CaseResult {
    let mut r = CaseResult::new("far_from_origin");
    for offset in [0.0, 1e6, 1e7] {
        let set = trials::build(&Setup {
            kind: Kind::SpherePairs,
            count: trials_per_set,
            radius: (0.1, 0.5),
            speed: (1.0, 50.0),
            offset: DVec3::splat(offset),
            ..Setup::default()
        });
        let e = trials::measure(&set, Method::Analytic, 1);
        r.fig(format!("analytic_toi_err_max_s_at_{offset:e}"), e.toi_err_max_s);
        r.require(!e.non_finite && e.missed_pct == 0.0, format!("analytic at {offset:e}: missed {}%", e.missed_pct));
    }
    for (kind, method) in [(Kind::SpherePairs, Method::Default), (Kind::SphereBox, Method::Default)] {
        let mut at_origin = 0.0;
        for offset in [0.0, 1e3, 1e5, 1e6, 1e7] {
            let set = trials::build(&Setup {
                kind,
                count: trials_per_set,
                radius: (0.1, 0.5),
                speed: (1.0, 50.0),
                offset: DVec3::splat(offset),
                ..Setup::default()
            });
            let e = trials::measure(&set, method, 1);
            r.fig(format!("{}_toi_err_max_s_at_{offset:e}", kind.name()), e.toi_err_max_s);
            r.require(!e.non_finite, format!("{} at {offset:e}: non-finite values", kind.name()));
            r.require(
                e.missed_pct == 0.0 && e.false_pct == 0.0,
                format!("{} at {offset:e}: missed {}%, false {}%", kind.name(), e.missed_pct, e.false_pct),
            );
            if offset == 0.0 {
                at_origin = e.toi_err_max_s;
            }
            if offset == 1e6 {
                r.require(
                    e.toi_err_max_s <= 2.0 * at_origin,
                    format!(
                        "{} at 1e6 m: error {:e} s > 2 x {:e} s at the origin",
                        kind.name(),
                        e.toi_err_max_s,
                        at_origin
                    ),
                );
            }
        }
    }
    r
}

/// Radii from 1 mm to 1 km (speeds scaled with them): time-of-impact error at most 1e-4 of a
/// tick and nothing missed at every scale.
pub fn scale(trials_per_set: u32) -> CaseResult {
    let mut r = CaseResult::new("scale");
    let dt = 1.0 / 64.0;
    for radius in [1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3] {
        for (kind, method) in [(Kind::SpherePairs, Method::Default), (Kind::SphereBox, Method::Default)] {
            // Trial boxes are 1-2 m: scale the box scene only up to spheres that fit on a face.
            if kind == Kind::SphereBox && radius > 0.1 {
                continue;
            }
            let set = trials::build(&Setup {
                kind,
                count: trials_per_set,
                radius: (radius, radius),
                speed: (radius, 40.0 * radius),
                ..Setup::default()
            });
            let e = trials::measure(&set, method, 1);
            r.fig(format!("{}_toi_err_max_ticks_r{radius:e}", kind.name()), e.toi_err_max_s / dt);
            r.require(!e.non_finite, format!("r = {radius:e}: non-finite values"));
            r.require(
                e.toi_err_max_s <= 1e-4 * dt,
                format!("{} r = {radius:e}: TOI error {:e} s over 1e-4 of a tick", kind.name(), e.toi_err_max_s),
            );
            r.require(e.missed_pct == 0.0, format!("{} r = {radius:e}: {}% missed", kind.name(), e.missed_pct));
        }
    }
    r
}

fn two_spheres(a: (DVec3, DVec3, f64), b: (DVec3, DVec3, f64)) -> World {
    // A tight contact slop: a graze 1e-9 m outside the radius sum must count as apart.
    let text = "[world]\nname = \"pair\"\ndefault_response = \"bounce\"\nbounce_threshold_mps = 0.0\ncontact_slop_m = 1e-12\n[[class]]\nname = \"ball\"\ngravity = false\nmax_speed_mps = 1e5\n";
    let mut w = Scene::parse(text, "<pair>").expect("valid").world;
    let class = w.config.classes.by_name("ball").expect("ball");
    for (p, v, r) in [a, b] {
        let body = impact_core::sim::world::NewBody {
            class,
            shape: impact_core::geometry::Shape::Sphere { radius: r },
            pos: p,
            vel: v,
            rot: glam::DQuat::IDENTITY,
            inv_mass: 1.0,
            owner: None,
        };
        w.spawn(body);
    }
    w
}

fn run_checked(mut w: World, ticks: u32) -> (World, usize, bool) {
    let mut st = Stepper::new(Plan::for_world(&w), false);
    let mut out = TickOutput::default();
    let mut events = 0;
    let mut finite = true;
    for _ in 0..ticks {
        st.step(&mut w, &[], &mut out);
        events += out.events.len();
        finite &= trials::finite(&w, &out.events);
    }
    (w, events, finite)
}

/// Grazing contacts, parallel equal velocities (B^2 = 0), coincident centres, zero relative
/// velocity and near-zero sizes: defined answers, no NaN.
pub fn degenerate() -> CaseResult {
    let mut r = CaseResult::new("degenerate");
    let x = DVec3::X;
    // Grazing: closest approach equal to the radius sum within 1e-9 relative, both sides.
    for (k, f) in [1.0 - 1e-9, 1.0 + 1e-9].into_iter().enumerate() {
        let w = two_spheres((DVec3::new(-1.0, 0.0, 0.0), x * 64.0, 0.5), (DVec3::new(1.0, f, 0.0), -x * 64.0, 0.5));
        let (_, events, finite) = run_checked(w, 8);
        r.require(finite, "grazing: non-finite");
        r.fig(format!("grazing_{}_events", if k == 0 { "touch" } else { "miss" }), events as f64);
        if k == 1 {
            r.require(events == 0, "a graze 1e-9 outside the radius sum reported a contact");
        }
    }
    // Parallel equal velocities: B^2 = 0, never a contact.
    let (_, events, finite) =
        run_checked(two_spheres((DVec3::ZERO, x * 5.0, 0.5), (DVec3::new(0.0, 1.5, 0.0), x * 5.0, 0.5)), 64);
    r.require(finite && events == 0, format!("parallel equal velocities: {events} events"));
    // Coincident centres: an overlap with a defined normal, pushed apart.
    let (w, events, finite) =
        run_checked(two_spheres((DVec3::ZERO, DVec3::ZERO, 0.5), (DVec3::ZERO, DVec3::ZERO, 0.5)), 4);
    r.require(finite && events >= 1, "coincident centres: no event or non-finite");
    r.fig("coincident_separation_m", (w.bodies.pos[1] - w.bodies.pos[0]).length());
    // Zero relative velocity, apart: nothing.
    let (_, events, finite) =
        run_checked(two_spheres((DVec3::ZERO, DVec3::ZERO, 0.5), (DVec3::new(3.0, 0.0, 0.0), DVec3::ZERO, 0.5)), 16);
    r.require(finite && events == 0, "zero relative velocity: events or non-finite");
    // Near-zero sizes (1 nm), head on at 10 m/s: they meet.
    let (_, events, finite) = run_checked(
        two_spheres((DVec3::new(-0.05, 0.0, 0.0), x * 10.0, 1e-9), (DVec3::new(0.05, 0.0, 0.0), -x * 10.0, 1e-9)),
        4,
    );
    r.require(finite && events >= 1, format!("nanometre spheres: {events} events"));
    r
}

/// Bullets at 1 to 10,000 m/s against 1 cm walls: every one hits, none passes.
pub fn speed(trials_per_set: u32) -> CaseResult {
    let mut r = CaseResult::new("speed");
    for s in [1.0, 10.0, 100.0, 1000.0, 10_000.0] {
        let set = trials::build(&Setup {
            kind: Kind::BulletWall,
            count: trials_per_set,
            radius: (0.05, 0.05),
            speed: (s, s),
            ..Setup::default()
        });
        let e = trials::measure(&set, Method::Default, 1);
        r.fig(format!("missed_pct_at_{s}_mps"), e.missed_pct);
        r.require(!e.non_finite && e.missed_pct == 0.0, format!("{s} m/s: {}% missed", e.missed_pct));
    }
    r
}

/// The pile case's scene: `n` spheres of radius 0.5 m dropped into an open box under gravity
/// (friction 0.5; a 3 mm contact band, wider than one tick of free fall at 64 Hz, 2.4 mm, so a
/// resting contact stays in the contact cache from tick to tick),
/// and the box's inner side, m.
pub fn pile_scene(n: u32) -> (Scene, f64) {
    let radius = 0.5;
    let side = ((f64::from(n)).cbrt() * 2.0 * radius * 1.6).max(4.0);
    let text = format!(
        "[world]\nname = \"pile\"\ngravity = [0.0, -9.81, 0.0]\ndefault_response = \"bounce\"\nrestitution = 0.2\nfriction = 0.5\ncontact_slop_m = 0.003\n\
[[class]]\nname = \"ball\"\nmax_speed_mps = 100.0\n[[class]]\nname = \"wall\"\nstatic = true\n\
[[body]]\nclass = \"wall\"\nshape = {{ type = \"cuboid\", half_extents_m = [{h}, 0.5, {h}] }}\nposition = [0.0, -0.5, 0.0]\n\
[[body]]\nclass = \"wall\"\nshape = {{ type = \"cuboid\", half_extents_m = [0.5, {H}, {h}] }}\nposition = [{neg}, {H}, 0.0]\n\
[[body]]\nclass = \"wall\"\nshape = {{ type = \"cuboid\", half_extents_m = [0.5, {H}, {h}] }}\nposition = [{pos}, {H}, 0.0]\n\
[[body]]\nclass = \"wall\"\nshape = {{ type = \"cuboid\", half_extents_m = [{h}, {H}, 0.5] }}\nposition = [0.0, {H}, {neg}]\n\
[[body]]\nclass = \"wall\"\nshape = {{ type = \"cuboid\", half_extents_m = [{h}, {H}, 0.5] }}\nposition = [0.0, {H}, {pos}]\n\
[[scatter]]\nclass = \"ball\"\nshape = {{ type = \"sphere\", radius_m = {radius} }}\ncount = {n}\nmin = [{m}, 0.6, {m}]\nmax = [{M}, {top}, {M}]\nspeed_mps = [0.0, 1.0]\nseed = 5\n",
        h = side / 2.0 + 1.0,
        H = side * 2.0,
        neg = -side / 2.0 - 0.5,
        pos = side / 2.0 + 0.5,
        m = -side / 2.0 + 0.05,
        M = side / 2.0 - 0.05,
        top = side * 3.0,
    );
    (Scene::parse(&text, "<pile>").expect("valid"), side)
}

/// A pile of `n` spheres under gravity in a box for `ticks` ticks: no body leaves the box,
/// penetration stays under 1 % of the radius, no velocity explodes, and by the end every body
/// is asleep.
pub fn pile(n: u32, ticks: u32) -> CaseResult {
    let mut r = CaseResult::new("pile");
    let radius = 0.5;
    let (scene, side) = pile_scene(n);
    let mut w = scene.world.clone();
    let mut st = Stepper::new(Plan::for_world(&w), false);
    let mut out = TickOutput::default();
    let (mut worst_pen, mut worst_speed, mut finite, mut left) = (0.0f64, 0.0f64, true, 0u32);
    let (mut worst_wall, mut worst_pair, mut worst_tick) = (0.0f64, 0.0f64, 0u32);
    let mut pairs = Vec::new();
    let mut grid = impact_core::broadphase::Broadphase::new(impact_core::broadphase::BroadphaseKind::Grid);
    for k in 0..ticks {
        st.step(&mut w, &[], &mut out);
        finite &= trials::finite(&w, &out.events);
        let b = &w.bodies;
        for (p, v) in b.pos.iter().zip(&b.vel) {
            worst_speed = worst_speed.max(v.length());
            if p.x.abs() > side / 2.0 + 1e-6 || p.z.abs() > side / 2.0 + 1e-6 || p.y < -1e-6 {
                left += 1;
            }
        }
        // Penetration: against the floor and walls directly, between balls through the grid
        // (every 10 ticks: it is the expensive check, and piles change slowly).
        for p in &b.pos {
            let pen = (radius - p.y).max(p.x.abs() + radius - side / 2.0).max(p.z.abs() + radius - side / 2.0);
            if pen > worst_wall {
                worst_wall = pen;
            }
        }
        if k % 10 == 9 || k + 1 == ticks {
            let boxes: Vec<impact_core::geometry::Aabb> = b
                .pos
                .iter()
                .map(|p| impact_core::geometry::Aabb { min: *p - DVec3::splat(radius), max: *p + DVec3::splat(radius) })
                .collect();
            grid.pairs(&boxes, &mut pairs, &impact_core::par::Pool::sequential());
            for &(i, j) in &pairs {
                let pen = 2.0 * radius - (b.pos[i as usize] - b.pos[j as usize]).length();
                if pen > worst_pair {
                    worst_pair = pen;
                    worst_tick = k;
                }
            }
        }
    }
    worst_pen = worst_pen.max(worst_wall).max(worst_pair);
    r.fig("ticks", f64::from(ticks));
    r.fig("max_penetration_pct_of_radius", 100.0 * worst_pen.max(0.0) / radius);
    r.fig("max_wall_penetration_pct", 100.0 * worst_wall.max(0.0) / radius);
    r.fig("max_pair_penetration_pct", 100.0 * worst_pair.max(0.0) / radius);
    r.fig("worst_pair_tick", f64::from(worst_tick));
    r.fig("max_speed_mps", worst_speed);
    r.fig("bodies_outside", f64::from(left));
    let awake = w.awake_asleep().0;
    r.fig("awake_at_end", awake as f64);
    r.require(finite, "non-finite values");
    r.require(left == 0, format!("{left} body-ticks outside the box"));
    r.require(worst_pen < 0.01 * radius, format!("penetration {:.3}% of the radius", 100.0 * worst_pen / radius));
    r.require(worst_speed < 50.0, format!("a velocity reached {worst_speed:.1} m/s"));
    r.require(awake == 0, format!("{awake} bodies still awake at the end: the pile never came to rest"));
    r
}

/// An elastic box of bouncing spheres for `ticks` ticks: kinetic energy drift under 0.1 %.
pub fn elastic(n: u32, ticks: u32) -> CaseResult {
    let mut r = CaseResult::new("elastic");
    let text = std::fs::read_to_string(Scene::bundled_path("arena"))
        .expect("arena scene")
        .replace("count = 2000", &format!("count = {n}"));
    let scene = Scene::parse(&text, "<elastic>").expect("valid");
    let energy = |w: &World| {
        w.bodies.vel.iter().zip(&w.bodies.inv_mass).map(|(v, im)| 0.5 * v.length_squared() / im).sum::<f64>()
    };
    let mut w = scene.world.clone();
    let e0 = energy(&w);
    let mut st = Stepper::new(Plan::for_world(&w), false);
    let mut out = TickOutput::default();
    let (mut finite, mut worst) = (true, 0.0f64);
    for _ in 0..ticks {
        st.step(&mut w, &[], &mut out);
        finite &= trials::finite(&w, &out.events);
        worst = worst.max((energy(&w) - e0).abs() / e0);
    }
    r.fig("ticks", f64::from(ticks));
    r.fig("energy_drift_max_pct", 100.0 * worst);
    r.require(finite, "non-finite values");
    r.require(worst < 1e-3, format!("energy drifted {:.4}%", 100.0 * worst));
    r
}

/// The rollback stress run's input for tick `t`: client 1 steers `player` with a velocity that
/// changes every tick (shared with the thread-count test).
pub fn stress_input(player: EntityId, t: u32) -> ClientInput {
    ClientInput {
        aim_tick: None,
        view_tick: None,
        client: ClientId(1),
        seq: t,
        tick: Tick(t),
        actions: vec![Action::SetVelocity {
            entity: player,
            velocity: [(f64::from(t % 7) - 3.0) * 2.0, f64::from(t % 3) - 1.0, (f64::from(t % 5) - 2.0) * 2.0],
        }],
    }
}

/// Depth-16 rollbacks every tick for `ticks` ticks: a session receiving every input 16 ticks
/// late ends bit-identical (state hash and confirmed events) to one receiving them on time.
pub fn rollback_stress(ticks: u32) -> CaseResult {
    let mut r = CaseResult::new("rollback_stress");
    let text = std::fs::read_to_string(Scene::bundled_path("arena")).expect("arena").replace("count = 2000", "count = 150")
        + "\n[[body]]\nclass = \"player\"\nshape = { type = \"sphere\", radius_m = 0.5 }\nposition = [0.0, 10.0, 0.0]\nowner = 1\n";
    let scene = Scene::parse(&text, "<rollback>").expect("valid");
    let b = &scene.world.bodies;
    let player = b.id[b.owner.iter().position(|o| *o == Some(ClientId(1))).expect("the player")];
    let mut cfg = RollbackConfig::for_world(&scene.world);
    cfg.window_ticks = 17;
    let mut on_time = Session::new(scene.world.clone(), Plan::for_world(&scene.world), cfg.clone());
    let mut late = Session::new(scene.world.clone(), Plan::for_world(&scene.world), cfg);
    let input = |t: u32| stress_input(player, t);
    let (mut same, mut finite, mut confirmed, mut depth_max, mut refused) = (true, true, 0u64, 0u32, 0u32);
    for t in 0..ticks {
        refused += u32::from(on_time.submit(input(t)).is_err());
        if t >= 16 {
            refused += u32::from(late.submit(input(t - 16)).is_err());
        }
        let a = on_time.advance();
        let b = late.advance();
        depth_max = depth_max.max(b.rollback_depth);
        finite &= trials::finite(on_time.world(), &a.events) && trials::finite(late.world(), &b.events);
        if let (Some(x), Some(y)) = (&a.confirmed, &b.confirmed) {
            confirmed += 1;
            let strip = |v: &[impact_protocol::CollisionEvent]| {
                v.iter().map(|e| (e.key(), e.toi.to_bits(), e.point.map(f64::to_bits))).collect::<Vec<_>>()
            };
            same &= x.tick == y.tick && strip(&x.events) == strip(&y.events);
        }
    }
    // The late session has not yet seen the last 16 ticks' inputs: give them and let both run on.
    for t in ticks.saturating_sub(16)..ticks {
        refused += u32::from(late.submit(input(t)).is_err());
    }
    let _ = late.advance();
    let _ = on_time.advance();
    same &= on_time.world().state_hash() == late.world().state_hash();
    r.fig("ticks", f64::from(ticks));
    r.fig("rollback_depth_max", f64::from(depth_max));
    r.fig("confirmed_ticks_compared", confirmed as f64);
    r.require(finite, "non-finite values");
    r.require(refused == 0, format!("{refused} inputs refused"));
    r.require(depth_max == 16, format!("rollbacks reached depth {depth_max}, expected 16"));
    r.require(same, "the late session diverged from the on-time one");
    r
}
