//! Islands: dynamic bodies joined by touching contacts. An island falls asleep whole, when every
//! body in it has been still long enough, and wakes whole, when anything disturbs one of its
//! bodies. Both walk the touching list in its sorted order over slots in id order, so the
//! result never depends on anything but the world.
//!
//! Under gravity with `partial_sleep` (a scene's choice), an island also sleeps in parts, from
//! the bottom up: a body still long enough whose every dynamic partner below it (along gravity)
//! sleeps falls asleep on its own, though bodies above it still move, and a sleeper woken wakes
//! the sleepers above it (what rests on it), not those it rests on. A pile whose last few bodies
//! slide down its slopes costs only those bodies, not the whole pile, until they stop.

use crate::sim::world::World;
use glam::DVec3;

/// Slots of the touching list's dynamic pairs, `(slot a, slot b)`, in list order; static and
/// terrain partners join no island (a floor does not make everything on it one island). With
/// `down`, `below` gets each pair's contact normal along it: positive where `b` is below `a`.
fn dynamic_pairs(w: &World, down: Option<DVec3>, out: &mut Vec<(u32, u32)>, below: &mut Vec<f64>) {
    out.clear();
    below.clear();
    let (mut ca, mut cb) = (0, 0);
    let b = &w.bodies;
    for t in &w.touching {
        if let (Some(i), Some(j)) = (b.slot_from(&mut ca, t.a), b.slot_from(&mut cb, t.b)) {
            out.push((i as u32, j as u32));
            if let Some(d) = down {
                below.push(t.normal.dot(d));
            }
        }
    }
}

/// Reusable buffers for island work (no allocation per tick once warm).
#[derive(Debug, Default)]
pub(crate) struct Islands {
    pairs: Vec<(u32, u32)>,
    below: Vec<f64>,
    parent: Vec<u32>,
    ready: Vec<bool>,
    woken: Vec<bool>,
    held_up: Vec<bool>,
}

impl Islands {
    /// Wakes the islands of the sleeping bodies in `seeds` (slots): every sleeping body joined
    /// to one of them through touching sleeping bodies wakes (sleeping in parts: through bodies
    /// each above the one before), keeping its zero velocity, with its still timer reset.
    /// Returns how many bodies woke.
    pub fn wake(&mut self, w: &mut World, seeds: &[u32]) -> usize {
        /// Wakes slot `s` if it sleeps; whether it did.
        fn wake_one(b: &mut crate::sim::world::Bodies, woken: &mut [bool], s: usize) -> bool {
            if !b.asleep[s] {
                return false;
            }
            b.asleep[s] = false;
            b.still_ticks[s] = 0;
            woken[s] = true;
            true
        }
        let b = &mut w.bodies;
        self.woken.clear();
        self.woken.resize(b.len(), false);
        let mut count = 0;
        for &s in seeds {
            count += usize::from(wake_one(b, &mut self.woken, s as usize));
        }
        if count == 0 {
            return 0;
        }
        let down = w.config.sleeps_in_parts();
        dynamic_pairs(w, down, &mut self.pairs, &mut self.below);
        let b = &mut w.bodies;
        // Spread along contacts to a fixpoint; each pass wakes at least one body or ends, so at
        // most as many passes as the island is long (sorted pairs usually need one or two).
        // Sleeping in parts, a wake spreads only up: to what rests on a woken body.
        loop {
            let mut spread = false;
            for (k, &(i, j)) in self.pairs.iter().enumerate() {
                let (i, j) = (i as usize, j as usize);
                let below = self.below.get(k).copied();
                for (from, to, up) in [(i, j, below.is_none_or(|s| s < 0.0)), (j, i, below.is_none_or(|s| s > 0.0))] {
                    if self.woken[from] && up && wake_one(b, &mut self.woken, to) {
                        count += 1;
                        spread = true;
                    }
                }
            }
            if !spread {
                return count;
            }
        }
    }

