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
use impact_client::bot;
use impact_client::predict::{PredictConfig, Predictor};
use impact_client::report::PlayReport;
use impact_client::transport::{ConnectOptions, Connection, Credentials, Mode};
use impact_client::{Session, SessionConfig, Status};
use impact_core::scene::Scene;
use impact_protocol::{ClientId, WorldId};
use std::time::{Duration, Instant};

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
    let mut opts = ConnectOptions::new(a.connect.clone(), world, client);
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
    let mut next_input = start;
    let mut inputs = 0u64;
    let mut drawn = Vec::new();
    // Counts frames and shots, and twice a second checks what was drawn against the server's
    // record of the same tick (`query/state`): the interpolation error.
    let mut report = PlayReport::new();
    while Instant::now() < end {
        let now = Instant::now();
        conn.pump(&mut game, now)?;
        // The frame: draw the remote world at the render time (a game hands `drawn` to its
        // renderer), read this tick's events.
        game.draw_remote(now, &mut drawn);
        let me = game.draw_avatar(now);
        report.frame(&conn, &game, now, &drawn);
        // A game shows its shots' results; the session counts hits. A hit on the body aimed at
        // (as drawn) shows the shot was judged against what the player saw.
        for r in game.take_ray_results() {
            report.ray_result(&r);
        }
        if let (Some(avatar), true) = (game.avatar(), now >= next_input) {
            next_input += input_every;
            inputs += 1;
            let character = game.predictor().is_some_and(|p| p.is_character());
            let t = now.duration_since(start).as_secs_f64();
            let (action, target) = bot::next_action(&drawn, me, (avatar, character), inputs, t);
            let seq = game.input(vec![action], now)?;
            if let Some(t) = target {
                report.aimed(seq, t);
            }
        }
        std::thread::sleep(frame.saturating_sub(now.elapsed()));
    }
    // The answers still owed.
    let settle = Instant::now() + Duration::from_millis(500);
    while Instant::now() < settle && game.pending_inputs() > 0 {
        conn.pump(&mut game, Instant::now())?;
        std::thread::sleep(frame);
    }
    let summary = report.summary(&game, &conn, a.seconds);
    conn.close();
    println!("{}", serde_json::to_string(&summary)?);
    Ok(())
}
