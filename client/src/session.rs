//! The session: one client's side of the protocol as a state machine. A transport feeds it what
//! arrived ([`Session::receive`]) and sends what it gives ([`Session::poll_transmit`]); the game
//! gives it actions ([`Session::input`]) and reads its views each frame. Nothing here does I/O or
//! reads a clock: every call takes the local instant.
//!
//! Its life (PROTOCOL.md, "Presence" and "`ping` (time sync)"):
//!
//! 1. **Joining**: the transport declared the client's presence; the session waits for its
//!    [`Welcome`] (its avatar, the tick rate, the window, the seq to resume from).
//! 2. **Syncing**: it probes the server's clock ([`ClientMessage::Ping`]), one probe at a time,
//!    [`SYNC_PROBES`] answers or [`SYNC_TIMEOUT`] at most. The answer that came back soonest
//!    anchors the clock (NTP's minimum-delay sample), the slowest round trip sets the first lead
//!    (so the first inputs are on time, not a round trip late until an ack recommends a lead).
//! 3. **Playing**: inputs are stamped ahead by the lead the acks recommend, numbered, and sent
//!    with up to [`SessionConfig::redundancy`] unanswered inputs before them in one
//!    [`ClientMessage::Inputs`] (one lost message loses no input; the server applies each seq
//!    once and skips repeats without an answer). Inputs of the game's still unanswered when it
//!    has made none for [`KEEPALIVE_AFTER`] bring an input of no actions, whose ack tells which
//!    of them never reached the server.
//!
//! A second welcome (the session reconnected within the server's grace period) resumes: the
//! inputs the server says it accepted are dropped from the resend set, the seqs go on from the
//! server's `next_seq`, and the clock is re-anchored.
//!
//! Every buffer is bounded: [`Outbox::DEFAULT_CAPACITY`] inputs awaiting an answer,
//! [`SessionConfig::redundancy`] inputs for resending, [`MAX_OUTGOING`] messages not yet taken
//! by the transport, [`MAX_RAY_RESULTS`] ray results, [`MAX_ANSWERS`] answers and
//! [`MAX_EVENT_NEWS`] event news not yet taken by the game, and the views'
//! own bounds ([`crate::events::MAX_TICKS`], [`RemoteConfig`]).

use crate::clock::Clock;
use crate::events::EventView;
use crate::inputs::{Outbox, Sent};
use crate::predict::{PredictConfig, PredictError, Predictor, Reconciled};
use crate::remote::{DrawnBody, RemoteConfig, RemoteWorld};
use impact_core::scene::SceneRules;
use impact_protocol::limits::{MAX_ACTIONS_PER_INPUT, MAX_INPUTS_PER_MESSAGE};
use impact_protocol::serial::precedes;
use impact_protocol::{
    Action, ClientId, ClientInput, ClientMessage, CollisionEvent, CorrectionBatch, EntityId, Epoch, EventBatch,
    FullFrameRequest, InputBatch, RayResult, RejectReason, SceneDescription, ServerMessage, Stamp, Tick, TimePing,
    Welcome, WorldClosed,
};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant};

/// Round trips measured before play: five, as a few NTP polls pick their best from eight.
pub const SYNC_PROBES: usize = 5;

/// The longest the sync waits for its probes (a server that does not answer them, or a lossy
/// link): then play starts with what it has, or with the acks' lead alone.
pub const SYNC_TIMEOUT: Duration = Duration::from_secs(2);

/// While the state stream waits for a full frame (after a gap), one is asked for this often.
pub const FULL_FRAME_EVERY: Duration = Duration::from_millis(250);

/// The game's inputs awaiting an answer while it makes none for this long: the session sends an
/// input of no actions (a keepalive, [`SessionStats::keepalives`]), again each time this passes,
/// until none of the game's awaits one. Nothing else tells what became of an input sent just
/// before the game fell idle: an input is known lost only by an ack of a later one (PROTOCOL.md,
/// "Messages lost or late"), and one sent into a server that stood still, or a link that dropped
/// it, would wait forever. A second is several round trips and leads: an input's answer
/// that has not come by then is late or lost; a game that sends every tick never needs one. Only
/// inputs an ack can tell about bring them: within [`KEEPALIVE_REACH`] seqs of the next.
pub const KEEPALIVE_AFTER: Duration = Duration::from_secs(1);

/// How far back a keepalive's ack tells: its `accepted_before` covers the 64 seqs before it. So
/// an idle game sends at most 64 keepalives for one input (a server gone for good does not fill
/// the outbox with them).
pub const KEEPALIVE_REACH: u32 = 64;

/// A probe unanswered this long is taken as lost, and the next one is sent.
pub const PROBE_TIMEOUT: Duration = Duration::from_millis(250);

/// How long a tick in doubt (its own confirmed batch missed, see [`crate::events`]) waits for the
/// batch the server kept (`query/confirmed`, asked by the transport through
/// [`Session::poll_recovery`]) before it is taken as having no events for this client.
pub const RECOVERY_WAIT: Duration = Duration::from_secs(2);

/// Messages held for the transport at most; past it the oldest is dropped and counted (a
/// transport that stopped taking them).
pub const MAX_OUTGOING: usize = 256;

/// Ray results held for the game at most; past it the oldest is dropped.
pub const MAX_RAY_RESULTS: usize = 256;

/// Answers to inputs held for the game at most; past it the oldest is dropped.
pub const MAX_ANSWERS: usize = 1024;

/// Event news held for the game at most ([`Session::take_event_news`]); past it the oldest is
/// dropped (a game that never takes them loses nothing else: the event view holds the events).
pub const MAX_EVENT_NEWS: usize = 4096;

/// What changed in the event view, in arrival order, for a game that reacts to events as they
/// come (a flash at a contact point, a sound) rather than reading the view a tick at a time.
#[derive(Clone, Debug, PartialEq)]
pub enum EventNews {
    /// A provisional event, as the server first published it.
    Event(CollisionEvent),
    /// A re-simulation changed a tick's events: some retracted, amended or added (a game redraws
    /// what it showed; events match by identity, [`CollisionEvent::key`]).
    Corrected(CorrectionBatch),
    /// A tick is final; `matched` says whether the view as it stood equalled the server's record.
    /// Every tick the view held hears this once, in tick order: a tick with no confirmed batch of
    /// its own (none of its final events involve this client) is final when a later one is.
    Confirmed {
        /// The tick.
        tick: Tick,
        /// The view equalled the confirmed batch.
        matched: bool,
    },
}

/// Queues news under [`MAX_EVENT_NEWS`], dropping (and counting) the oldest.
fn push_news(news: &mut VecDeque<EventNews>, dropped: &mut u64, n: EventNews) {
    if news.len() >= MAX_EVENT_NEWS {
        news.pop_front();
        *dropped += 1;
    }
    news.push_back(n);
}

/// The server's answer to one of the client's inputs ([`Session::take_answers`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Answer {
    /// The input's seq ([`Session::input`] returned it).
    pub seq: u32,
    /// The tick it was stamped for.
    pub tick: Tick,
    /// When it was first sent.
    pub sent: Instant,
    /// From its first sending to its answer.
    pub round_trip: Duration,
    /// What the server did with it.
    pub outcome: Outcome,
}

/// The seqs an ack of `seq` says were accepted before it (`InputAck::accepted_before`), nearest
/// first.
pub fn accepted_before(seq: u32, bits: u64) -> impl Iterator<Item = u32> {
    (0..64u32).filter(move |k| bits & (1 << k) != 0).map(move |k| seq.wrapping_sub(k + 1)).filter(|&s| s != 0)
}

/// The client's own keys, each numbering its messages apart ([`Stamp::number`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum OwnKey {
    /// `client/{id}/ack`: answers, welcomes, pongs, ray results, the closing notice.
    Ack,
    /// `client/{id}/events`: `events`, `corrections` and `confirmed` batches.
    Events,
    /// `client/{id}/state`.
    State,
}

impl OwnKey {
    const COUNT: usize = 3;

    /// The key a message of this kind comes on.
    fn of(msg: &ServerMessage) -> OwnKey {
        match msg {
            ServerMessage::Events(_) | ServerMessage::Corrections(_) | ServerMessage::Confirmed(_) => OwnKey::Events,
            ServerMessage::State(_) => OwnKey::State,
            _ => OwnKey::Ack,
        }
    }
}

/// The numbers of one key's messages as they arrive ([`Stamp::number`]). Each owner counts
/// anew: start again ([`KeyNumbers::default`]) with a newer epoch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KeyNumbers {
    last: Option<u64>,
}

impl KeyNumbers {
    /// Message `n` arrived: how many before it were lost since the last one heard (or, for the
    /// first one heard, since the owner's first on the key: a subscription the server's messages
    /// did not reach at once). None when `n` follows it, and none when `n` is not past it (the
    /// server's count started again: it forgot the key).
    pub fn heard(&mut self, n: u64) -> u64 {
        let lost = n.saturating_sub(self.last.unwrap_or(0)).saturating_sub(1);
        self.last = Some(n);
        lost
    }
}

/// See [`Session::lost_at_welcome`].
#[derive(Clone, Copy, Debug)]
struct LostCheck {
    /// When the welcome came.
    welcomed: Instant,
    /// The welcome's `next_seq`.
    next_seq: u32,
}

/// How long a tick a message named stands as evidence of the server's present
/// ([`Session::link_restored`]): run on at the full rate, it overestimates a server that stalled
/// since, and only for this long.
const NAMED_FOR: Duration = Duration::from_secs(10);

/// What the server did with an input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Applied at `applied_tick`; `margin_ticks` is how many ticks before that tick began it
    /// arrived (negative: late, the server rolled back for it).
    Accepted {
        /// The tick it was applied at.
        applied_tick: Tick,
        /// Arrival margin, ticks.
        margin_ticks: i32,
    },
    /// Accepted, as a later ack said (`accepted_before`): its own ack was lost on the way, so
    /// the tick it was applied at and its margin are not known.
    AckLost,
    /// Refused, for this reason (PROTOCOL.md, "Rejects").
    Rejected(RejectReason),
    /// Never reached the server: the welcome after a reconnect or a takeover (`next_seq`) said
    /// it was not accepted, it was last sent before that welcome, and an input made after the
    /// welcome was acked while it was unanswered; or an input made after its last copy went was
    /// acked, and that ack does not count it accepted (a client's messages arrive in order, and
    /// its accepted inputs are acked in order, after the rejects of their tick). Its actions were
    /// not applied; send them again as a new input if they still matter. (One below a second
    /// welcome's `next_seq`, sent before the link dropped, may have been refused instead, its
    /// reject lost with the link: not applied either way.)
    Lost,
}

/// How a session behaves.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionConfig {
    /// The client id (the `{client}` of its keys).
    pub client: ClientId,
    /// Stamp inputs ahead of the server by the recommended lead (default), or with the tick the
    /// client sees (every input a round trip late; the server rolls back for each).
    pub ahead: bool,
    /// Unanswered inputs sent again before each new one (default 3, at most
    /// `MAX_INPUTS_PER_MESSAGE - 1`; 0 turns redundancy off). Copies are only added while the
    /// message's actions stay within `MAX_ACTIONS_PER_INPUT`, and only for inputs the server can
    /// still accept (not older than its window).
    pub redundancy: usize,
    /// How far behind the server's present remote bodies are drawn, seconds (default 0.1).
    pub interpolation_delay_s: f64,
    /// How the own avatar is predicted once the server's scene arrives (`query/scene`, which the
    /// transport asks): `None` predicts nothing until [`Session::predict_with`] (default: the
    /// [`PredictConfig`] defaults).
    pub predict: Option<PredictConfig>,
}

impl SessionConfig {
    /// The defaults for client `client`.
    pub fn new(client: ClientId) -> SessionConfig {
        SessionConfig {
            client,
            ahead: true,
            redundancy: MAX_INPUTS_PER_MESSAGE - 1,
            interpolation_delay_s: 0.1,
            predict: Some(PredictConfig::default()),
        }
    }
}

