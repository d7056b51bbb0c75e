//! A game client in one file: joins a world, moves its avatar and fires at the nearest body it
//! draws, reads the three views every frame at 60 Hz, and prints a one-line JSON summary.
//!
//! ```sh
//! cargo run --release -p impact-server -- --scene scenes/arena.toml &
//! cargo run --release -p impact-client --example play -- --connect tcp/127.0.0.1:7447 --world arena --seconds 20
//! ```
//!
//! On a world whose avatars are characters (`--scene scenes/field.toml` on the server, `--world
//! field` here) it walks by `move` intents and jumps now and then instead of setting velocities.
//!
//! Twice a second it also asks the server where every body was at the tick it just drew
//! (`query/state?tick=T`) and compares: the interpolation error, the distance between a remote
//! body as drawn and as the server had it at that tick.

use clap::Parser;
use impact_client::predict::{PredictConfig, Predictor};
use impact_client::remote::DrawnBody;
use impact_client::transport::{decode_server, ConnectOptions, Connection, Credentials, Mode};
use impact_client::{Session, SessionConfig, Status};
use impact_core::scene::Scene;
use impact_protocol::{keys, Action, ClientId, EntityId, ServerMessage, Tick, WorldId};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use zenoh::Wait;

#[derive(Parser, Debug)]
#[command(about = "Plays against an impact server: moves, fires, draws, and prints a JSON summary")]
struct Args {
    /// Zenoh endpoint of the server or router (repeatable).
    #[arg(long, default_value = "tcp/127.0.0.1:7447")]
    connect: Vec<String>,
    /// The world to join.
    #[arg(long, default_value = "arena")]
    world: String,
    /// How long to play, seconds.
    #[arg(long, default_value_t = 20.0)]
    seconds: f64,
    /// Client id (default: one from the process id, 100,000 and up, clear of impact-sim's).
    #[arg(long)]
    client: Option<u32>,
    /// Join through a router in Zenoh's client mode instead of as a peer.
    #[arg(long)]
    router: bool,
    /// User name, for a server started with --users.
    #[arg(long, requires = "password")]
    user: Option<String>,
    /// Password, with --user.
    #[arg(long, requires = "user")]
    password: Option<String>,
    /// Predict the avatar with this scene file instead of the rules and static world the server
    /// sends (`query/scene`); its hash must match the server's.
    #[arg(long)]
    scene: Option<std::path::PathBuf>,
    /// Do not predict the avatar.
    #[arg(long)]
    no_predict: bool,
    /// Inputs per second.
    #[arg(long, default_value_t = 10.0)]
    input_hz: f64,
}

fn main() {
    let args = Args::parse();
    if let Err(e) = play(&args) {
        eprintln!("play: {e}");
        std::process::exit(1);
    }
}

fn p99(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[((v.len() as f64 * 0.99).ceil() as usize).clamp(1, v.len()) - 1])
}

/// Every third input fires at the nearest other body drawn, from where the avatar is drawn (`me`,
/// predicted; or as the stream shows it), and says which; the others circle at 6 m/s, bobbing up
/// and down, or, for a character (moved by the server from intents), walk in a circle and jump
/// now and then.
fn next_action(
    drawn: &[DrawnBody],
    me: Option<[f64; 3]>,
    (avatar, character): (EntityId, bool),
    inputs: u64,
    t: f64,
) -> (Action, Option<EntityId>) {
    let me = me.or_else(|| drawn.iter().find(|b| b.entity == avatar).map(|b| b.position));
    if let Some(p) = me.filter(|_| inputs % 3 == 0) {
        let target = drawn
            .iter()
            .filter(|b| b.entity != avatar)
            .map(|b| (b, (0..3).map(|k| (b.position[k] - p[k]).powi(2)).sum::<f64>()))
            .filter(|(_, d)| *d > 1e-6)
            .min_by(|x, y| x.1.total_cmp(&y.1));
        if let Some((b, d)) = target {
            let d = d.sqrt();
            let direction = [0, 1, 2].map(|k| (b.position[k] - p[k]) / d);
            return (Action::FireRay { shooter: avatar, origin: p, direction, max_distance_m: 60.0 }, Some(b.entity));
        }
    }
    if character {
        let direction = [(0.7 * t).cos(), 0.0, (0.7 * t).sin()];
        return (Action::Move { entity: avatar, direction, jump: inputs % 7 == 0 }, None);
    }
    let velocity = [6.0 * (0.7 * t).cos(), 2.0 * (1.3 * t).sin(), 6.0 * (0.7 * t).sin()];
    (Action::SetVelocity { entity: avatar, velocity }, None)
}

