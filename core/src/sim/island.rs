//! Islands: dynamic bodies joined by touching contacts. An island falls asleep whole, when every
//! body in it has been still long enough, and wakes whole, when anything disturbs one of its
//! bodies. Both walk the touching list in its sorted order over slots in id order, so the
//! result never depends on anything but the world.

use crate::sim::world::World;

/// Slots of the touching list's dynamic pairs, `(slot a, slot b)`, in list order; static and
/// terrain partners join no island (a floor does not make everything on it one island).
fn dynamic_pairs(w: &World, out: &mut Vec<(u32, u32)>) {
    out.clear();
    let (mut ca, mut cb) = (0, 0);
    let b = &w.bodies;
    for t in &w.touching {
        if let (Some(i), Some(j)) = (b.slot_from(&mut ca, t.a), b.slot_from(&mut cb, t.b)) {
            out.push((i as u32, j as u32));
        }
    }
}

/// Reusable buffers for island work (no allocation per tick once warm).
#[derive(Debug, Default)]
pub(crate) struct Islands {
    pairs: Vec<(u32, u32)>,
    parent: Vec<u32>,
    ready: Vec<bool>,
    woken: Vec<bool>,
}

impl Islands {
    /// Wakes the islands of the sleeping bodies in `seeds` (slots): every sleeping body joined
    /// to one of them through touching sleeping bodies wakes, keeping its zero velocity, with its
    /// still timer reset. Returns how many bodies woke.
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
        dynamic_pairs(w, &mut self.pairs);
        let b = &mut w.bodies;
        // Spread along contacts to a fixpoint; each pass wakes at least one body or ends, so at
        // most as many passes as the island is long (sorted pairs usually need one or two).
        loop {
            let mut spread = false;
            for &(i, j) in &self.pairs {
                let (i, j) = (i as usize, j as usize);
                for (from, to) in [(i, j), (j, i)] {
                    if self.woken[from] && wake_one(b, &mut self.woken, to) {
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
    /// in an island count as ready. Returns how many bodies fell asleep.
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
        dynamic_pairs(w, &mut self.pairs);
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
        let mut count = 0;
        for i in 0..n {
            if !b.asleep[i] && self.ready[find(&mut self.parent, i as u32) as usize] {
                b.asleep[i] = true;
                b.vel[i] = glam::DVec3::ZERO;
                count += 1;
            }
        }
        count
    }
}
