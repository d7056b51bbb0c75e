//! A standby: a second process for a world that follows its primary and takes over when the
//! primary dies.
//!
//! It starts from the primary's checkpoint (the complete state after the last confirmed tick),
//! then steps every confirmed tick of the input log and checks the state hash the log carries.
//! Beside the log it keeps what the primary admitted but has not confirmed yet (`log/admitted`)
//! and the events the primary published for those ticks (`events`, `corrections`). When the
//! primary's liveliness token goes, it re-simulates the ticks since the last confirmed one with
//! every acked input, publishes the difference from what clients hold as a correction (a takeover
//! looks like one more rollback), declares the world's subscriber, queryables and token, and
//! welcomes every present client again so it re-anchors its clock. Ticks the primary confirmed
//! are never published again; ticks it did not confirm are confirmed by the standby, once. The
//! primary puts a tick's log entry before its confirmed events, so a primary killed between the
//! two leaves a tick logged but not confirmed: the standby keeps the two marks apart.

use super::recent::KEPT_TICKS;
use super::{Control, RuntimeError, TickLoop};
use crate::rollback::log::{self, ConfirmedTick};
use crate::rollback::{Advance, Session};
use crate::runtime::owner::{epoch_of, reachable, Owner, HOLD_REACHABLE};
use impact_core::sim::{SystemAction, TickInput};
use impact_protocol::{
    decode, keys, Admitted, CollisionEvent, Encoding, EventBatch, EventKey, LogTick, ServerMessage, Tick, WorldId,
};
use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};
use zenoh::Wait;

/// Messages the follower's callbacks pass to the tick thread. A full queue drops the message and
/// counts it: the standby then starts again from a checkpoint.
const FOLLOW_QUEUE: usize = 16_384;

/// Log entries held while no checkpoint has been restored yet (the checkpoint's tick is among
/// them or later).
const EARLY_LOG: usize = 4_096;

/// The most a takeover simulates beyond the primary's last tick for the time it was silent.
const MAX_CATCH_UP: Duration = Duration::from_secs(10);

/// How long a standby watches its own links after the primary's token went, before it takes
/// over: a link lost under the standby itself is reported a little after the tokens that went
/// with it.
const LINKS_SETTLE: Duration = Duration::from_millis(200);

/// The largest reply a checkpoint may be (a world of `max_bodies` bodies fits).
const MAX_CHECKPOINT_BYTES: usize = 256 << 20;

/// The newest ticks an earlier primary published on the log and on the confirmed stream: a
/// standby that took over publishes neither again for a tick up to its mark.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Published {
    log: Option<Tick>,
    confirmed: Option<Tick>,
}

impl Published {
    /// Whether the earlier primary put `t` on the log.
    pub(super) fn logged(&self, t: Tick) -> bool {
        self.log.is_some_and(|c| t <= c)
    }

    /// Whether the earlier primary published `t`'s confirmed events.
    pub(super) fn confirmed(&self, t: Tick) -> bool {
        self.confirmed.is_some_and(|c| t <= c)
    }
}

enum Followed {
    Log(LogTick),
    Confirmed(EventBatch),
    Admitted(Admitted),
    Published(ServerMessage),
    PrimaryUp,
    PrimaryDown,
}

/// The subscriptions a standby follows its primary through.
pub(super) struct Follower {
    rx: Receiver<Followed>,
    lost: Arc<AtomicU64>,
    _subs: Vec<zenoh::pubsub::Subscriber<()>>,
}