/// A drawn world awaiting the server's positions at the same tick.
struct Check {
    tick: Tick,
    drawn: Vec<DrawnBody>,
    replies: zenoh::handlers::FifoChannelHandler<zenoh::query::Reply>,
}

impl Check {
    /// Compares what was drawn with the server's answer once it came (true: done).
    fn compare(&self, errors: &mut Vec<f64>, steady: &mut Vec<f64>) -> bool {
        let Ok(Some(reply)) = self.replies.try_recv() else { return false };
        if let Ok(ServerMessage::Snapshot(s)) =
            reply.result().map_err(|_| ()).and_then(|s| decode_server(s).map_err(|_| ()))
        {
            if s.tick == self.tick {
                let truth: BTreeMap<_, _> = s.bodies.iter().map(|b| (b.entity, b.position)).collect();
                for d in &self.drawn {
                    if let Some(p) = truth.get(&d.entity) {
                        let e = (0..3).map(|k| (d.position[k] - p[k]).powi(2)).sum::<f64>().sqrt();
                        errors.push(e);
                        if d.steady {
                            steady.push(e);
                        }
                    }
                }
            }
        }
        true
    }
}

/// Pumps until the session plays and, when it predicts, has the scene to predict with (at most
/// 10 s), then says how it joined.
fn join(conn: &Connection, game: &mut Session, client: ClientId) -> Result<(), Box<dyn std::error::Error>> {
    let frame = Duration::from_secs_f64(1.0 / 60.0);
    let joined_by = Instant::now() + Duration::from_secs(10);
    let predicting = game.config().predict.is_some();
    let ready = |g: &Session| {
        g.status() == Status::Playing && (!predicting || g.predictor().is_some() || g.prediction_problem().is_some())
    };
    while !ready(game) {
        conn.pump(game, Instant::now())?;
        if Instant::now() > joined_by {
            return Err(format!(
                "not ready within 10 s (status {:?}, scene {}): is the scene spawning avatars?",
                game.status(),
                if game.predictor().is_some() { "in" } else { "not in" }
            )
            .into());
        }
        std::thread::sleep(frame);
    }
    if let Some(e) = game.prediction_problem() {
        return Err(format!("prediction: {e}; or play without it: --no-predict").into());
    }
    let s = game.stats();
    eprintln!(
        "client {} joined: avatar {:?}, round trip {:.1}-{:.1} ms, lead {} ticks",
        client.0,
        game.avatar(),
        s.sync_rtt_min_s * 1e3,
        s.sync_rtt_max_s * 1e3,
        game.clock().lead().unwrap_or(0.0)
    );

    Ok(())
}