/// Where the session is in its life (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    /// Waiting for the welcome.
    Joining,
    /// Measuring the round trip.
    Syncing,
    /// Ready: inputs are stamped on time.
    Playing,
    /// The world closed ([`Session::closed`] says where its players go next): no more inputs.
    Closed,
}

/// Why [`Session::input`] refused actions.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum InputError {
    /// No welcome yet: the session knows neither the server's tick nor its rate.
    NotJoined,
    /// The world closed ([`Session::closed`]).
    Closed,
    /// More actions than one input may carry.
    TooManyActions {
        /// How many were given.
        count: usize,
    },
}

impl std::fmt::Display for InputError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            InputError::NotJoined => write!(f, "not joined yet: wait for the welcome (Status::Playing)"),
            InputError::Closed => write!(f, "the world closed (Session::closed says where to go next)"),
            InputError::TooManyActions { count } => {
                write!(f, "{count} actions in one input; at most {MAX_ACTIONS_PER_INPUT}")
            }
        }
    }
}

impl std::error::Error for InputError {}

/// What a session counted.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SessionStats {
    /// Welcomes received (more than one: the session reconnected).
    pub welcomes: u64,
    /// Inputs given to the transport (each once, however many times it is carried).
    pub inputs_sent: u64,
    /// Inputs acknowledged (those whose own ack was lost and a later one told included).
    pub inputs_acked: u64,
    /// Of them, inputs whose ack was lost and a later ack told accepted (`accepted_before`), or,
    /// further back than that reaches, below a welcome's `next_seq` once an ack came after it.
    pub acks_recovered: u64,
    /// Acked inputs that arrived after their tick had begun (`margin_ticks < 0`): the server
    /// rolled back for each.
    pub late_acks: u64,
    /// Inputs that never reached the server, found at a reconnect or takeover ([`Outcome::Lost`]).
    pub inputs_lost: u64,
    /// Inputs refused, by reason (rejects that name no seq included).
    pub rejects: BTreeMap<RejectReason, u64>,
    /// Acks and rejects that matched no input awaiting an answer.
    pub unmatched_answers: u64,
    /// Inputs sent again as redundant copies.
    pub copies_sent: u64,
    /// Inputs of no actions the session sent itself ([`KEEPALIVE_AFTER`]). Each is counted in
    /// `inputs_sent` too, and its answer where it falls (`inputs_acked`, `inputs_lost`, ...),
    /// but not given to the game.
    pub keepalives: u64,
    /// Provisional events received.
    pub events: u64,
    /// Correction batches applied.
    pub corrections: u64,
    /// Ray results received, and how many hit something.
    pub ray_results: u64,
    /// Ray results that hit something.
    pub hits: u64,
    /// State frames received.
    pub state_frames: u64,
    /// Round trips measured by the sync, and the shortest and longest, seconds.
    pub sync_samples: u64,
    /// Shortest sync round trip, seconds.
    pub sync_rtt_min_s: f64,
    /// Longest sync round trip, seconds.
    pub sync_rtt_max_s: f64,
    /// Times the clock re-anchored on a tick far from its estimate.
    pub clock_resyncs: u64,
    /// Messages the transport could not decode (it says so with [`Session::malformed`]).
    pub malformed: u64,
    /// Messages from an older owner of the world than one already heard (a primary that came
    /// back after a standby took over): dropped ([`Session::receive_from`]).
    pub stale_owner: u64,
    /// Times a newer owner of the world was heard after an older one (a takeover), each taken as
    /// a lost link ([`Session::receive_from`]).
    pub owner_changes: u64,
    /// Messages the server numbered on the client's keys that never arrived (a skip in a key's
    /// numbers: dropped on a congested path, or by a transport's full inbox). One on the events key
    /// is taken as a lost link ([`Session::receive_from`]).
    pub messages_lost: u64,
    /// Messages for another client, or of a kind a client does not use: skipped.
    pub skipped: u64,
    /// Full state frames asked for after a gap.
    pub full_frames_asked: u64,
    /// Outgoing messages dropped because the transport did not take them.
    pub outgoing_dropped: u64,
    /// Event news dropped because the game did not take it ([`MAX_EVENT_NEWS`]).
    pub event_news_dropped: u64,
}

/// Most prediction errors kept for the figures (about 14 hours of states at 20 Hz); past it the
/// figures are over the first ones.
pub const MAX_PREDICTION_SAMPLES: usize = 1 << 20;

/// How the own avatar's prediction fared: every authoritative state compared with the
/// prediction for its tick.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PredictionStats {
    /// Authoritative states compared with a prediction.
    pub compared: u64,
    /// ...of which equal to the bit.
    pub exact: u64,
    /// States taken without a prediction to compare (the first, a new avatar).
    pub taken: u64,
    /// States that named a teleport by game logic the prediction could not know: taken and
    /// drawn there at once, not compared.
    pub teleported: u64,
    /// Mispredictions by cause, each classified when the next state arrives (what explains it,
    /// an event correction or an ack, travels on other keys and may come just after it):
    /// `other_body` (another body collided with the avatar, by its events, or came within reach
    /// of it around that tick: the predictor simulates no other body), `input_late` (one of the
    /// client's inputs before that tick is unanswered, or was applied late within the rollback
    /// window and an eighth of a second before it), `unexplained` (none of these: a bug, since
    /// the core is deterministic).
    pub causes: BTreeMap<&'static str, u64>,
    /// The error of every compared state, m (0 when exact), in arrival order.
    pub errors_m: Vec<f64>,
    /// The same, for states no other body came near (`other_body` and `input_late` left out).
    pub errors_untouched_m: Vec<f64>,
    /// The largest distance the easing of a correction moved the drawn avatar in one frame,
    /// scaled to a 60 Hz frame (the easing's speed over a sixtieth of a second), m.
    pub max_frame_correction_m: f64,
}

/// A misprediction awaiting its cause.
#[derive(Clone, Copy, Debug)]
struct Miss {
    tick: Tick,
    entity: EntityId,
    /// Another body was drawn within reach of it.
    near: bool,
    error: f64,
}

/// One client's session (see the module docs).
#[derive(Debug)]
pub struct Session {
    cfg: SessionConfig,
    status: Status,
    welcome: Option<Welcome>,
    clock: Clock,
    outbox: Outbox,
    events: EventView,
    remote: Option<RemoteWorld>,
    /// The probe in flight: its id and when it was sent.
    probe: Option<(u32, Instant)>,
    next_probe: u32,
    /// Sync answers: round trip, the tick named, when it arrived.
    samples: Vec<(Duration, Tick, Instant)>,
    sync_started: Option<Instant>,
    /// Inputs not yet answered, oldest first, for resending (at most `cfg.redundancy`).
    resend: VecDeque<ClientInput>,
    outgoing: VecDeque<ClientMessage>,
    rays: VecDeque<RayResult>,
    answers: VecDeque<Answer>,
    news: VecDeque<EventNews>,
    stats: SessionStats,
    predictor: Option<Predictor>,
    prediction: PredictionStats,
    prediction_problem: Option<PredictError>,
    /// Ticks of inputs acked late (rolled back on the server), for the causes of mispredictions.
    late_ticks: VecDeque<Tick>,
    last_drawn: Option<Instant>,
    /// The last misprediction, classified when the next state comes.
    unclassified: Option<Miss>,
    /// When a full state frame was last asked for.
    full_asked: Option<Instant>,
    /// The world's closing notice.
    closed: Option<WorldClosed>,
    /// When the last message from the server arrived.
    heard: Option<Instant>,
    /// The newest owner epoch heard (see [`Session::receive_from`]).
    epoch: Epoch,
    /// The number of the last message heard on each of the client's keys ([`OwnKey`]) from the
    /// owner at `epoch`.
    numbers: [KeyNumbers; OwnKey::COUNT],
    /// After a restored link: the server's present then, as the session estimated it. The first
    /// message published at or past it was published after the link came back, and every tick
    /// before its present may have lost events (see [`Session::published_at`]).
    path_check: Option<Tick>,
    /// The link was restored before the welcome (or messages were lost on the events key),
    /// with no estimate of the server's present to say which ticks it lost: until the welcome
    /// gives one, every tick an events-key message names is taken as lost up to it (see
    /// [`Session::receive_from`]).
    lost_unwelcomed: bool,
    /// After a second welcome: which inputs it left unaccepted, answered lost once an input made
    /// after it is acked.
    lost_check: Option<LostCheck>,
    /// When the last input was made (the game's or a keepalive).
    last_input: Option<Instant>,
    /// The freshest evidence of the server's tick: a tick a message named and when it came,
    /// the one that run on at the full rate puts the server furthest (a message that came late
    /// names an old tick and does not replace it), for at most [`NAMED_FOR`].
    newest_named: Option<(Tick, Instant)>,
    /// The event view's ticks in doubt: when each went in doubt, and whether the transport was
    /// given it to ask for.
    recovery: BTreeMap<Tick, (Instant, bool)>,
}

impl Session {
    /// A session that has not joined yet: declare the client's presence (the transport does),
    /// and feed it what arrives.
    pub fn new(cfg: SessionConfig) -> Session {
        Session {
            cfg,
            status: Status::Joining,
            welcome: None,
            clock: Clock::new(),
            outbox: Outbox::default(),
            events: EventView::default(),
            remote: None,
            probe: None,
            next_probe: 0,
            samples: Vec::new(),
            sync_started: None,
            resend: VecDeque::new(),
            outgoing: VecDeque::new(),
            rays: VecDeque::new(),
            answers: VecDeque::new(),
            news: VecDeque::new(),
            stats: SessionStats::default(),
            predictor: None,
            prediction: PredictionStats::default(),
            prediction_problem: None,
            late_ticks: VecDeque::new(),
            last_drawn: None,
            unclassified: None,
            full_asked: None,
            closed: None,
            heard: None,
            epoch: Epoch::default(),
            numbers: [KeyNumbers::default(); OwnKey::COUNT],
            lost_check: None,
            last_input: None,
            path_check: None,
            lost_unwelcomed: false,
            newest_named: None,
            recovery: BTreeMap::new(),
        }
    }

    /// Predicts the own avatar with `p` from now on (see [`crate::predict`]), instead of a
    /// predictor made from the server's scene; the welcome's scene hash is checked against it
    /// ([`Session::prediction_problem`] says why prediction stopped).
    pub fn predict_with(&mut self, p: Predictor) {
        if let Some(Err(e)) = self.welcome.as_ref().map(|w| p.check(w.scene_hash)) {
            self.prediction_problem = Some(e);
            return;
        }
        self.predictor = Some(p);
        self.prediction_problem = None;
    }

    /// The server could not be asked for its scene (`reason`): nothing to predict with unless
    /// the game gives a predictor ([`Session::prediction_problem`] then says so).
    pub fn scene_unavailable(&mut self, reason: String) {
        if self.predictor.is_none() {
            self.prediction_problem = Some(PredictError::NoScene(reason));
        }
    }

    /// The server's scene arrived: unless the game gave a predictor or
    /// [`SessionConfig::predict`] is off, the own avatar is predicted with it from now on.
    fn scene(&mut self, d: &SceneDescription) {
        let Some(cfg) = self.cfg.predict.clone() else { return };
        if self.predictor.is_some() {
            return;
        }
        let made = SceneRules::from_description(d)
            .map_err(PredictError::Described)
            .and_then(|rules| Predictor::new(&rules, self.cfg.client, cfg));
        match made {
            Ok(p) => self.predict_with(p),
            Err(e) => self.prediction_problem = Some(e),
        }
    }

    /// Why the own avatar is not predicted: the server runs another scene than the predictor
    /// given, its scene did not arrive or did not rebuild, or it spawns no avatars.
    pub fn prediction_problem(&self) -> Option<&PredictError> {
        self.prediction_problem.as_ref()
    }

    /// How the prediction fared.
    pub fn prediction(&self) -> &PredictionStats {
        &self.prediction
    }

    /// The predictor, if predicting.
    pub fn predictor(&self) -> Option<&Predictor> {
        self.predictor.as_ref()
    }