impl Follower {
    /// Subscribes to the world's log, admitted inputs, published and confirmed events and server
    /// token.
    pub(super) fn start(zs: &zenoh::Session, world: &WorldId, owner: &Arc<Owner>) -> Result<Follower, RuntimeError> {
        let (tx, rx) = sync_channel::<Followed>(FOLLOW_QUEUE);
        let lost = Arc::new(AtomicU64::new(0));
        let mut subs = Vec::new();
        for pattern in [keys::LOG, keys::LOG_ADMITTED, keys::EVENTS, keys::CORRECTIONS, keys::CONFIRMED] {
            let (tx, lost, owner) = (tx.clone(), lost.clone(), owner.clone());
            let sub = zs
                .declare_subscriber(pattern.key(world, None))
                .callback(move |sample| {
                    if let Some(e) = epoch_of(&sample) {
                        owner.heard(e);
                    }
                    let enc = Encoding::from_zenoh_tag(&sample.encoding().to_string()).unwrap_or(Encoding::MsgPack);
                    let bytes = sample.payload().to_bytes();
                    let msg = match decode::<ServerMessage>(&bytes, enc, MAX_CHECKPOINT_BYTES) {
                        Ok(ServerMessage::Log(l)) => Followed::Log(l),
                        Ok(ServerMessage::Admitted(a)) => Followed::Admitted(a),
                        Ok(ServerMessage::Confirmed(b)) => Followed::Confirmed(b),
                        Ok(m @ (ServerMessage::Events(_) | ServerMessage::Corrections(_))) => Followed::Published(m),
                        _ => return,
                    };
                    if tx.try_send(msg).is_err() {
                        lost.fetch_add(1, Ordering::Relaxed);
                    }
                })
                .wait()
                .map_err(|e| RuntimeError::Zenoh(format!("declaring the standby's subscriber: {e}")))?;
            subs.push(sub);
        }
        let primary = zs
            .liveliness()
            .declare_subscriber(keys::SERVER.key(world, None))
            .history(true)
            .callback(move |sample| {
                let m = match sample.kind() {
                    zenoh::sample::SampleKind::Put => Followed::PrimaryUp,
                    zenoh::sample::SampleKind::Delete => Followed::PrimaryDown,
                };
                // Blocking here would stall Zenoh; the token's news is never dropped in practice
                // (one message per primary), and a lost one is seen again on the next change.
                let _ = tx.try_send(m);
            })
            .wait()
            .map_err(|e| RuntimeError::Zenoh(format!("declaring the standby's liveliness subscriber: {e}")))?;
        subs.push(primary);
        Ok(Follower { rx, lost, _subs: subs })
    }
}

/// The avatars a tick's server actions remove.
fn removed_by(system: &[SystemAction]) -> Vec<impact_protocol::EntityId> {
    system
        .iter()
        .filter_map(|a| match a {
            SystemAction::Remove { entity } => Some(*entity),
            SystemAction::SpawnAvatar { .. } => None,
        })
        .collect()
}

/// What the standby knows of the ticks its primary has not confirmed.
#[derive(Default)]
struct Unconfirmed {
    /// Server actions and acked inputs, by the tick they apply at.
    admitted: BTreeMap<u32, (Vec<SystemAction>, Vec<TickInput>)>,
    /// Events as the primary published them (with their latest revision), by tick.
    published: BTreeMap<u32, (BTreeMap<EventKey, CollisionEvent>, u32)>,
    /// The newest tick the primary said it was at.
    newest: Option<Tick>,
    /// The newest tick the primary confirmed the events of.
    confirmed: Option<Tick>,
    /// The confirmed batches heard, until kept for `query/confirmed` (see
    /// [`TickLoop::keep_heard`]), at most [`KEPT_TICKS`].
    batches: VecDeque<EventBatch>,
    /// When the primary last said anything (a log entry, admitted inputs, events).
    heard: Option<Instant>,
}

impl Unconfirmed {
    /// Forgets the inputs up to the logged tick `t`: the log has them now.
    fn logged(&mut self, t: Tick) {
        self.admitted = self.admitted.split_off(&(t.0 + 1));
    }

    /// Forgets the events up to the confirmed tick `b.tick` (clients have them as final), and
    /// holds the batch to keep.
    fn confirmed(&mut self, b: EventBatch) {
        let t = b.tick;
        self.confirmed = self.confirmed.max(Some(t));
        self.published = self.published.split_off(&(t.0 + 1));
        if self.batches.len() >= KEPT_TICKS {
            self.batches.pop_front();
        }
        self.batches.push_back(b);
    }