fn play(a: &Args) -> Result<(), Box<dyn std::error::Error>> {
    let world = WorldId::new(&a.world)?;
    let client = ClientId(a.client.unwrap_or(100_000 + std::process::id() % 100_000));
    let mut opts = ConnectOptions::new(a.connect.clone(), world.clone(), client);
    opts.mode = if a.router { Mode::Client } else { Mode::Peer };
    opts.credentials = a.user.clone().zip(a.password.clone()).map(|(user, password)| Credentials { user, password });
    opts.scene = !a.no_predict && a.scene.is_none();
    let conn = Connection::open(&opts)?;
    let predict = (!a.no_predict).then(PredictConfig::default);
    let mut game = Session::new(SessionConfig { predict: predict.clone(), ..SessionConfig::new(client) });
    if let (Some(path), Some(cfg)) = (&a.scene, predict) {
        game.predict_with(Predictor::new(&Scene::load(path)?.rules(), client, cfg)?);
    }

    join(&conn, &mut game, client)?;
    let frame = Duration::from_secs_f64(1.0 / 60.0);
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(a.seconds);
    let input_every = Duration::from_secs_f64(1.0 / a.input_hz.max(0.1));
    let (mut next_input, mut next_check) = (start, start + Duration::from_secs(1));
    let (mut frames, mut inputs, mut remote_bodies) = (0u64, 0u64, 0usize);
    let mut drawn = Vec::new();
    let mut checks: Vec<Check> = Vec::new();
    let mut interpolation_errors = Vec::new();
    let (mut aimed, mut shots, mut on_target) = (BTreeMap::new(), 0u64, 0u64);
    let mut steady_errors = Vec::new();
    let state_key = keys::QUERY_STATE.key(&world, None);
    while Instant::now() < end {
        let now = Instant::now();
        conn.pump(&mut game, now)?;
        // The frame: draw the remote world at the render time (a game hands `drawn` to its
        // renderer), read this tick's events.
        game.draw_remote(now, &mut drawn);
        let me = game.draw_avatar(now);
        remote_bodies = drawn.len();
        frames += 1;
        // A game shows its shots' results; the session counts hits. A hit on the body aimed at
        // (as drawn) shows the shot was judged against what the player saw.
        for r in game.take_ray_results() {
            if let Some(target) = aimed.remove(&r.seq) {
                on_target += u64::from(r.hit.is_some_and(|h| h.entity == target));
            }
        }
        if let (Some(avatar), true) = (game.avatar(), now >= next_input) {
            next_input += input_every;
            inputs += 1;
            let character = game.predictor().is_some_and(|p| p.is_character());
            let t = now.duration_since(start).as_secs_f64();
            let (action, target) = next_action(&drawn, me, (avatar, character), inputs, t);
            let seq = game.input(vec![action], now)?;
            if let Some(t) = target {
                aimed.insert(seq, t);
                shots += 1;
            }
        }
        // Twice a second: what was drawn at a whole tick, against the server's record of it.
        if let (true, Some(r)) = (now >= next_check, game.render_tick(now)) {
            next_check += Duration::from_millis(500);
            if let Some(remote) = game.remote() {
                let tick = Tick(r.floor().max(0.0) as u32);
                let mut at_tick = Vec::new();
                remote.draw(f64::from(tick.0), &mut at_tick);
                let replies = conn
                    .zenoh()
                    .get(format!("{state_key}?tick={}", tick.0))
                    .timeout(Duration::from_secs(2))
                    .wait()
                    .map_err(|e| format!("state query: {e}"))?;
                checks.push(Check { tick, drawn: at_tick, replies });
            }
        }
        checks.retain(|c| !c.compare(&mut interpolation_errors, &mut steady_errors));
        std::thread::sleep(frame.saturating_sub(now.elapsed()));
    }
    // The answers still owed.
    let settle = Instant::now() + Duration::from_millis(500);
    while Instant::now() < settle && game.pending_inputs() > 0 {
        conn.pump(&mut game, Instant::now())?;
        std::thread::sleep(frame);
    }
    let s = game.stats().clone();
    let pr = game.prediction().clone();
    let summary = serde_json::json!({
        "client": client.0,
        "seconds": a.seconds,
        "frames": frames,
        "inputs_sent": s.inputs_sent,
        "inputs_acked": s.inputs_acked,
        "rejects": s.rejects.values().sum::<u64>(),
        "events": s.events,
        "corrections": s.corrections,
        "hits": s.hits,
        "shots": shots,
        "hits_on_target": on_target,
        "remote_bodies": remote_bodies,
        "prediction_error_m_p99": p99(pr.errors_m.clone()),
        "prediction_error_untouched_m_p99": p99(pr.errors_untouched_m.clone()),
        "prediction_states": pr.compared,
        "prediction_exact": pr.exact,
        "prediction_causes": pr.causes,
        "prediction_max_frame_correction_m": pr.max_frame_correction_m,
        "interpolation_error_m_p99": p99(interpolation_errors.clone()),
        "interpolation_samples": interpolation_errors.len(),
        // Bodies nothing hit between the two frames they were drawn between.
        "interpolation_error_steady_m_p99": p99(steady_errors.clone()),
        "interpolation_steady_samples": steady_errors.len(),
        "view_mismatches": game.events().mismatched,
        "view_matches": game.events().matched,
        "rtt_ms_min": s.sync_rtt_min_s * 1e3,
        "rtt_ms_max": s.sync_rtt_max_s * 1e3,
        "welcomes": s.welcomes,
        "malformed": s.malformed,
        "inbox_dropped": conn.dropped(),
    });
    conn.close();
    println!("{summary}");
    Ok(())
}