    /// Where to draw the own avatar at `now`, predicted: at the tick an input made now would be
    /// stamped with, plus what is left of the last corrections. `None` without prediction or
    /// before the first authoritative state.
    pub fn draw_avatar(&mut self, now: Instant) -> Option<[f64; 3]> {
        let at = self.clock.server_ticks(now)? + if self.cfg.ahead { self.clock.lead().unwrap_or(0.0) } else { 0.0 };
        let frame_s = self.last_drawn.map_or(0.0, |t| now.saturating_duration_since(t).as_secs_f64());
        self.last_drawn = Some(now);
        let (p, moved) = self.predictor.as_mut()?.drawn(at, frame_s)?;
        // As if the frame were a 60 Hz one: a late frame moves further, at the same speed.
        if frame_s > 0.0 {
            let m = &mut self.prediction.max_frame_correction_m;
            *m = m.max(moved / (frame_s * 60.0));
        }
        Some(p)
    }

    /// An authoritative state of the avatar arrived in a frame at `tick`.
    fn reconcile(&mut self, tick: Tick, s: &impact_protocol::AvatarState) {
        if self.avatar() != Some(s.entity) {
            return;
        }
        let Some(p) = self.predictor.as_mut() else { return };
        let error = match p.authoritative(tick, s) {
            Reconciled::Taken => {
                self.prediction.taken += 1;
                return;
            }
            Reconciled::Teleported => {
                self.prediction.teleported += 1;
                return;
            }
            Reconciled::Exact => 0.0,
            Reconciled::Corrected(e) => e,
        };
        // The last misprediction's cause, now that what explains it has had time to come.
        if let Some(m) = self.unclassified.take() {
            self.classify(m);
        }
        let st = &mut self.prediction;
        st.compared += 1;
        if st.errors_m.len() < MAX_PREDICTION_SAMPLES {
            st.errors_m.push(error);
        }
        if error == 0.0 {
            st.exact += 1;
            if st.errors_untouched_m.len() < MAX_PREDICTION_SAMPLES {
                st.errors_untouched_m.push(0.0);
            }
        } else {
            // What the stream drew is judged now, while its frames around the tick are held.
            let near = self.body_within_reach(tick, s.entity, s.position);
            self.unclassified = Some(Miss { tick, entity: s.entity, near, error });
        }
    }

    /// Puts a misprediction down to its cause. It is classified one state later: the event
    /// corrections and acks that explain it travel on other keys than the state stream, and a
    /// correction published with the state of the same tick can arrive after it.
    fn classify(&mut self, m: Miss) {
        let cause = if self.late_ticks.iter().any(|&t| t < m.tick) || self.outbox.pending_ticks().any(|t| t < m.tick) {
            "input_late"
        } else if m.near || self.collided(m.tick, m.entity) {
            "other_body"
        } else {
            "unexplained"
        };
        let st = &mut self.prediction;
        *st.causes.entry(cause).or_insert(0) += 1;
        if cause == "unexplained" && st.errors_untouched_m.len() < MAX_PREDICTION_SAMPLES {
            st.errors_untouched_m.push(m.error);
        }
        self.forget_late_before(m.tick);
    }

    /// Forgets the late inputs that can no longer explain the state of `tick`: a late input
    /// explains the states after it until the server's states include it (it was applied at
    /// most a window late, and the next states still differ from a prediction replayed from one
    /// that did not).
    fn forget_late_before(&mut self, tick: Tick) {
        let keep = self.welcome.as_ref().map_or(24, |w| w.window_ticks + w.tick_hz / 8);
        while self.late_ticks.front().is_some_and(|&t| t.0.saturating_add(keep) < tick.0) {
            self.late_ticks.pop_front();
        }
    }

    /// Whether one of the avatar's collision events (a body touched it: the stream may not
    /// carry the body, past the client's byte budget) falls in the eighth of a second before
    /// `tick`.
    fn collided(&self, tick: Tick, entity: EntityId) -> bool {
        let since = self.welcome.as_ref().map_or(8, |w| w.tick_hz / 8);
        (tick.0.saturating_sub(since)..=tick.0).any(|t| {
            self.events.at(Tick(t)).any(|e| e.phase != impact_protocol::Phase::Hit && (e.a == entity || e.b == entity))
        })
    }

    /// Whether another body of the remote world came within reach of the avatar at `at` in the
    /// eighth of a second before `tick` (as the stream drew them: the server's at its frames).
    fn body_within_reach(&self, tick: Tick, entity: EntityId, at: [f64; 3]) -> bool {
        let since = self.welcome.as_ref().map_or(8, |w| w.tick_hz / 8);
        let Some(r) = &self.remote else { return false };
        let size = |e| r.info(e).map_or(0.5, |i| f64::from(i.half_extents_m.iter().copied().fold(0.0f32, f32::max)));
        let me = size(entity);
        let mut drawn = Vec::new();
        (0..=since).any(|k| {
            r.draw(f64::from(tick.0.saturating_sub(k)), &mut drawn);
            drawn.iter().filter(|b| b.entity != entity).any(|b| {
                let d = (0..3).map(|i| (b.position[i] - at[i]).powi(2)).sum::<f64>().sqrt();
                d < me + size(b.entity) + 0.5
            })
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SessionConfig {
        &self.cfg
    }

    /// Where the session is.
    pub fn status(&self) -> Status {
        self.status
    }

    /// The world's closing notice, once it closed ([`Status::Closed`]): where its players go
    /// next (a game joins that world with a new session and connection), and why.
    pub fn closed(&self) -> Option<&WorldClosed> {
        self.closed.as_ref()
    }

    /// The last welcome: the avatar, tick rate, window and lead bounds.
    pub fn welcome(&self) -> Option<&Welcome> {
        self.welcome.as_ref()
    }

    /// The client's avatar, once welcomed (if the scene spawns one).
    pub fn avatar(&self) -> Option<EntityId> {
        self.welcome.as_ref().and_then(|w| w.avatar)
    }

    /// The client's estimate of the server's clock.
    pub fn clock(&self) -> &Clock {
        &self.clock
    }

    /// The event view: provisional events with corrections applied, confirmed ticks compared.
    pub fn events(&self) -> &EventView {
        &self.events
    }

    /// The remote world (once welcomed: it needs the tick rate).
    pub fn remote(&self) -> Option<&RemoteWorld> {
        self.remote.as_ref()
    }

    /// The tick remote bodies are drawn at, at `now`: the server's present as the clock sees it,
    /// less the interpolation delay.
    pub fn render_tick(&self, now: Instant) -> Option<f64> {
        let delay = self.remote.as_ref()?.config().delay_ticks();
        Some(self.clock.server_ticks(now)? - delay)
    }

    /// Every remote body as drawn at `now`, into `out` (cleared first; empty before the welcome).
    pub fn draw_remote(&self, now: Instant, out: &mut Vec<DrawnBody>) {
        out.clear();
        if let (Some(r), Some(t)) = (&self.remote, self.render_tick(now)) {
            r.draw(t, out);
        }
    }

    /// The ray results received since the last call, oldest first.
    pub fn take_ray_results(&mut self) -> impl Iterator<Item = RayResult> + '_ {
        self.rays.drain(..)
    }

    /// The answers to inputs received since the last call, in arrival order: one per input
    /// (its first answer; a copy's second answer is not repeated here).
    pub fn take_answers(&mut self) -> impl Iterator<Item = Answer> + '_ {
        self.answers.drain(..)
    }

    /// What changed in the event view since the last call, in arrival order (at most
    /// [`MAX_EVENT_NEWS`]; older news is dropped and counted in
    /// [`SessionStats::event_news_dropped`]).
    pub fn take_event_news(&mut self) -> impl Iterator<Item = EventNews> + '_ {
        self.news.drain(..)
    }

    fn news(&mut self, n: EventNews) {
        push_news(&mut self.news, &mut self.stats.event_news_dropped, n);
    }

    fn answered(&mut self, seq: u32, sent: Sent, outcome: Outcome, now: Instant) {
        if let Some(p) = self.predictor.as_mut() {
            match outcome {
                Outcome::Accepted { applied_tick, .. } => p.answered(seq, Some(applied_tick)),
                Outcome::Rejected(_) | Outcome::Lost => p.answered(seq, None),
                // Applied, most likely at its tick: the prediction keeps it where it is.
                Outcome::AckLost => {}
            }
        }
        if sent.keepalive {
            return; // the session's own
        }
        if self.answers.len() >= MAX_ANSWERS {
            self.answers.pop_front();
        }
        let round_trip = now.saturating_duration_since(sent.at);
        self.answers.push_back(Answer { seq, tick: sent.tick, sent: sent.at, round_trip, outcome });
    }

    /// When the last message from the server arrived (`None`: nothing yet). A game tells a
    /// server gone quiet from here: with the state stream on, or inputs awaiting answers, a
    /// second of silence is a lost connection or a server failing over.
    pub fn last_heard(&self) -> Option<Instant> {
        self.heard
    }

    /// What the session counted.
    pub fn stats(&self) -> &SessionStats {
        &self.stats
    }

    /// Whether the game's input `seq` awaits an answer (a keepalive is the session's own: once
    /// the inputs it was sent for are answered, its own answer, lost on the way, is owed to no
    /// one).
    pub fn awaits(&self, seq: u32) -> bool {
        self.outbox.get(seq).is_some_and(|s| !s.keepalive)
    }

    /// The game's inputs awaiting an answer (the session's keepalives are not counted).
    pub fn pending_inputs(&self) -> usize {
        self.outbox.pending_games()
    }

    /// The transport received something it could not decode (counted, then skipped).
    pub fn malformed(&mut self) {
        self.stats.malformed += 1;
    }

    /// A message on one of the client's own keys from the world's owner, stamped `stamp` (the
    /// sample's attachment, [`Stamp::from_attachment`]), arrived at `now`. One from an older
    /// owner than the newest heard is dropped and counted ([`SessionStats::stale_owner`]): after a
    /// failover, the primary that stood still may publish for a moment before it hears it was
    /// replaced. `None` (a message with no stamp) is taken as [`Session::receive`] takes it.
    ///
    /// A newer owner than one heard before (a takeover) is taken as a lost link
    /// ([`Session::link_restored`]): what the old owner published as it died may or may not have
    /// arrived, and the new owner corrects from what it heard, not from what this client holds,
    /// so the ticks before its present are taken from the confirmed stream as they come. So is a
    /// skip in the numbers of the events key's messages ([`SessionStats::messages_lost`]): events
    /// or corrections lost on the way leave the ticks they were for unverifiable. (Which key a
    /// message came on follows from its kind, PROTOCOL.md "Key expressions"; a transport hands
    /// this only what came on the client's own keys.)
    pub fn receive_from(&mut self, stamp: Option<Stamp>, msg: ServerMessage, now: Instant) {
        if let Some(Stamp { epoch: e, number }) = stamp {
            if e < self.epoch {
                self.stats.stale_owner += 1;
                return;
            }
            if e > self.epoch {
                if self.epoch > Epoch(0) {
                    self.stats.owner_changes += 1;
                    self.link_restored(now);
                }
                self.numbers = [KeyNumbers::default(); OwnKey::COUNT];
            }
            self.epoch = e;
            if let Some(n) = number {
                let key = OwnKey::of(&msg);
                let lost = self.numbers[key as usize].heard(n);
                self.stats.messages_lost += lost;
                if lost > 0 && key == OwnKey::Events {
                    self.link_restored(now);
                }
                if self.lost_unwelcomed {
                    // Lost before the welcome: each message's tick and those before it, until
                    // the welcome's present covers the rest (see [`Session::link_restored`]).
                    if let ServerMessage::Events(b) | ServerMessage::Confirmed(b) = &msg {
                        self.events.lost_before(b.tick.next());
                    } else if let ServerMessage::Corrections(c) = &msg {
                        self.events.lost_before(c.tick.next());
                    }
                }
            }
        }
        self.receive(msg, now);
    }