    /// The end-of-tick sleep rule: every awake body's still timer counts ticks under the sleep
    /// speed (or restarts); an island whose awake bodies have all been still for
    /// `sleep_after_ticks` (and may all sleep) falls asleep, velocities zeroed. Sleeping bodies
    /// in an island count as ready. Sleeping in parts, a body still that long also falls asleep
    /// when no dynamic partner below it was awake at the start of the pass (so a pile sleeps a
    /// layer a tick from the bottom). Returns how many bodies fell asleep.
    pub(crate) fn fall_asleep(&mut self, w: &mut World) -> usize {
        let cfg = &w.config;
        let after = cfg.sleep_after_ticks;
        if after == 0 {
            return 0;
        }
        let limit = u16::try_from(after).unwrap_or(u16::MAX);
        let speed2 = cfg.sleep_speed_mps * cfg.sleep_speed_mps;
        let b = &mut w.bodies;
        let n = b.len();
        let mut any_ready = false;
        for i in 0..n {
            if b.asleep[i] {
                continue;
            }
            let may = cfg.classes.props[b.class[i].0 as usize].can_sleep;
            if may && b.vel[i].length_squared() <= speed2 {
                b.still_ticks[i] = b.still_ticks[i].saturating_add(1);
                any_ready |= b.still_ticks[i] >= limit;
            } else {
                b.still_ticks[i] = 0;
            }
        }
        if !any_ready {
            return 0;
        }
        // Union-find over the dynamic contacts; the root is the smallest slot (deterministic).
        let down = w.config.sleeps_in_parts();
        dynamic_pairs(w, down, &mut self.pairs, &mut self.below);
        self.parent.clear();
        self.parent.extend(0..n as u32);
        fn find(parent: &mut [u32], mut x: u32) -> u32 {
            while parent[x as usize] != x {
                let up = parent[parent[x as usize] as usize];
                parent[x as usize] = up;
                x = up;
            }
            x
        }
        for &(i, j) in &self.pairs {
            let (ri, rj) = (find(&mut self.parent, i), find(&mut self.parent, j));
            if ri != rj {
                let (lo, hi) = (ri.min(rj), ri.max(rj));
                self.parent[hi as usize] = lo;
            }
        }
        let b = &mut w.bodies;
        self.ready.clear();
        self.ready.resize(n, true);
        for i in 0..n {
            if !b.asleep[i] && b.still_ticks[i] < limit {
                let r = find(&mut self.parent, i as u32) as usize;
                self.ready[r] = false;
            }
        }
        // Sleeping in parts: a body is held up while a partner below it is awake.
        self.held_up.clear();
        if down.is_some() {
            self.held_up.resize(n, false);
            for (&(i, j), &below) in self.pairs.iter().zip(&self.below) {
                let (i, j) = (i as usize, j as usize);
                if below > 0.0 && !b.asleep[j] {
                    self.held_up[i] = true;
                } else if below < 0.0 && !b.asleep[i] {
                    self.held_up[j] = true;
                }
            }
        }
        let on_its_own = |held_up: &[bool], i: usize| held_up.get(i).is_some_and(|h| !h);
        let mut count = 0;
        for i in 0..n {
            if !b.asleep[i]
                && (self.ready[find(&mut self.parent, i as u32) as usize]
                    || (b.still_ticks[i] >= limit && on_its_own(&self.held_up, i)))
            {
                b.asleep[i] = true;
                b.vel[i] = DVec3::ZERO;
                count += 1;
            }
        }
        count
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use crate::sim::output::TickOutput;
    use crate::sim::step::Stepper;
    use crate::sim::Plan;

    /// Three balls in a column on a floor under gravity, stepped until they touch: slots 0
    /// (bottom), 1 and 2 (top), every body awake.
    fn column(partial: bool) -> World {
        let ball = |y: f64| {
            format!("[[body]]\nclass = \"ball\"\nshape = {{ type = \"sphere\", radius_m = 0.5 }}\nposition = [0.0, {y}, 0.0]\n")
        };
        let text = format!(
            "[world]\nname = \"column\"\ngravity = [0.0, -9.81, 0.0]\npartial_sleep = {partial}\n\
             [[class]]\nname = \"ball\"\n[[class]]\nname = \"floor\"\nstatic = true\n\
             [[body]]\nclass = \"floor\"\nshape = {{ type = \"cuboid\", half_extents_m = [5.0, 0.5, 5.0] }}\n\
             position = [0.0, -0.5, 0.0]\n{}{}{}",
            ball(0.5),
            ball(1.5),
            ball(2.5)
        );
        let mut w = Scene::parse(&text, "<column>").unwrap().world;
        let mut stepper = Stepper::new(Plan::for_world(&w), false);
        for _ in 0..4 {
            stepper.step(&mut w, &[], &mut TickOutput::default());
        }
        let (mut pairs, mut below) = (Vec::new(), Vec::new());
        dynamic_pairs(&w, Some(w.config.gravity), &mut pairs, &mut below);
        assert_eq!(pairs, vec![(0, 1), (1, 2)], "the column touches");
        assert!(below.iter().all(|&s| s < 0.0), "each higher id lies above: {below:?}");
        assert!(!w.bodies.asleep.contains(&true));
        w
    }

    /// Still ticks for each slot (the middle one moved lately), and the bodies asleep after one
    /// pass of the rule.
    fn pass(w: &mut World, still: [u32; 3]) -> Vec<bool> {
        let limit = w.config.sleep_after_ticks;
        for (s, k) in still.into_iter().enumerate() {
            if !w.bodies.asleep[s] {
                // The pass counts this tick: one short of `limit` reaches it.
                w.bodies.still_ticks[s] = (k.min(limit) as u16).saturating_sub(1);
                w.bodies.vel[s] = DVec3::ZERO;
            }
        }
        Islands::default().fall_asleep(w);
        w.bodies.asleep.clone()
    }

    /// Sleeping in parts, a pile sleeps from the bottom up past a body that still moves: the
    /// bottom ball, on the floor, sleeps though the middle one moved; the top one waits for the
    /// middle one; the middle one sleeps on the bottom one though the top one moved. A whole
    /// island waits for its last body.
    #[test]
    fn a_column_sleeps_from_the_bottom_up() {
        let mut w = column(true);
        let limit = w.config.sleep_after_ticks;
        assert_eq!(pass(&mut w, [limit, 0, limit]), vec![true, false, false]);
        assert_eq!(pass(&mut w, [limit, limit, 0]), vec![true, true, false], "on its sleeping support");
        assert_eq!(pass(&mut w, [limit, limit, limit]), vec![true, true, true]);

        let mut whole = column(false);
        assert_eq!(pass(&mut whole, [limit, 0, limit]), vec![false; 3]);
        assert_eq!(pass(&mut whole, [limit, limit, limit]), vec![true; 3]);
    }

    /// Sleeping in parts, a woken body wakes what rests on it and not what it rests on; a whole
    /// island wakes whole.
    #[test]
    fn a_wake_spreads_up() {
        for (partial, woke) in [(true, vec![true, false, false]), (false, vec![false; 3])] {
            let mut w = column(partial);
            let limit = w.config.sleep_after_ticks;
            while w.bodies.asleep.contains(&false) {
                pass(&mut w, [limit; 3]);
            }
            assert_eq!(Islands::default().wake(&mut w, &[1]), if partial { 2 } else { 3 });
            assert_eq!(w.bodies.asleep, woke, "partial_sleep = {partial}");
            assert!(w.bodies.still_ticks[1..].iter().all(|&t| t == 0));
        }
    }
}