    fn admit(&mut self, a: Admitted, avatar: log::AvatarShape<'_>) -> Result<(), String> {
        self.newest = self.newest.max(Some(a.tick));
        let system = a.system.iter().map(|s| log::system_action(s, avatar)).collect::<Result<Vec<_>, _>>()?;
        self.admitted.entry(a.tick.0).or_default().0.extend(system);
        for i in a.inputs {
            let t = i.tick.0;
            self.admitted.entry(t).or_default().1.push(log::pending_input(i));
        }
        Ok(())
    }

    fn publish(&mut self, m: ServerMessage) {
        match m {
            ServerMessage::Events(b) => {
                self.newest = self.newest.max(Some(b.tick));
                let t = self.published.entry(b.tick.0).or_default();
                t.0.extend(b.events.into_iter().map(|e| (e.key(), e)));
            }
            ServerMessage::Corrections(c) => {
                let t = self.published.entry(c.tick.0).or_default();
                for e in &c.retracted {
                    t.0.remove(&e.key());
                }
                t.0.extend(c.amended.into_iter().chain(c.added).map(|e| (e.key(), e)));
                t.1 = c.revision;
            }
            _ => {}
        }
    }
}

impl TickLoop {
    /// Follows the primary until it goes (then takes over and returns `true`) or the stop flag
    /// is set (`false`).
    pub(super) fn follow(
        &mut self,
        f: Follower,
        stop: &AtomicBool,
        zs: &zenoh::Session,
        control: &Receiver<Control>,
    ) -> bool {
        let avatar_rule = self.avatar.clone();
        let avatar = avatar_rule.as_ref().map(|a| (a.class, &a.shape));
        let mut synced = false;
        let mut early: VecDeque<LogTick> = VecDeque::new();
        let mut pending = Unconfirmed::default();
        let mut primary_up = false;
        // When the primary's token went, and when this process last reached nobody itself.
        let (mut down, mut unreachable_at): (Option<Instant>, Option<Instant>) = (None, None);
        let mut asked: Option<Instant> = None;
        let mut refused: Option<String> = None;
        let mut lost_seen = 0;
        let mut last_status = Instant::now();
        let (verbose, world) = (self.opts.verbose, self.world.clone());
        let say = move |msg: String| {
            if verbose {
                eprintln!("  standby {world}: {msg}");
            }
        };
        say("waiting for the primary".into());
        loop {
            if stop.load(Ordering::SeqCst) {
                return false;
            }
            self.presence(control);
            self.watch_own_link(zs);
            let lost = f.lost.load(Ordering::Relaxed);
            if lost != lost_seen {
                lost_seen = lost;
                if synced {
                    say(format!("{lost} followed messages lost so far: starting again from a checkpoint"));
                }
                synced = false;
            }
            if !synced && primary_up && asked.is_none_or(|t| t.elapsed() > Duration::from_secs(1)) {
                asked = Some(Instant::now());
                match self.restore(zs) {
                    Ok(()) => {
                        synced = true;
                        say(format!("following from the checkpoint of tick {}", self.session.now().0));
                        // The log entries that came while the checkpoint was on its way.
                        for l in early.drain(..) {
                            if !self.follow_tick(l, avatar, &mut synced) {
                                break;
                            }
                        }
                    }
                    // Said once per reason, verbose or not: a standby that cannot follow (a
                    // primary with other settings) must not be silent about it.
                    Err(e) if refused.as_ref() != Some(&e) => {
                        eprintln!("impact-server: standby {}: no checkpoint restored yet: {e}", self.world);
                        refused = Some(e);
                    }
                    Err(_) => {}
                }
            }
            if self.opts.verbose && synced && last_status.elapsed() >= Duration::from_secs(1) {
                last_status = Instant::now();
                eprintln!(
                    "  standby {}: confirmed tick {} followed ({} ticks, {} hashes differed), {} clients present",
                    self.world,
                    self.session.now().0.saturating_sub(1),
                    self.summary.followed_ticks,
                    self.summary.desyncs,
                    self.clients.values().filter(|c| c.present).count()
                );
            }
            // A standby that was cut off itself saw the token go too, and must not take over:
            // its links are watched for a moment after the token went (Zenoh reports the token
            // gone a little before the link), and after being cut off it waits for the primary
            // to come back through the restored links.
            if let Some(d) = down.filter(|_| synced) {
                if !reachable(zs) {
                    if unreachable_at.is_none() {
                        say(format!(
                            "cut off from every router and peer ({} ms after the primary's token went): not taking \
                             over until back and the primary still gone",
                            d.elapsed().as_millis()
                        ));
                    }
                    unreachable_at = Some(Instant::now());
                } else if d.elapsed() >= LINKS_SETTLE && unreachable_at.is_none_or(|t| t.elapsed() >= HOLD_REACHABLE) {
                    self.take_over(pending);
                    return true;
                }
            }
            self.keep_heard(&mut pending.batches, synced.then(|| self.session.now()));
            let got = f.rx.recv_timeout(Duration::from_millis(20));
            if let Ok(Followed::Log(_) | Followed::Admitted(_) | Followed::Published(_) | Followed::Confirmed(_)) = &got
            {
                pending.heard = Some(Instant::now());
            }
            match got {
                Ok(Followed::Confirmed(b)) => pending.confirmed(b),
                Ok(Followed::Log(l)) => {
                    pending.logged(l.tick);
                    if synced {
                        self.follow_tick(l, avatar, &mut synced);
                    } else {
                        if early.len() >= EARLY_LOG {
                            early.pop_front();
                        }
                        early.push_back(l);
                    }
                }
                Ok(Followed::Admitted(a)) => {
                    if let Err(e) = pending.admit(a, avatar) {
                        say(e);
                    }
                }
                Ok(Followed::Published(m)) => pending.publish(m),
                Ok(Followed::PrimaryUp) => {
                    if down.take().is_some() {
                        say("the primary is back".into());
                    }
                    primary_up = true;
                }
                Ok(Followed::PrimaryDown) => {
                    primary_up = false;
                    if synced {
                        down = Some(Instant::now());
                    } else {
                        say("the primary went before this standby had its state: waiting for another".into());
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => return false,
            }
        }
    }

    /// Keeps the confirmed batches heard from the primary for `query/confirmed`, as they went
    /// out, with their bodies' owners: those of the ticks before `before` (the present of a
    /// replica in step: a tick's log may come after its batch; none while it is not).
    fn keep_heard(&mut self, heard: &mut VecDeque<EventBatch>, before: Option<Tick>) {
        while let Some(b) = heard.front().filter(|b| before.is_some_and(|t| b.tick < t)) {
            let owners = self.owners(&b.events, b.tick);
            let b = heard.pop_front().expect("looked at");
            self.recent.keep(b, owners);
        }
    }

    /// Asks the primary for its checkpoint and continues from it.
    fn restore(&mut self, zs: &zenoh::Session) -> Result<(), String> {
        let selector = format!("{}?encoding=msgpack", keys::QUERY_CHECKPOINT.key(&self.world, None));
        let replies = zs.get(selector).timeout(Duration::from_secs(5)).wait().map_err(|e| e.to_string())?;
        let reply = replies.recv().map_err(|_| "no server answered".to_string())?;
        let sample = reply.result().map_err(|e| format!("the server answered with an error: {e:?}"))?;
        if let Some(e) = epoch_of(sample) {
            self.shared.owner.heard(e);
        }
        let bytes = sample.payload().to_bytes();
        let c = match decode::<ServerMessage>(&bytes, Encoding::MsgPack, MAX_CHECKPOINT_BYTES) {
            Ok(ServerMessage::Checkpoint(c)) => c,
            Ok(ServerMessage::QueryError(e)) => return Err(e.detail),
            Ok(_) => return Err("the checkpoint query was answered with another message".into()),
            Err(e) => return Err(e.to_string()),
        };
        let cfg = self.session.config().clone();
        let plan = impact_core::sim::Plan::for_world(self.session.world());
        let mut session = Session::restore(self.session.world(), &c, plan, cfg)?;
        session.set_pool(self.session.stepper().pool().clone());
        self.session = session;
        for cl in &c.clients {
            if let Some(avatar) = cl.avatar {
                let state = self.new_client(cl.client, false, None, self.opts.encoding);
                self.clients.entry(cl.client).or_insert(state).avatar = Some(avatar);
            }
        }
        Ok(())
    }

    /// Steps one confirmed tick of the log; a gap or an undecodable entry clears `synced`.
    /// Returns whether it was stepped.
    fn follow_tick(&mut self, l: LogTick, avatar: log::AvatarShape<'_>, synced: &mut bool) -> bool {
        let now = self.session.now();
        if l.tick < now {
            return true; // before the checkpoint
        }
        if l.tick > now {
            *synced = false; // a gap: start again from a checkpoint
            return false;
        }
        let t = match ConfirmedTick::from_wire(l, avatar) {
            Ok(t) => t,
            Err(e) => {
                eprintln!("  standby {}: {e}", self.world);
                *synced = false;
                return false;
            }
        };
        let removed = removed_by(&t.system);
        if let Err(e) = self.session.follow(t.tick, t.system, t.inputs) {
            eprintln!("  standby {}: {e}", self.world);
            *synced = false;
            return false;
        }
        let adv = self.session.advance();
        self.summary.ticks += 1;
        self.summary.followed_ticks += 1;
        if self.session.world().state_hash() != t.state_hash {
            self.summary.desyncs += 1;
            eprintln!(
                "  standby {}: tick {} ends with another state hash than the primary's: is the scene file the same?",
                self.world, t.tick.0
            );
        }
        self.track_avatars(&adv, &removed);
        true
    }

    /// Keeps the clients' avatars as the log spawns and removes them. The log runs a window
    /// behind the presence this server hears: a client whose grace ran out on the primary may be
    /// back already when the log removes its old avatar. It stays, present, without an avatar
    /// until the log spawns its new one (or, after a takeover, it joins anew): dropping it would
    /// leave a present client taken for gone, whose new avatar the takeover then removes.
    fn track_avatars(&mut self, adv: &Advance, removed: &[impact_protocol::EntityId]) {
        for (client, entity) in &adv.spawned {
            let state = self.new_client(*client, false, None, self.opts.encoding);
            self.clients.entry(*client).or_insert(state).avatar = Some(*entity);
        }
        for entity in removed {
            let gone: Vec<_> =
                self.clients.iter().filter(|(_, s)| s.avatar == Some(*entity)).map(|(c, _)| *c).collect();
            for c in gone {
                self.session.forget_client(c);
                match self.clients.get_mut(&c) {
                    Some(s) if s.present => s.avatar = None,
                    _ => {
                        self.clients.remove(&c);
                    }
                }
            }
        }
    }

    /// The primary is gone: re-simulate its unconfirmed ticks with every input it acked, and
    /// publish them as this server's.
    fn take_over(&mut self, mut pending: Unconfirmed) {
        self.keep_heard(&mut pending.batches, Some(Tick(u32::MAX)));
        // Owned above every epoch heard: the old primary, if it comes back, is fenced by it.
        let owner = self.shared.owner.clone();
        owner.own(owner.newest().next());
        let from = self.session.now();
        // Followed without a gap: every tick before the present one is logged. The confirmed
        // events of the last of them may not be out (the primary went between the two puts).
        let logged = from.0.checked_sub(1).map(Tick);
        self.earlier = Published { log: logged, confirmed: pending.confirmed.min(logged) };
        // Logged but not confirmed: this session confirms them when they leave its window, at
        // the revision clients hold.
        let mut corrections = Vec::new();
        for (k, (events, revision)) in pending.published.range(..from.0) {
            corrections.extend(self.session.adopt(Tick(*k), events.values().cloned().collect(), *revision));
        }
        pending.published = pending.published.split_off(&from.0);
        // The primary had simulated up to its newest tick: the last logged one plus the window,
        // or the newest it said anything about.
        let window = self.session.config().window_ticks;
        let by_window = logged.map(|c| Tick(c.0 + window));
        let primary_at = by_window.max(pending.newest).unwrap_or(from).max(from);
        // ... when it last said anything. The world's clock goes on from where the primary's
        // would be now, so the clients' clocks (which ran on) stay right: the ticks it was
        // silent for are simulated too, with no inputs (none reached a server then).
        let hz = f64::from(self.session.world().config.tick_hz);
        let silent = pending.heard.map_or(Duration::ZERO, |t| t.elapsed()).min(MAX_CATCH_UP);
        let to = Tick(primary_at.0 + (silent.as_secs_f64() * hz) as u32);
        for k in from.0..=to.0 {
            let (system, inputs) = pending.admitted.remove(&k).unwrap_or_default();
            self.summary.reapplied_inputs += inputs.len() as u64;
            // The primary's own removals (a client's grace ran out) leave the client table as
            // following the log does: a client back later joins anew, not to a removed avatar.
            let removed = removed_by(&system);
            if let Err(e) = self.session.follow(Tick(k), system, inputs) {
                eprintln!("  standby {}: {e}", self.world);
            }
            let mut adv = self.session.advance();
            self.track_avatars(&adv, &removed);
            self.summary.ticks += 1;
            self.summary.caught_up_ticks += 1;
            if let Some((events, revision)) = pending.published.remove(&k) {
                // Clients hold the primary's events for this tick: correct them, if need be.
                adv.events.clear();
                adv.corrections = self.session.adopt(Tick(k), events.into_values().collect(), revision);
            }
            adv.corrections.splice(0..0, std::mem::take(&mut corrections));
            self.publish(adv);
        }
        // Inputs acked for ticks still ahead.
        // (Server actions apply at the tick they were queued at, all simulated above.)
        for (k, (_, inputs)) in std::mem::take(&mut pending.admitted) {
            self.summary.reapplied_inputs += inputs.len() as u64;
            if let Err(e) = self.session.follow(Tick(k), Vec::new(), inputs) {
                eprintln!("  standby {}: {e}", self.world);
            }
        }
        self.summary.promoted_at = Some(self.session.now());
        eprintln!(
            "impact-server: world {}: the primary is gone; took over at tick {} as epoch {} (logged up to {}, confirmed up to {}, {} ticks re-simulated, {} acked inputs re-applied)",
            self.world,
            self.session.now().0,
            owner.newest(),
            self.earlier.log.map_or(-1, |t| i64::from(t.0)),
            self.earlier.confirmed.map_or(-1, |t| i64::from(t.0)),
            self.summary.caught_up_ticks,
            self.summary.reapplied_inputs
        );
    }

    /// After a takeover: every present client is welcomed again (its avatar and the new tick),
    /// a present client with no avatar joins, and an absent one starts its grace period.
    pub(super) fn reanchor(&mut self) {
        let now = self.session.now();
        let clients: Vec<_> = self.clients.iter().map(|(c, s)| (*c, s.present, s.avatar)).collect();
        for (client, present, avatar) in clients {
            match (present, avatar) {
                (true, Some(a)) => self.welcome(client, Some(a)),
                (true, None) => {
                    self.clients.remove(&client);
                    self.join(client);
                }
                (false, _) => {
                    let at = now.0 + self.opts.grace_ticks;
                    if let Some(s) = self.clients.get_mut(&client) {
                        s.leave_at = Some(at);
                    }
                    self.note_leave(at);
                }
            }
        }
    }
}