    /// The transport's link to the server was lost and is back at `now` (a router restarted, a
    /// network handover): what the server published meanwhile never arrived, so the ticks before
    /// the server's present are taken from the confirmed stream as they come, not compared with
    /// the view ([`crate::events::EventView::unverified`]; their `EventNews::Confirmed` says
    /// `matched: false`, so a game redraws them from the confirmed events). The client's link
    /// being back does not mean the server's is (a restarted router: each side reconnects in its
    /// own time), so the ticks before the server's present when it published the first message
    /// heard since are taken the same way. Before the welcome, the ticks of the events-key
    /// messages heard until it comes are, and those before its present.
    pub fn link_restored(&mut self, now: Instant) {
        // The clock's estimate of the server's present (or the newest tick held), and a margin
        // for an estimate a little behind: a tick left out of the comparison costs nothing, a
        // tick compared after losing its events is a false mismatch. Nor less than the newest
        // tick heard, run on at the full rate since: a clock pulled back by old messages that
        // came late (a flood after a stall on the client's side) would miss ticks lost.
        const MARGIN_TICKS: u32 = 8;
        let newest = self.events.newest();
        let run_on = self.newest_named.map(|n| Tick(self.run_on(n, now) as u32));
        if let Some(t) = self.clock.server_tick(now).max(newest.map(Tick::next)).max(run_on) {
            self.events.lost_before(Tick(t.0.saturating_add(MARGIN_TICKS)));
            self.path_check = Some(t);
        }
        // No estimate of the server's present before the welcome (it comes on another key, and
        // may come after the events key's first messages: a client back on a new session, whose
        // keys the server published on while it was away): the ticks lost are not known until
        // it comes, and it restores the link again from its tick.
        self.lost_unwelcomed |= !self.clock.is_anchored();
    }

    /// A tick whose confirmed batch this client missed (a later one came while it held events
    /// of it, see [`crate::events`]): the transport asks the server for the batch it kept
    /// (`query/confirmed?from=T;to=T;client=C`), hands each reply to [`Session::recovered`]
    /// and says when the answer ended ([`Session::recovery_ended`]). Each tick is given once;
    /// one not recovered within [`RECOVERY_WAIT`] is taken as having no events for this client.
    pub fn poll_recovery(&mut self) -> Option<Tick> {
        let (t, (_, asked)) = self.recovery.iter_mut().find(|(_, (_, asked))| !*asked)?;
        *asked = true;
        Some(*t)
    }

    /// A confirmed batch the server kept, from a `query/confirmed` reply: a tick in doubt is
    /// compared with it and made final (`EventNews::Confirmed`, after later ticks').
    pub fn recovered(&mut self, b: EventBatch) {
        let (news, dropped) = (&mut self.news, &mut self.stats.event_news_dropped);
        self.events.recovered(&b, |tick, matched| push_news(news, dropped, EventNews::Confirmed { tick, matched }));
        self.recovery.remove(&b.tick);
    }

    /// The answer to the query for `tick` ended: if it brought no batch of it, the server no
    /// longer keeps it, and the tick is final with no events for this client.
    pub fn recovery_ended(&mut self, tick: Tick) {
        let (news, dropped) = (&mut self.news, &mut self.stats.event_news_dropped);
        self.events.give_up(tick, |tick, matched| push_news(news, dropped, EventNews::Confirmed { tick, matched }));
        self.recovery.remove(&tick);
    }

    /// Ticks in doubt for longer than [`RECOVERY_WAIT`] (a transport that does not ask, or an
    /// answer that never ended) are given up on.
    fn give_up_recovery(&mut self, now: Instant) {
        while let Some((&t, _)) =
            self.recovery.iter().find(|(_, (since, _))| now.saturating_duration_since(*since) >= RECOVERY_WAIT)
        {
            self.recovery_ended(t);
        }
    }

    /// The newest owner epoch heard (0 before any).
    pub fn epoch(&self) -> Epoch {
        self.epoch
    }

    /// A message from the server arrived at `now` (with no owner epoch: see
    /// [`Session::receive_from`]).
    pub fn receive(&mut self, msg: ServerMessage, now: Instant) {
        let me = self.cfg.client;
        self.heard = Some(self.heard.map_or(now, |h| h.max(now)));
        match msg {
            ServerMessage::Welcome(w) if w.client == me => self.welcomed(w, now),
            ServerMessage::Pong(p) if p.client == me => {
                let Some((id, sent)) = self.probe else { return };
                if id != p.id || self.status != Status::Syncing {
                    return;
                }
                self.probe = None;
                self.samples.push((now.saturating_duration_since(sent), p.server_tick, now));
                if self.samples.len() >= SYNC_PROBES {
                    self.start_playing();
                }
            }
            ServerMessage::Ack(a) if a.client == me => {
                self.observe(a.server_tick, now);
                self.clock.recommend(a.lead_ticks);
                self.stats.late_acks += u64::from(a.margin_ticks < 0);
                if a.margin_ticks < 0 {
                    // Forgotten as they age here too, not only as states are compared (a client
                    // that does not predict held a thousand after hours of play), with room for
                    // the states of the ticks before this one, still to come.
                    let room = self.welcome.as_ref().map_or(24, |w| w.window_ticks + w.tick_hz / 8);
                    self.forget_late_before(Tick(a.applied_tick.0.saturating_sub(room)));
                }
                if a.margin_ticks < 0 && self.late_ticks.len() < 1024 {
                    self.late_ticks.push_back(a.applied_tick);
                }
                self.resend.retain(|i| i.seq != a.seq);
                let made = self.outbox.answered(a.seq).map(|sent| {
                    self.stats.inputs_acked += 1;
                    let outcome = Outcome::Accepted { applied_tick: a.applied_tick, margin_ticks: a.margin_ticks };
                    self.answered(a.seq, sent, outcome, now);
                    sent.at
                });
                if made.is_none() {
                    self.stats.unmatched_answers += 1;
                }
                // Inputs before it the server accepted whose own acks never came.
                for seq in accepted_before(a.seq, a.accepted_before) {
                    if let Some(sent) = self.outbox.answered(seq) {
                        self.resend.retain(|i| i.seq != seq);
                        self.stats.inputs_acked += 1;
                        self.stats.acks_recovered += 1;
                        self.answered(seq, sent, Outcome::AckLost, now);
                    }
                }
                if let Some(made) = made {
                    self.lost_before(&a, made, now);
                    self.acked_after(made, now);
                }
            }
            ServerMessage::Reject(j) if j.client == me => self.rejected(&j, now),
            ServerMessage::Events(b) => {
                self.observe(b.tick, now);
                self.stats.events += b.events.len() as u64;
                self.events.events(&b);
                for e in b.events {
                    self.news(EventNews::Event(e));
                }
            }
            ServerMessage::Corrections(c) => {
                self.stats.corrections += 1;
                self.events.correct(&c);
                self.news(EventNews::Corrected(c));
            }
            ServerMessage::Confirmed(b) => {
                // Published as the tick left the server's rollback window.
                if let Some(window) = self.welcome.as_ref().map(|w| w.window_ticks) {
                    self.published_at(Tick(b.tick.0.saturating_add(window)));
                }
                let (news, dropped) = (&mut self.news, &mut self.stats.event_news_dropped);
                self.events
                    .confirm(&b, |tick, matched| push_news(news, dropped, EventNews::Confirmed { tick, matched }));
                let doubtful: BTreeSet<Tick> = self.events.doubtful().collect();
                self.recovery.retain(|t, _| doubtful.contains(t));
                for t in doubtful {
                    self.recovery.entry(t).or_insert((now, false));
                }
            }
            ServerMessage::RayResult(r) if r.client == me => {
                self.stats.ray_results += 1;
                self.stats.hits += u64::from(r.hit.is_some());
                if self.rays.len() >= MAX_RAY_RESULTS {
                    self.rays.pop_front();
                }
                self.rays.push_back(r);
            }
            ServerMessage::State(f) => {
                self.stats.state_frames += 1;
                self.observe(f.tick, now);
                if let Some(r) = self.remote.as_mut() {
                    r.apply(&f);
                }
                if let Some(a) = &f.avatar {
                    self.reconcile(f.tick, a);
                }
            }
            ServerMessage::Stats(s) => self.observe(s.tick, now),
            ServerMessage::Scene(d) => self.scene(&d),
            ServerMessage::Closed(c) => {
                self.status = Status::Closed;
                self.outgoing.clear();
                self.resend.clear();
                self.closed = Some(c);
            }
            _ => self.stats.skipped += 1,
        }
    }

    /// Where the server would be at `now` had it ticked at the full rate since it named `tick`
    /// at `at` (further than it is if it stalled since: an estimate never short).
    fn run_on(&self, (tick, at): (Tick, Instant), now: Instant) -> f64 {
        let hz = f64::from(self.clock.tick_hz().unwrap_or(0));
        f64::from(tick.0) + now.saturating_duration_since(at).as_secs_f64() * hz
    }

    /// A message published when the server was at `present` arrived: the first since a
    /// restored link published at or past the session's estimate then ([`Session::link_restored`])
    /// shows the path whole again, and every tick before `present` may have lost events.
    fn published_at(&mut self, present: Tick) {
        if self.path_check.is_some_and(|p| present >= p) {
            self.path_check = None;
            self.events.lost_before(present);
        }
    }

    fn observe(&mut self, tick: Tick, now: Instant) {
        self.published_at(tick);
        self.stats.clock_resyncs += u64::from(self.clock.observe(tick, now));
        if self.newest_named.is_none_or(|n| f64::from(tick.0) >= self.run_on(n, now) || now - n.1 > NAMED_FOR) {
            self.newest_named = Some((tick, now));
        }
    }

    fn welcomed(&mut self, w: Welcome, now: Instant) {
        self.stats.welcomes += 1;
        self.clock.anchor(w.tick, w.tick_hz, now);
        if std::mem::take(&mut self.lost_unwelcomed) {
            // Events-key messages were lost before it: from its present on, as after a link
            // restored (what was published before it may have been lost).
            self.link_restored(now);
        }
        if self.remote.as_ref().is_none_or(|r| r.config().tick_hz != w.tick_hz) {
            let cfg = RemoteConfig { delay_s: self.cfg.interpolation_delay_s, ..RemoteConfig::new(w.tick_hz) };
            self.remote = Some(RemoteWorld::new(cfg));
        }
        // Seqs below the server's next_seq: it accepted the one just below, and answered or
        // never heard the others (answers lost with the old link). None is carried again, so the
        // next ack's `accepted_before` tells each accepted (`AckLost`) or not (`Lost`). Ours go
        // on from wherever is further.
        self.outbox.resume_from(w.next_seq);
        self.resend.retain(|i| !precedes(i.seq, w.next_seq));
        if self.stats.welcomes > 1 {
            self.lost_at_welcome(&w, now);
        }
        if let Some(Err(e)) = self.predictor.as_ref().map(|p| p.check(w.scene_hash)) {
            self.prediction_problem = Some(e);
            self.predictor = None;
        }
        if self.status == Status::Joining {
            self.status = Status::Syncing;
            self.sync_started = Some(now);
        }
        self.welcome = Some(w);
    }

    /// A reject of one of this client's inputs: its answer, and a `future` one lowers the lead.
    fn rejected(&mut self, j: &impact_protocol::InputReject, now: Instant) {
        *self.stats.rejects.entry(j.reason).or_insert(0) += 1;
        let Some(seq) = j.seq else { return };
        self.resend.retain(|i| i.seq != seq);
        match self.outbox.answered(seq) {
            Some(sent) => {
                if let (RejectReason::Future, Some(t), Some(n), Some(view)) =
                    (j.reason, j.tick, j.newest_tick, sent.view)
                {
                    let ahead = self.welcome.as_ref().map_or(0, |w| w.input_lead_ticks);
                    self.clock.back_off(t, view, n, ahead);
                }
                self.answered(seq, sent, Outcome::Rejected(j.reason), now);
            }
            // An accepted input whose entity went away before its tick was re-simulated is told
            // so by a second message (PROTOCOL.md): not unmatched.
            None if matches!(j.reason, RejectReason::UnknownEntity | RejectReason::NotOwner) => {}
            None => self.stats.unmatched_answers += 1,
        }
    }

    /// Welcomed again (a reconnect, a takeover): the inputs at or above `next_seq` were never
    /// accepted. Those sent before this welcome may still be on their way, or their answers may
    /// (a path that stalls after the welcome holds them for seconds), so no length of time tells.
    /// Order does: the server takes a client's messages in order and acks the inputs it accepted
    /// in that order on the `ack` key, each tick's acks after its rejects. So once an input made
    /// after the welcome is acked, every input sent before it that is still unanswered, and not
    /// carried again since, never reached the server (its ack or reject would have come first).
    /// It is answered [`Outcome::Lost`] then ([`Session::acked_after`]), so none is silently gone.
    /// (Not a reject nor a pong: those go out at once, and may pass the acks of earlier inputs,
    /// which wait for the end of their tick.)
    fn lost_at_welcome(&mut self, w: &Welcome, now: Instant) {
        self.lost_check = Some(LostCheck { welcomed: now, next_seq: w.next_seq });
    }

    /// An ack of an input made at `made`: an earlier input within its `accepted_before` bits
    /// that the server did not accept, and that no message carried since that input was made,
    /// never reached the server. A client's messages arrive in order, so every copy of it came
    /// (if at all) before the acked one, and was neither accepted (its bit) nor rejected (the
    /// reject, on the same key, would have come first). It is answered [`Outcome::Lost`]: its
    /// every copy was lost on the way (or went to a server that died, or through a router that
    /// restarted), with no welcome after to tell.
    fn lost_before(&mut self, a: &impact_protocol::InputAck, made: Instant, now: Instant) {
        let unaccepted = |seq: u32| {
            let back = a.seq.wrapping_sub(seq);
            precedes(seq, a.seq) && back <= 64 && (a.accepted_before >> (back - 1)) & 1 == 0
        };
        self.answer_lost(|seq, s| unaccepted(seq) && s.carried < made, now);
    }

    /// Every input awaiting an answer that `lost` says never reached the server is answered
    /// [`Outcome::Lost`].
    fn answer_lost(&mut self, lost: impl FnMut(u32, &Sent) -> bool, now: Instant) {
        for (seq, sent) in self.outbox.take_pending(lost) {
            self.resend.retain(|i| i.seq != seq);
            self.stats.inputs_lost += 1;
            self.answered(seq, sent, Outcome::Lost, now);
        }
    }

    /// An input first sent at `sent` was acked: the check [`Session::lost_at_welcome`] left is
    /// settled when that was after the welcome.
    fn acked_after(&mut self, sent: Instant, now: Instant) {
        let Some(c) = self.lost_check.filter(|c| sent >= c.welcomed) else { return };
        self.lost_check = None;
        self.answer_lost(|seq: u32, s: &Sent| !precedes(seq, c.next_seq) && s.carried < c.welcomed, now);
        // Below next_seq and further back than the ack's `accepted_before` reaches (64 seqs):
        // taken as the welcome implies, accepted with the seq just below next_seq, acks lost.
        for (seq, s) in self.outbox.take_pending(|seq, s| precedes(seq, c.next_seq) && s.carried < c.welcomed) {
            self.stats.inputs_acked += 1;
            self.stats.acks_recovered += 1;
            self.answered(seq, s, Outcome::AckLost, now);
        }
    }

    /// Ends the sync: the soonest answer anchors the clock, the slowest round trip (in ticks,
    /// plus one) is the first lead, as the server's own recommendation is its largest recent
    /// delay plus one.
    fn start_playing(&mut self) {
        self.status = Status::Playing;
        self.probe = None;
        let Some(hz) = self.clock.tick_hz() else { return };
        let Some(&(_, tick, at)) = self.samples.iter().min_by_key(|s| s.0) else { return };
        let slowest = self.samples.iter().map(|s| s.0).max().unwrap_or_default();
        let fastest = self.samples.iter().map(|s| s.0).min().unwrap_or_default();
        self.stats.sync_samples = self.samples.len() as u64;
        self.stats.sync_rtt_min_s = fastest.as_secs_f64();
        self.stats.sync_rtt_max_s = slowest.as_secs_f64();
        self.clock.anchor(tick, hz, at);
        self.clock.recommend((slowest.as_secs_f64() * f64::from(hz)).ceil() as u32 + 1);
    }

    /// Numbers and stamps `actions` as the client's next input and queues it for the transport
    /// (with the unanswered inputs before it). An input that fires a ray carries the tick the
    /// remote world is drawn at now (`aim_tick`), so the server rewinds the shot to what the
    /// player saw. Returns its seq.
    pub fn input(&mut self, actions: Vec<Action>, now: Instant) -> Result<u32, InputError> {
        self.make_input(actions, false, now)
    }

    /// [`Session::input`], or a keepalive ([`KEEPALIVE_AFTER`]).
    fn make_input(&mut self, actions: Vec<Action>, keepalive: bool, now: Instant) -> Result<u32, InputError> {
        if self.status == Status::Closed {
            return Err(InputError::Closed);
        }
        if actions.len() > MAX_ACTIONS_PER_INPUT {
            return Err(InputError::TooManyActions { count: actions.len() });
        }
        let (tick, view) = self.clock.stamp(self.cfg.ahead, now).ok_or(InputError::NotJoined)?;
        let seq = self.outbox.next_seq();
        // Behind, the view tick is the input's own: saying so again would change nothing.
        let view_tick = self.cfg.ahead.then_some(view);
        // A shot is aimed at the remote world as drawn, an interpolation delay behind the view:
        // the server rewinds it there.
        let fires = actions.iter().any(|a| matches!(a, Action::FireRay { .. }));
        let aim_tick = self.render_tick(now).filter(|_| fires).map(|r| Tick(r.floor().max(0.0) as u32));
        let input = ClientInput { client: self.cfg.client, seq, tick, view_tick, aim_tick, actions };
        self.outbox.sent(seq, Sent { at: now, tick, view: view_tick, carried: now, keepalive });
        self.last_input = Some(now);
        self.stats.keepalives += u64::from(keepalive);
        if let Some(p) = self.predictor.as_mut() {
            p.input(tick, seq, &input.actions);
        }
        self.stats.inputs_sent += 1;
        // Copies, newest first, while the server can still accept them and the actions fit.
        let oldest = self.welcome.as_ref().map_or(0, |w| view.0.saturating_sub(w.window_ticks));
        let mut actions = input.actions.len();
        let mut inputs = Vec::new();
        for old in self.resend.iter().rev().take(self.cfg.redundancy.min(MAX_INPUTS_PER_MESSAGE - 1)) {
            if old.tick.0 < oldest || actions + old.actions.len() > MAX_ACTIONS_PER_INPUT {
                break;
            }
            actions += old.actions.len();
            inputs.push(old.clone());
        }
        self.stats.copies_sent += inputs.len() as u64;
        for copy in &inputs {
            self.outbox.carried(copy.seq, now);
        }
        inputs.reverse();
        let msg = if inputs.is_empty() {
            ClientMessage::Input(input.clone())
        } else {
            inputs.push(input.clone());
            ClientMessage::Inputs(InputBatch { client: self.cfg.client, inputs })
        };
        if self.cfg.redundancy > 0 {
            self.resend.push_back(input);
            while self.resend.len() > self.cfg.redundancy {
                self.resend.pop_front();
            }
        }
        self.push(msg);
        Ok(seq)
    }

    fn push(&mut self, msg: ClientMessage) {
        if self.outgoing.len() >= MAX_OUTGOING {
            self.outgoing.pop_front();
            self.stats.outgoing_dropped += 1;
        }
        self.outgoing.push_back(msg);
    }

    /// The next message to send at `now`, if any: the sync's probes, then inputs in order.
    /// Call it until it returns `None` each frame.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<ClientMessage> {
        self.give_up_recovery(now);
        if self.status == Status::Syncing {
            let started = *self.sync_started.get_or_insert(now);
            if now.saturating_duration_since(started) >= SYNC_TIMEOUT {
                self.start_playing();
            } else if self.probe.is_none_or(|(_, at)| now.saturating_duration_since(at) >= PROBE_TIMEOUT) {
                let id = self.next_probe;
                self.next_probe = self.next_probe.wrapping_add(1);
                self.probe = Some((id, now));
                return Some(ClientMessage::Ping(TimePing { client: self.cfg.client, id }));
            }
        }
        // A state stream past a gap ignores deltas until a full frame: ask for one rather than
        // wait for the periodic one (up to 2 s).
        let waiting = self.stats.state_frames > 0 && self.remote.as_ref().is_some_and(RemoteWorld::needs_full_frame);
        if waiting && self.full_asked.is_none_or(|at| now.saturating_duration_since(at) >= FULL_FRAME_EVERY) {
            self.full_asked = Some(now);
            self.stats.full_frames_asked += 1;
            return Some(ClientMessage::FullFrame(FullFrameRequest { client: self.cfg.client }));
        }
        let idle = self.last_input.is_some_and(|t| now.saturating_duration_since(t) >= KEEPALIVE_AFTER);
        if idle && self.status == Status::Playing && self.outbox.awaits_the_games(KEEPALIVE_REACH) {
            let _ = self.make_input(Vec::new(), true, now);
        }
        self.outgoing.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use impact_protocol::{InputAck, InputReject, TimePong};

    fn welcome(next_seq: u32) -> ServerMessage {
        ServerMessage::Welcome(Welcome {
            client: ClientId(7),
            avatar: Some(EntityId(3)),
            tick: Tick(100),
            tick_hz: 64,
            window_ticks: 16,
            input_lead_ticks: 8,
            max_rewind_ticks: 16,
            next_seq,
            scene_hash: 0,
        })
    }

    fn walk() -> Vec<Action> {
        vec![Action::SetVelocity { entity: EntityId(3), velocity: [1.0, 0.0, 0.0] }]
    }

    fn ack(seq: u32, server_tick: u32, lead: u32) -> ServerMessage {
        ServerMessage::Ack(InputAck {
            client: ClientId(7),
            seq,
            tick: Tick(server_tick),
            applied_tick: Tick(server_tick),
            server_tick: Tick(server_tick),
            margin_ticks: 0,
            lead_ticks: lead,
            accepted_before: 0,
        })
    }

    /// A session welcomed, synced by timeout (no probe answered) and playing, that sent three
    /// inputs (seqs 1, 2, 3) at the returned instant, none answered.
    fn played_three(cfg: SessionConfig) -> (Session, Instant) {
        let t0 = Instant::now();
        let mut s = Session::new(cfg);
        s.receive(welcome(0), t0);
        let mut t = t0 + SYNC_TIMEOUT;
        while s.status() == Status::Syncing {
            let _ = s.poll_transmit(t);
            t += Duration::from_millis(50);
        }
        let seqs: Vec<u32> = (0..3).map(|_| s.input(walk(), t).unwrap()).collect();
        assert_eq!(seqs, [1, 2, 3]);
        while s.poll_transmit(t).is_some() {}
        (s, t)
    }

    /// The ticks of late inputs are kept only as long as they can explain a misprediction, also
    /// by a client that does not predict (it held a thousand after hours of play).
    #[test]
    fn late_inputs_are_forgotten_as_they_age() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        for k in 0..2000u32 {
            let tick = 101 + 10 * k;
            let late = InputAck {
                margin_ticks: -1,
                ..match ack(k, tick, 2) {
                    ServerMessage::Ack(a) => a,
                    _ => unreachable!(),
                }
            };
            s.receive(ServerMessage::Ack(late), t0);
        }
        // Within 2 x (16 + 64 / 8) ticks of the newest, ten ticks apart.
        assert!(s.late_ticks.len() <= 5, "{} late ticks held", s.late_ticks.len());
        assert_eq!(s.late_ticks.back(), Some(&Tick(101 + 10 * 1999)));
    }

    /// After a failover the new owner's messages carry a newer epoch; what the old primary still
    /// sends (an older one) is dropped and counted, and a message with no epoch is taken.
    #[test]
    fn an_older_owner_is_not_heard_once_a_newer_one_was() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive_from(Some(Epoch(1).into()), welcome(0), t0);
        assert_eq!(s.epoch(), Epoch(1));
        // Acks of no input sent: each is counted as unmatched when it is taken.
        s.receive_from(Some(Epoch(1).into()), ack(40, 101, 2), t0);
        assert_eq!(s.stats().unmatched_answers, 1);
        // The standby took over: its welcome, at epoch 2.
        s.receive_from(Some(Epoch(2).into()), welcome(0), t0);
        assert_eq!((s.epoch(), s.stats().welcomes), (Epoch(2), 2));
        // The old primary resumed for a moment: nothing of it is taken.
        s.receive_from(Some(Epoch(1).into()), ack(41, 102, 2), t0);
        s.receive_from(Some(Epoch(1).into()), welcome(9), t0);
        assert_eq!((s.stats().unmatched_answers, s.stats().welcomes, s.stats().stale_owner), (1, 2, 2));
        s.receive_from(Some(Epoch(2).into()), ack(42, 103, 2), t0);
        s.receive_from(None, ack(43, 104, 2), t0);
        assert_eq!((s.stats().unmatched_answers, s.epoch()), (3, Epoch(2)));
    }

    /// A takeover: what the old owner published as it died may not have arrived, and the new
    /// owner corrects from what it heard, so the ticks before its present are not compared; the
    /// first owner heard is no change.
    #[test]
    fn a_new_owner_leaves_the_ticks_before_it_uncompared() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive_from(Some(Epoch(1).into()), welcome(0), t0);
        s.receive_from(Some(Epoch(1).into()), ServerMessage::Events(batch(101)), t0);
        assert_eq!(s.stats().owner_changes, 0);
        let t = t0 + Duration::from_millis(500);
        s.receive_from(Some(Epoch(2).into()), ServerMessage::Events(batch(150)), t);
        assert_eq!(s.stats().owner_changes, 1);
        // Tick 120's events went out from the dying primary and never came.
        s.receive_from(Some(Epoch(2).into()), ServerMessage::Confirmed(batch(120)), t);
        assert_eq!((s.events().mismatched, s.events().unverified), (0, 2), "101 and 120");
        s.receive_from(Some(Epoch(2).into()), ServerMessage::Confirmed(batch(150)), t);
        assert_eq!(s.events().matched, 1);
    }

    /// Events lost on the way with no link lost (a congested path dropped them, or a full
    /// inbox): the skip in the events key's numbers leaves the ticks before it uncompared, where
    /// the same messages numbered in order would have been compared (and differed). A skip on the
    /// ack key is counted only; a count started again (a number not past the last) loses nothing.
    #[test]
    fn a_skip_in_the_events_numbers_leaves_the_ticks_before_it_uncompared() {
        let t0 = Instant::now();
        let on = |n| Some(Stamp { epoch: Epoch(1), number: Some(n) });
        let run = |skip: u64| {
            let mut s = Session::new(SessionConfig::new(ClientId(7)));
            s.receive_from(on(1), welcome(0), t0);
            s.receive_from(on(1), ServerMessage::Events(batch(101)), t0);
            s.receive_from(on(2), ServerMessage::Events(batch(102)), t0);
            s.receive_from(on(3), ServerMessage::Confirmed(batch(101)), t0);
            s.receive_from(on(4), ServerMessage::Confirmed(batch(102)), t0);
            // Number 5, tick 103's events, lost on the way (when `skip` is 1).
            s.receive_from(on(5 + skip), ServerMessage::Events(batch(104)), t0);
            s.receive_from(on(6 + skip), ServerMessage::Confirmed(batch(103)), t0);
            s
        };
        let (lost, whole) = (run(1), run(0));
        assert_eq!((whole.stats().messages_lost, whole.events().matched, whole.events().mismatched), (0, 2, 1));
        assert_eq!((lost.stats().messages_lost, lost.events().matched, lost.events().mismatched), (1, 2, 0));
        assert!(lost.events().unverified >= 1);

        let mut s = run(1);
        s.receive_from(on(3), ack(40, 105, 2), t0);
        assert_eq!((s.stats().messages_lost, s.events().mismatched), (2, 0), "one ack lost: counted");
        s.receive_from(on(1), ServerMessage::Events(batch(130)), t0);
        s.receive_from(on(2), ServerMessage::Confirmed(batch(130)), t0);
        assert_eq!((s.stats().messages_lost, s.events().matched, s.events().mismatched), (2, 3, 0));

        // A subscription the owner's first messages on the key did not reach (a join through a
        // router): the first heard is not number 1.
        let mut late = Session::new(SessionConfig::new(ClientId(7)));
        late.receive_from(on(1), welcome(0), t0);
        late.receive_from(on(3), ServerMessage::Events(batch(102)), t0);
        late.receive_from(on(4), ServerMessage::Confirmed(batch(101)), t0);
        assert_eq!((late.stats().messages_lost, late.events().mismatched, late.events().unverified), (2, 0, 1));
    }

    /// A client back on a new session (or joining through a router) hears its events key
    /// before the welcome, which comes on another key: the server published on the key while
    /// it was away, and the first number heard is not 1. The ticks of what it hears before the
    /// welcome, and those before them, are not compared (tick 84's events were the one lost,
    /// and tick 80's confirmation was published after them), nor those before the welcome's
    /// present (tick 100); from the first message published after it on, ticks are compared.
    #[test]
    fn a_skip_before_the_welcome_leaves_the_ticks_before_it_uncompared() {
        let t0 = Instant::now();
        let on = |n| Some(Stamp { epoch: Epoch(1), number: Some(n) });
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive_from(on(2), ServerMessage::Confirmed(batch(80)), t0);
        s.receive_from(on(3), ServerMessage::Confirmed(batch(84)), t0);
        assert_eq!((s.stats().messages_lost, s.events().mismatched, s.events().unverified), (1, 0, 2));
        s.receive_from(on(1), welcome(0), t0);
        s.receive_from(on(4), ServerMessage::Events(batch(105)), t0);
        s.receive_from(on(5), ServerMessage::Events(batch(140)), t0);
        s.receive_from(on(6), ServerMessage::Confirmed(batch(105)), t0);
        assert_eq!((s.events().mismatched, s.events().unverified), (0, 3), "before the welcome's present");
        s.receive_from(on(7), ServerMessage::Confirmed(batch(140)), t0);
        assert_eq!((s.events().matched, s.events().mismatched), (1, 0), "published after the welcome: compared");

        // The same messages with none lost: compared from the first.
        let mut whole = Session::new(SessionConfig::new(ClientId(7)));
        whole.receive_from(on(1), ServerMessage::Events(batch(95)), t0);
        whole.receive_from(on(2), ServerMessage::Confirmed(batch(95)), t0);
        assert_eq!(whole.events().matched, 1);
    }

    /// A server gone for good: an idle game's last input brings one keepalive a second while an
    /// ack could still tell about it (64 seqs), then none; the keepalives await their answers
    /// apart from the game's.
    #[test]
    fn keepalives_stop_where_an_ack_could_no_longer_tell() {
        let (mut s, mut t) = played_three(SessionConfig::new(ClientId(7)));
        let mut sent = Vec::new();
        for _ in 0..100 {
            t += KEEPALIVE_AFTER;
            while let Some(m) = s.poll_transmit(t) {
                match m {
                    ClientMessage::Input(i) => sent.push(i.seq),
                    ClientMessage::Inputs(b) => sent.extend(b.inputs.last().map(|i| i.seq)),
                    other => panic!("{other:?}"),
                }
            }
        }
        assert_eq!(s.stats().keepalives, 64, "from seq 4 while seq 3 is within 64 of it: {sent:?}");
        assert_eq!(sent.last(), Some(&67));
        assert_eq!(s.pending_inputs(), 3, "the game's three await still");
        assert!(s.awaits(3) && !s.awaits(4), "a keepalive is not the game's");
    }

    /// Welcomed again after a reconnect: an input sent before the welcome that the server never
    /// accepted (at or above next_seq) is answered as lost once an input made after the welcome
    /// is acked, however long that takes: a path that stalls after the welcome holds the answers
    /// for seconds, and a refusal it held is an answer, not a loss. One accepted before (below
    /// next_seq) is not lost: that ack's `accepted_before` tells it accepted.
    #[test]
    fn inputs_lost_with_the_link_are_answered_as_lost() {
        let (mut s, mut t) = played_three(SessionConfig { redundancy: 0, ..SessionConfig::new(ClientId(7)) });
        let seqs: Vec<u32> = (1..=3).collect();
        // The link drops; back, the server welcomes again: it accepted the first input only.
        t += Duration::from_secs(1);
        s.receive(welcome(seqs[0] + 1), t);
        let after = s.input(walk(), t).unwrap();
        while s.poll_transmit(t).is_some() {}
        // The path stalls: nothing comes for 3 s, and that alone loses nothing.
        t += Duration::from_secs(3);
        while s.poll_transmit(t).is_some() {}
        assert!(s.take_answers().next().is_none(), "no length of silence tells an input lost");
        // Then what it held, in order: the refusal of one input, the ack of the one after.
        let stale = InputReject {
            client: ClientId(7),
            seq: Some(seqs[1]),
            reason: RejectReason::Stale,
            tick: None,
            detail: String::new(),
            oldest_tick: None,
            newest_tick: None,
        };
        s.receive(ServerMessage::Reject(stale), t);
        assert!(s.awaits(seqs[2]), "an answer to an input sent before the welcome settles nothing");
        let ServerMessage::Ack(mut a) = ack(after, 300, 4) else { unreachable!() };
        a.accepted_before = 1 << (after - seqs[0] - 1);
        s.receive(ServerMessage::Ack(a), t);
        let answers: Vec<(u32, Outcome)> = s.take_answers().map(|a| (a.seq, a.outcome)).collect();
        assert_eq!(answers[..2], [(seqs[1], Outcome::Rejected(RejectReason::Stale)), (after, answers[1].1)]);
        assert_eq!(answers[2..], [(seqs[0], Outcome::AckLost), (seqs[2], Outcome::Lost)]);
        // The keepalive the 3 s of silence brought awaits its answer still, but is not the game's.
        assert_eq!((s.stats().inputs_lost, s.pending_inputs(), s.stats().keepalives), (1, 0, 1));
    }

    /// A game that falls idle with inputs unanswered (sent into a server that stood still, or
    /// lost on a link): a second later the session sends an input of no actions, again each
    /// second while none is answered, and the ack of one tells what became of those before it.
    /// Its own answers are not the game's, and once none of the game's awaits one it sends none.
    #[test]
    fn an_idle_game_learns_the_fate_of_its_last_inputs() {
        let (mut s, mut t) = played_three(SessionConfig::new(ClientId(7)));
        let seqs: Vec<u32> = (1..=3).collect();
        let keepalive = |s: &mut Session, at: Instant| -> Option<u32> {
            let mut made = None;
            while let Some(m) = s.poll_transmit(at) {
                let newest = match m {
                    ClientMessage::Input(i) => i,
                    ClientMessage::Inputs(b) => b.inputs.last().cloned().expect("an input"),
                    other => panic!("{other:?}"),
                };
                assert!(newest.actions.is_empty(), "a keepalive has no actions: {newest:?}");
                made = Some(newest.seq);
            }
            made
        };
        assert_eq!(keepalive(&mut s, t + Duration::from_millis(900)), None, "not yet overdue");
        t += KEEPALIVE_AFTER;
        let first = keepalive(&mut s, t).expect("a keepalive after a second of silence");
        assert_eq!(keepalive(&mut s, t + Duration::from_millis(500)), None, "one a second");
        t += KEEPALIVE_AFTER;
        let second = keepalive(&mut s, t).expect("another while nothing is answered");
        assert_eq!(s.stats().keepalives, 2);
        // The server heard the second input and the second keepalive only.
        let ServerMessage::Ack(mut a) = ack(second, 300, 4) else { unreachable!() };
        a.accepted_before = 1 << (second - seqs[1] - 1);
        s.receive(ServerMessage::Ack(a), t);
        let mut answers: Vec<(u32, Outcome)> = s.take_answers().map(|a| (a.seq, a.outcome)).collect();
        answers.sort_by_key(|a| a.0);
        assert_eq!(answers, [(seqs[0], Outcome::Lost), (seqs[1], Outcome::AckLost), (seqs[2], Outcome::Lost)]);
        assert_eq!((s.stats().inputs_lost, s.awaits(first)), (3, false), "the first keepalive is lost too");
        assert_eq!(keepalive(&mut s, t + Duration::from_secs(5)), None, "nothing of the game's awaits");
        assert_eq!(s.pending_inputs(), 0);
    }

    /// After a welcome again, the ack of an input made after it settles every input made before
    /// it: those further back than the ack's `accepted_before` reaches (64 seqs) too.
    #[test]
    fn an_ack_after_a_welcome_again_tells_the_inputs_before_it_lost() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig { redundancy: 0, ..SessionConfig::new(ClientId(7)) });
        s.receive(welcome(0), t0);
        let t = t0 + SYNC_TIMEOUT;
        while s.poll_transmit(t).is_some() {}
        let before: Vec<u32> = (0..70).map(|_| s.input(walk(), t).unwrap()).collect();
        while s.poll_transmit(t).is_some() {}
        let back = t + Duration::from_secs(1);
        s.receive(welcome(before[0]), back);
        let after = s.input(walk(), back).unwrap();
        while s.poll_transmit(back).is_some() {}
        s.receive(ack(after, 200, 4), back + Duration::from_secs(2));
        let lost: Vec<u32> = s.take_answers().filter(|a| a.outcome == Outcome::Lost).map(|a| a.seq).collect();
        assert_eq!(lost.len(), 70, "{lost:?}");
        assert_eq!(s.pending_inputs(), 0);
    }

    /// A link lost and back: the ticks the server published meanwhile are confirmed without a
    /// comparison (their events never arrived), later ones are compared again.
    #[test]
    fn a_restored_link_leaves_the_ticks_before_it_uncompared() {
        use impact_protocol::EventBatch;
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        let batch = |tick| ServerMessage::Confirmed(EventBatch { tick: Tick(tick), revision: 0, events: vec![] });
        let held = |tick| ServerMessage::Events(EventBatch { tick: Tick(tick), revision: 0, events: vec![] });
        s.receive(held(101), t0);
        s.link_restored(t0);
        // Tick 102's events were published while the link was down: the view never had them.
        // Its confirmation makes tick 101 final too, and 101 was as exposed to the outage.
        s.receive(batch(102), t0);
        assert_eq!((s.events().mismatched, s.events().unverified), (0, 2));
        s.receive(batch(130), t0);
        assert_eq!(s.events().matched, 1, "a tick after the link came back is compared");
    }

    /// A session welcomed at tick 100 whose link was lost and came back at once, and when.
    fn restored() -> (Session, Instant) {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        s.link_restored(t0);
        (s, t0)
    }

    /// A batch of one event at `tick`.
    fn batch(tick: u32) -> impact_protocol::EventBatch {
        let events = vec![CollisionEvent { tick: Tick(tick), ..crate::events::tests::event(1, 2, 0.5) }];
        impact_protocol::EventBatch { tick: Tick(tick), revision: 0, events }
    }

    /// The client's link back before the server's (each side of a restarted router reconnects
    /// in its own time): what the server published until its own link was back was lost too, so
    /// the ticks before the first message it published after are left uncompared.
    #[test]
    fn ticks_before_the_first_message_after_a_restored_link_are_uncompared() {
        let (mut s, t0) = restored();
        // A second on, with the server at tick 164, its first message since comes.
        let t = t0 + Duration::from_secs(1);
        s.receive(ServerMessage::Events(batch(164)), t);
        // Tick 150's events went out before the server's link was back: never held.
        s.receive(ServerMessage::Confirmed(batch(150)), t);
        assert_eq!((s.events().mismatched, s.events().unverified), (0, 1));
        s.receive(ServerMessage::Confirmed(batch(164)), t);
        assert_eq!(s.events().matched, 1, "from that message on, ticks are compared");
    }

    /// The first message since a restored link may be a confirmed batch, published as its tick
    /// left the server's window (16 ticks): the ticks before that present are left uncompared,
    /// its own among them.
    #[test]
    fn a_confirmed_batch_first_after_a_restored_link_shows_the_server_present() {
        let (mut s, t0) = restored();
        let t = t0 + Duration::from_secs(1);
        s.receive(ServerMessage::Confirmed(batch(150)), t);
        s.receive(ServerMessage::Events(batch(170)), t);
        s.receive(ServerMessage::Confirmed(batch(160)), t);
        assert_eq!((s.events().mismatched, s.events().unverified), (0, 2), "150 and 160 went out before tick 166");
        s.receive(ServerMessage::Confirmed(batch(170)), t);
        assert_eq!(s.events().matched, 1);
    }

    /// A link back after old messages came late and pulled the clock back (a flood after the
    /// client itself stalled): the ticks lost are still left uncompared, up to the newest tick
    /// heard run on to the present.
    #[test]
    fn a_clock_pulled_back_by_late_messages_does_not_hide_lost_ticks() {
        use impact_protocol::EventBatch;
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(100), t0);
        let batch = |tick| ServerMessage::Events(EventBatch { tick: Tick(tick), revision: 0, events: vec![] });
        let confirmed = |tick| ServerMessage::Confirmed(EventBatch { tick: Tick(tick), revision: 0, events: vec![] });
        s.receive(batch(164), t0 + Duration::from_secs(1));
        // Two seconds on, messages of ticks 170 to 172 arrive over 40 ms (2.6 ticks; held on
        // the client's side): newer than any before, yet old, and going on long enough that the
        // clock follows them back.
        let t = t0 + Duration::from_secs(3);
        for (k, tick) in (170..=172).enumerate() {
            s.receive(batch(tick), t + Duration::from_millis(20 * k as u64));
        }
        let t = t + Duration::from_millis(40);
        assert!(s.clock().server_tick(t).is_some_and(|x| x.0 < 180), "the clock followed them back");
        s.link_restored(t);
        // The server was at 164 two seconds before: about 292 now. Tick 250 was published
        // while the link was down.
        // Ticks 164 and 170 to 172, held, are final with it: all five uncompared.
        s.receive(confirmed(250), t);
        assert_eq!((s.events().matched, s.events().unverified), (0, 5));
    }

    /// Joins, probes one at a time, and plays once five answers came: the first lead is the
    /// slowest round trip in ticks plus one, so the first input is stamped ahead.
    #[test]
    fn the_sync_sets_the_first_lead_before_any_input() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        assert_eq!(s.input(walk(), t0), Err(InputError::NotJoined));
        assert_eq!(s.poll_transmit(t0), None, "nothing before the welcome");
        s.receive(welcome(0), t0);
        assert_eq!(s.status(), Status::Syncing);
        let mut t = t0;
        for k in 0..SYNC_PROBES as u32 {
            let Some(ClientMessage::Ping(p)) = s.poll_transmit(t) else { panic!("a probe") };
            assert_eq!(p.id, k);
            assert_eq!(s.poll_transmit(t), None, "one probe in flight");
            // Round trips of 40 to 80 ms; the server is 3 ticks on when it answers.
            let rtt = Duration::from_millis(40 + 10 * u64::from(k));
            t += rtt;
            s.receive(ServerMessage::Pong(TimePong { client: ClientId(7), id: p.id, server_tick: Tick(103 + k) }), t);
        }
        assert_eq!(s.status(), Status::Playing);
        assert_eq!(s.stats().sync_samples, 5);
        // 80 ms at 64 Hz is 5.12 ticks: a lead of 7.
        assert_eq!(s.clock().lead(), Some(7.0));
        let seq = s.input(walk(), t).unwrap();
        assert_eq!(seq, 1);
        let Some(ClientMessage::Input(i)) = s.poll_transmit(t) else { panic!("the input") };
        assert_eq!(i.tick.0 - i.view_tick.unwrap().0, 7);
    }

    /// A server that never answers probes: play starts after the timeout, with no lead until an
    /// ack recommends one.
    #[test]
    fn a_silent_server_ends_the_sync_by_timeout() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        let mut probes = 0;
        let mut t = t0;
        while s.status() == Status::Syncing {
            probes += u32::from(matches!(s.poll_transmit(t), Some(ClientMessage::Ping(_))));
            t += Duration::from_millis(10);
        }
        assert_eq!(probes, 8, "one probe every 250 ms for 2 s");
        assert_eq!(s.clock().lead(), None);
    }

    /// Each input carries the unanswered ones before it (at most three); an ack removes one from
    /// the copies; a second welcome after a reconnect resumes the seqs, stops carrying those below
    /// its `next_seq`, and the next ack answers each of them.
    #[test]
    fn inputs_carry_the_unanswered_ones_and_resume_after_a_reconnect() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig { redundancy: 3, ..SessionConfig::new(ClientId(7)) });
        s.receive(welcome(0), t0);
        let t = t0 + SYNC_TIMEOUT;
        while s.poll_transmit(t).is_some() {}
        let seqs = |m: ClientMessage| match m {
            ClientMessage::Input(i) => vec![i.seq],
            ClientMessage::Inputs(b) => b.inputs.iter().map(|i| i.seq).collect(),
            ClientMessage::Ping(_) | ClientMessage::FullFrame(_) | ClientMessage::World(_) => vec![],
        };
        let mut sent = Vec::new();
        for _ in 0..5 {
            s.input(walk(), t).unwrap();
            sent.push(seqs(s.poll_transmit(t).unwrap()));
        }
        assert_eq!(sent, [vec![1], vec![1, 2], vec![1, 2, 3], vec![1, 2, 3, 4], vec![2, 3, 4, 5]]);
        s.receive(ack(3, 100, 4), t);
        s.input(walk(), t).unwrap();
        assert_eq!(seqs(s.poll_transmit(t).unwrap()), [4, 5, 6], "3 was answered; 2 left the copies");
        assert_eq!(s.stats().inputs_acked, 1);
        // Reconnected: the server accepted 5 and nothing after. 1, 2 and 4 still await their
        // answers (lost with the link), carried no more; the next ack tells.
        s.take_answers().for_each(drop);
        s.receive(welcome(6), t);
        assert_eq!((s.take_answers().count(), s.pending_inputs()), (0, 5));
        let t2 = t + Duration::from_millis(10);
        s.input(walk(), t2).unwrap();
        assert_eq!(seqs(s.poll_transmit(t2).unwrap()), [6, 7]);
        // Accepted before 7: 6, 5, 2 and 1; 4 was refused, its reject lost with the link.
        let ServerMessage::Ack(mut a) = ack(7, 110, 4) else { unreachable!() };
        a.accepted_before = 0b11_0011;
        s.receive(ServerMessage::Ack(a), t2);
        let told: Vec<(u32, Outcome)> = s.take_answers().map(|a| (a.seq, a.outcome)).collect();
        let (acked, lost_ack) = (Outcome::Accepted { applied_tick: Tick(110), margin_ticks: 0 }, Outcome::AckLost);
        assert_eq!(told, [(7, acked), (6, lost_ack), (5, lost_ack), (2, lost_ack), (1, lost_ack), (4, Outcome::Lost)]);
        assert_eq!((s.stats().inputs_acked, s.stats().acks_recovered, s.stats().inputs_lost), (6, 4, 1));
        assert_eq!(s.pending_inputs(), 0);
        // A server that remembers more than the client sent: the client's seqs jump past it.
        s.receive(welcome(20), t);
        assert_eq!(s.input(walk(), t), Ok(20));
    }

    /// Events, corrections and confirmations reach the game as news in arrival order, once each,
    /// and news the game never takes is bounded.
    #[test]
    fn event_news_comes_in_order_once_and_is_bounded() {
        use impact_protocol::EventBatch;
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        let e = |toi: f64| CollisionEvent { tick: Tick(101), ..crate::events::tests::event(1, 2, toi) };
        s.receive(ServerMessage::Events(EventBatch { tick: Tick(101), revision: 0, events: vec![e(0.5)] }), t0);
        let c =
            CorrectionBatch { tick: Tick(101), revision: 1, retracted: vec![], amended: vec![e(0.25)], added: vec![] };
        s.receive(ServerMessage::Corrections(c.clone()), t0);
        s.receive(ServerMessage::Confirmed(EventBatch { tick: Tick(101), revision: 1, events: vec![e(0.25)] }), t0);
        let news: Vec<EventNews> = s.take_event_news().collect();
        assert_eq!(
            news,
            [
                EventNews::Event(e(0.5)),
                EventNews::Corrected(c),
                EventNews::Confirmed { tick: Tick(101), matched: true }
            ]
        );
        assert_eq!(s.take_event_news().count(), 0, "taken once");
        for k in 0..MAX_EVENT_NEWS as u32 + 5 {
            s.receive(ServerMessage::Events(EventBatch { tick: Tick(200 + k), revision: 0, events: vec![e(0.5)] }), t0);
        }
        assert_eq!(s.take_event_news().count(), MAX_EVENT_NEWS);
        assert_eq!(s.stats().event_news_dropped, 5);
    }

    /// A tick whose own confirmed batch was lost (a later one came while it held an event) is
    /// given to the transport to ask for, once, and made final by the batch the server kept;
    /// another, never answered, is given up on after [`RECOVERY_WAIT`] as having no events.
    #[test]
    fn a_missed_confirmed_batch_is_asked_for_and_given_up_on_in_time() {
        use impact_protocol::EventBatch;
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        let e = |t: u32| CollisionEvent { tick: Tick(t), ..crate::events::tests::event(1, 2, 0.5) };
        let batch = |t: u32, events| EventBatch { tick: Tick(t), revision: 0, events };
        for t in [101, 102] {
            s.receive(ServerMessage::Events(batch(t, vec![e(t)])), t0);
        }
        s.receive(ServerMessage::Confirmed(batch(103, vec![])), t0);
        let _ = s.take_event_news().count();
        assert_eq!((s.poll_recovery(), s.poll_recovery(), s.poll_recovery()), (Some(Tick(101)), Some(Tick(102)), None));
        s.recovered(batch(101, vec![e(101)]));
        assert_eq!(s.take_event_news().collect::<Vec<_>>(), [EventNews::Confirmed { tick: Tick(101), matched: true }]);
        while s.poll_transmit(t0 + RECOVERY_WAIT / 2).is_some() {}
        assert_eq!(s.take_event_news().count(), 0, "tick 102 still waits");
        while s.poll_transmit(t0 + RECOVERY_WAIT).is_some() {}
        assert_eq!(s.take_event_news().collect::<Vec<_>>(), [EventNews::Confirmed { tick: Tick(102), matched: false }]);
        assert_eq!((s.events().recovered, s.events().matched, s.events().mismatched), (1, 2, 1));
    }

    /// Each input's first answer reaches the game once, typed, with its round trip; a second
    /// answer for the same seq is counted as unmatched, not repeated.
    #[test]
    fn answers_reach_the_game_once_each() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        let t = t0 + SYNC_TIMEOUT;
        while s.poll_transmit(t).is_some() {}
        let (a, b) = (s.input(walk(), t).unwrap(), s.input(walk(), t).unwrap());
        let later = t + Duration::from_millis(90);
        s.receive(ack(a, 101, 4), later);
        let reject = InputReject {
            client: ClientId(7),
            seq: Some(b),
            reason: RejectReason::RateLimited,
            tick: None,
            detail: String::new(),
            oldest_tick: None,
            newest_tick: None,
        };
        s.receive(ServerMessage::Reject(reject), later);
        s.receive(ack(a, 102, 4), later);
        // Two more inputs; the first one's ack is lost, the second's says it was accepted.
        let (c, d) = (s.input(walk(), t).unwrap(), s.input(walk(), t).unwrap());
        let ServerMessage::Ack(mut told) = ack(d, 103, 4) else { unreachable!() };
        told.accepted_before = 1 << (d - c - 1) | 1 << (d - a - 1);
        s.receive(ServerMessage::Ack(told), later);
        assert_eq!(s.pending_inputs(), 0);
        assert_eq!((s.stats().inputs_acked, s.stats().acks_recovered), (3, 1), "a was acked already");
        let answers: Vec<Answer> = s.take_answers().collect();
        assert_eq!(answers.len(), 4);
        assert_eq!((answers[3].seq, answers[3].outcome), (c, Outcome::AckLost));
        assert_eq!(answers[0].seq, a);
        assert_eq!(answers[0].outcome, Outcome::Accepted { applied_tick: Tick(101), margin_ticks: 0 });
        assert_eq!(answers[0].round_trip, Duration::from_millis(90));
        assert_eq!(answers[1].outcome, Outcome::Rejected(RejectReason::RateLimited));
        assert_eq!(s.stats().unmatched_answers, 1);
        assert_eq!(s.take_answers().count(), 0, "taken");
    }

    /// An input every copy of which went before a later input was made, and which that later
    /// input's ack does not count as accepted, never reached the server: answered `Lost`. One
    /// carried in the acked input's own message is not (it may have been refused, the refusal
    /// still on its way).
    #[test]
    fn an_input_passed_by_an_acked_one_is_lost() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig { redundancy: 1, ..SessionConfig::new(ClientId(7)) });
        s.receive(welcome(0), t0);
        let t = t0 + SYNC_TIMEOUT;
        while s.poll_transmit(t).is_some() {}
        let a = s.input(walk(), t).unwrap();
        let b = s.input(walk(), t + Duration::from_millis(10)).unwrap();
        // `a` rode again in `b`'s message; `c` is made after `a`'s last copy went, and carries `b`.
        let c = s.input(walk(), t + Duration::from_millis(20)).unwrap();
        while s.poll_transmit(t + Duration::from_millis(20)).is_some() {}
        let later = t + Duration::from_millis(100);
        s.receive(ack(b, 101, 4), later);
        assert!(s.awaits(a), "a rode in b's message: it may have been refused, not lost");
        s.receive(ack(c, 102, 4), later);
        let answers: Vec<Answer> = s.take_answers().collect();
        let outcome = |seq| answers.iter().find(|x| x.seq == seq).map(|x| x.outcome);
        assert_eq!(outcome(a), Some(Outcome::Lost), "{answers:?}");
        assert!(matches!(outcome(b), Some(Outcome::Accepted { .. })));
        assert_eq!((s.pending_inputs(), s.stats().inputs_lost), (0, 1));
    }

    /// A misprediction is put down to another body when one of the avatar's collision events
    /// falls in the eighth of a second before the state (the body may be one the stream never
    /// carried); a shot that hit the avatar moves nothing and explains nothing.
    #[test]
    fn the_avatars_collisions_explain_a_misprediction() {
        use impact_protocol::{CollisionEvent, EventBatch, EventStatus, Phase, Response};
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        let me = EntityId(3);
        let event = |tick: u32, phase: Phase| {
            let e = CollisionEvent {
                tick: Tick(tick),
                toi: 0.5,
                a: EntityId(9),
                b: EntityId(3),
                point: [0.0; 3],
                normal: [1.0, 0.0, 0.0],
                depth_m: 0.0,
                closing_speed_mps: 4.0,
                phase,
                response: Response::Bounce,
                status: EventStatus::Provisional,
            };
            ServerMessage::Events(EventBatch { tick: Tick(tick), revision: 0, events: vec![e] })
        };
        s.receive(event(120, Phase::Hit), t0);
        assert!(!s.collided(Tick(122), me), "a shot");
        s.receive(event(100, Phase::Begin), t0);
        assert!(!s.collided(Tick(122), me), "too long before (64 Hz: 8 ticks)");
        assert!(s.collided(Tick(104), me));
        s.receive(event(118, Phase::End), t0);
        assert!(s.collided(Tick(122), me));
    }

    /// A shot carries the tick the remote world is drawn at (the server rewinds it there), an
    /// interpolation delay behind the view tick; a move carries none.
    #[test]
    fn a_shot_carries_the_tick_it_was_aimed_at() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        let t = t0 + SYNC_TIMEOUT;
        while s.poll_transmit(t).is_some() {}
        let shot =
            Action::FireRay { shooter: EntityId(3), origin: [0.0; 3], direction: [1.0, 0.0, 0.0], max_distance_m: 9.0 };
        s.input(vec![shot], t).unwrap();
        let Some(ClientMessage::Input(i)) = s.poll_transmit(t) else { panic!("the shot") };
        let drawn = s.render_tick(t).unwrap();
        assert_eq!(i.aim_tick, Some(Tick(drawn.floor() as u32)));
        // 100 ms at 64 Hz: 6.4 ticks behind the view.
        assert_eq!(i.view_tick.unwrap().0 - i.aim_tick.unwrap().0, 7);
        s.receive(ack(i.seq, 100, 4), t);
        s.input(walk(), t).unwrap();
        let Some(ClientMessage::Input(w)) = s.poll_transmit(t) else { panic!("the walk") };
        assert_eq!(w.aim_tick, None);
    }

    /// Nothing for another client changes the session; an unknown kind is skipped and counted.
    /// The server's scene makes the predictor; one that does not rebuild to its hash, or a
    /// scene query that got nothing, says why instead.
    #[test]
    fn the_servers_scene_makes_the_predictor_or_says_why_not() {
        let t0 = Instant::now();
        let scene = impact_core::scene::Scene::load(&impact_core::scene::Scene::bundled_path("arena")).unwrap();
        let d = scene.describe();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(ServerMessage::Scene(Box::new(d.clone())), t0);
        assert!(s.predictor().is_some() && s.prediction_problem().is_none());

        let mut bent = d.clone();
        bent.statics[0].orientation[3] -= 1e-12;
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(ServerMessage::Scene(Box::new(bent)), t0);
        assert!(s.predictor().is_none());
        assert!(matches!(s.prediction_problem(), Some(PredictError::Described(e)) if e.entry == "scene_hash"));

        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.scene_unavailable("no server answered".into());
        assert!(s.prediction_problem().unwrap().to_string().contains("no server answered"));
        // Off in the config: the scene is not used.
        let mut s = Session::new(SessionConfig { predict: None, ..SessionConfig::new(ClientId(7)) });
        s.receive(ServerMessage::Scene(Box::new(d)), t0);
        assert!(s.predictor().is_none() && s.prediction_problem().is_none());
    }

    #[test]
    fn messages_for_others_are_skipped() {
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(8)));
        s.receive(welcome(0), t0);
        assert_eq!(s.status(), Status::Joining);
        assert_eq!(s.stats().skipped, 1);
        s.receive(ack(1, 100, 3), t0);
        assert_eq!(s.stats().skipped, 2);
        assert_eq!(s.stats().unmatched_answers, 0);
    }

    /// A gap in the state stream's frame numbers: a full frame is asked for at once and again
    /// every 250 ms while none came; none once one did.
    #[test]
    fn a_gap_in_the_state_stream_asks_for_a_full_frame() {
        use impact_protocol::StateFrame;
        let frame = |n: u32, full: bool| {
            ServerMessage::State(StateFrame {
                tick: Tick(100 + n),
                frame: n,
                full,
                entered: vec![],
                moved: vec![],
                left: vec![],
                deferred: 0,
                centre: None,
                avatar: None,
            })
        };
        let t0 = Instant::now();
        let mut s = Session::new(SessionConfig::new(ClientId(7)));
        s.receive(welcome(0), t0);
        let t = t0 + SYNC_TIMEOUT;
        let asks = |s: &mut Session, t: Instant| {
            std::iter::from_fn(|| s.poll_transmit(t)).filter(|m| matches!(m, ClientMessage::FullFrame(_))).count()
        };
        assert_eq!(asks(&mut s, t), 0, "no stream yet");
        s.receive(frame(0, true), t);
        s.receive(frame(1, false), t);
        assert_eq!(asks(&mut s, t), 0);
        s.receive(frame(3, false), t);
        assert_eq!(asks(&mut s, t), 1, "frame 2 lost");
        assert_eq!(asks(&mut s, t + Duration::from_millis(100)), 0, "not again so soon");
        assert_eq!(asks(&mut s, t + Duration::from_millis(260)), 1, "still none: again");
        s.receive(frame(5, true), t + Duration::from_millis(300));
        assert_eq!(asks(&mut s, t + Duration::from_millis(600)), 0, "the full frame came");
        assert_eq!(s.stats().full_frames_asked, 2);
    }
}
