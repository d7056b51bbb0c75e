//! A game's rules as a process of their own: a deathmatch on `scenes/field.toml`, run by a client
//! with the game-logic role.
//!
//! ```sh
//! cargo run --release -p impact-server -- --scene scenes/field.toml --logic-client 900 --open-worlds 2 &
//! cargo run --release -p impact-client --example logic -- --world field --seconds 60 &
//! cargo run --release -p impact-client-sim --bin impact-sim -- --world field --clients 20 \
//!     --behaviour fighter --predict 20 --duration 60s
//! ```
//!
//! It hears every client's answers (`client/*/ack`: who joined with which avatar, every shot and
//! what it hit). A hit costs the player hit 25 health; at 0 the shooter scores a kill and the
//! player becomes a ghost (`set_class`), lifted out of the game (`teleport`), and three seconds
//! later is put back at a spawn point as a player with full health. Health, kills and deaths are
//! each player's game state (`set_state`), which the state streams carry to the players near
//! them. Every `--match-s` seconds the match ends: the scores are printed, the next match's world
//! opens from the scene (`field-2`, `field-3`, ...), and the rules close this one naming it, so
//! its players follow (PROTOCOL.md, "Worlds at run time"); a server that opens no worlds gets the
//! next match in the same world instead (everyone back at a spawn point, scores cleared). Its
//! commands are inputs: acked with their tick, rolled back and recorded like any other. At the
//! end it prints a one-line JSON summary (`kills`, `respawns`, `matches`, `worlds_opened`,
//! `commands_sent`, `commands_acked`, `commands_refused`, `players`).

use clap::Parser;
use impact_client::transport::{decode_server, world_command, ConnectOptions, Connection};
use impact_client::{Outcome, Session, SessionConfig, Status};
use impact_protocol::{Action, ClientId, EntityId, GameState, ServerMessage, WorldCommand, WorldId, WorldOutcome};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use zenoh::Wait;

#[derive(Parser, Debug)]
#[command(about = "A deathmatch's rules, as an impact game-logic client")]
struct Args {
    /// Zenoh endpoint of the server or router.
    #[arg(long, default_value = "tcp/127.0.0.1:7447")]
    connect: Vec<String>,
    /// The world.
    #[arg(long, default_value = "field")]
    world: String,
    /// The logic's client id (the server's --logic-client, or a `role = "logic"` user).
    #[arg(long, default_value_t = 900)]
    client: u32,
    /// How long to run, seconds.
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// How long a match lasts, seconds.
    #[arg(long, default_value_t = 30.0)]
    match_s: f64,
    /// The scene each new match's world opens from (the server's `--open-worlds` scenes).
    #[arg(long, default_value = "field")]
    scene: String,
}

/// Damage of one hit; health starts at 100.
const DAMAGE: i32 = 25;
/// How long a player shot down stays a ghost.
const RESPAWN: Duration = Duration::from_secs(3);
/// Where ghosts wait, out of everyone's way.
const LIMBO: [f64; 3] = [0.0, 60.0, 0.0];
/// The `k`th spawn point: 64 spots 8 m apart over the field (clear of the wall at z = -10), and
/// for the 65th player on, 0.8 m beside them, so that a whole match starting at once (every
/// player put back in one tick) puts no two players inside each other.
fn spawn_point(k: usize) -> [f64; 3] {
    let (spot, beside) = (k % 64, (k / 64) as f64);
    let (x, z) = ((spot % 8) as f64 * 8.0 - 28.0, (spot / 8) as f64 * 8.0 - 28.0);
    // The row at z = -12 moves 4 m away from the wall.
    let z = if (z + 10.0).abs() < 3.0 { z - 4.0 } else { z };
    [x + 0.8 * (beside % 8.0), 4.0, z]
}

/// A player's game state as the streams carry it.
fn state(health: i32, kills: u32, deaths: u32) -> GameState {
    GameState::from([("health", f64::from(health)), ("kills", f64::from(kills)), ("deaths", f64::from(deaths))])
}

/// A player as the rules see it.
struct Player {
    avatar: EntityId,
    health: i32,
    /// Shot down: back at this instant.
    back_at: Option<Instant>,
    kills: u32,
    deaths: u32,
}

#[derive(Default)]
struct Tally {
    worlds: u64,
    kills: u64,
    respawns: u64,
    matches: u64,
    sent: u64,
    acked: u64,
    refused: u64,
}

fn main() {
    let a = Args::parse();
    if let Err(e) = run(&a) {
        eprintln!("logic: {e}");
        std::process::exit(1);
    }
}

/// One match: the world it runs in, the rules' connection to it and who plays it.
struct Match {
    world: WorldId,
    conn: Connection,
    rules: Session,
    heard: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    players: BTreeMap<ClientId, Player>,
}

type Error = Box<dyn std::error::Error>;

impl Match {
    /// Connects the rules to `world` and listens to every client's answers there (before any
    /// player joins it, when the world is new, so that no welcome goes unheard).
    fn connect(a: &Args, world: WorldId) -> Result<Match, Error> {
        let me = ClientId(a.client);
        // The rules draw nothing and predict nothing: no state stream, no scene.
        let opts =
            ConnectOptions { state: false, scene: false, ..ConnectOptions::new(a.connect.clone(), world.clone(), me) };
        let conn = Connection::open(&opts)?;
        let every_ack = format!("impact/{}/{}/client/*/ack", impact_protocol::keys::VERSION, world.as_str());
        // Every player's answers: a second of 300 busy players and more. A full channel would
        // hold up the session's other traffic (a world command's answer among it) until drained.
        let heard = conn
            .zenoh()
            .declare_subscriber(every_ack)
            .with(zenoh::handlers::FifoChannel::new(1 << 16))
            .wait()
            .map_err(|e| e.to_string())?;
        let rules = Session::new(SessionConfig { predict: None, ..SessionConfig::new(me) });
        Ok(Match { world, conn, rules, heard, players: BTreeMap::new() })
    }

    /// Waits for the rules' welcome.
    fn join(&mut self) -> Result<(), Error> {
        let joined_by = Instant::now() + Duration::from_secs(10);
        while self.rules.status() != Status::Playing {
            self.conn.pump(&mut self.rules, Instant::now())?;
            if Instant::now() > joined_by {
                return Err(format!("not welcomed within 10 s: is the server running world {}?", self.world).into());
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        if self.rules.avatar().is_some() {
            let c = self.rules.config().client.0;
            return Err(format!("client {c} got an avatar: start the server with --logic-client {c}").into());
        }
        Ok(())
    }

    fn send(&mut self, actions: Vec<Action>, tally: &mut Tally) {
        if self.rules.input(actions, Instant::now()).is_ok() {
            tally.sent += 1;
        }
    }
}

fn run(a: &Args) -> Result<(), Error> {
    let mut game = Match::connect(a, WorldId::new(&a.world)?)?;
    game.join()?;
    eprintln!("logic: running the deathmatch of world {} as client {}", a.world, a.client);
    let mut tally = Tally::default();
    let mut next_spawn = 0usize;
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(a.seconds);
    let mut match_end = start + Duration::from_secs_f64(a.match_s);
    let mut moves = true;
    while Instant::now() < end {
        let now = Instant::now();
        referee(&mut game, now, &mut tally)?;
        // The match's end: the next one opens in a world of its own and the players follow,
        // or (a server that opens no worlds) it starts again in this one.
        let mut restart = false;
        if now >= match_end {
            tally.matches += 1;
            let scores: BTreeMap<u32, (u32, u32)> =
                game.players.iter().map(|(c, p)| (c.0, (p.kills, p.deaths))).collect();
            println!(
                "{}",
                serde_json::json!({"match": tally.matches, "world": game.world, "scores (kills, deaths)": scores})
            );
            match_end += Duration::from_secs_f64(a.match_s);
            if moves {
                match next_match(a, &game, tally.matches + 1) {
                    Ok(next) => {
                        game.conn.close();
                        game = next;
                        game.join()?;
                        tally.worlds += 1;
                    }
                    Err(e) => {
                        eprintln!("logic: {e}: the matches start again in world {}", game.world);
                        moves = false;
                        restart = true;
                    }
                }
            } else {
                restart = true;
            }
        }
        let due: Vec<ClientId> = game
            .players
            .iter()
            .filter(|(_, p)| restart || p.back_at.is_some_and(|t| t <= now))
            .map(|(c, _)| *c)
            .collect();
        for c in due {
            let p = game.players.get_mut(&c).expect("listed");
            if restart {
                (p.kills, p.deaths) = (0, 0);
            }
            let at = spawn_point(next_spawn);
            next_spawn += 1;
            let out = vec![
                Action::Teleport { entity: p.avatar, position: at, velocity: Some([0.0; 3]) },
                Action::SetClass { entity: p.avatar, class: "player".into() },
                Action::SetState { entity: p.avatar, values: state(100, p.kills, p.deaths) },
            ];
            tally.respawns += u64::from(p.back_at.is_some());
            (p.health, p.back_at) = (100, None);
            game.send(out, &mut tally);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let summary = serde_json::json!({
        "kills": tally.kills,
        "respawns": tally.respawns,
        "matches": tally.matches,
        "worlds_opened": tally.worlds,
        "commands_sent": tally.sent,
        "commands_acked": tally.acked,
        "commands_refused": tally.refused,
        "players": game.players.len(),
    });
    println!("{summary}");
    game.conn.close();
    Ok(())
}

/// Opens match `n`'s world (`{world}-{n}`, from the scene), listens there, and closes this
/// match's world naming it: its players follow.
fn next_match(a: &Args, game: &Match, n: u64) -> Result<Match, Error> {
    let me = ClientId(a.client);
    let next = WorldId::new(format!("{}-{n}", a.world))?;
    let t = Duration::from_secs(10);
    let open = WorldCommand::Open { scene: a.scene.clone() };
    match world_command(game.conn.zenoh(), &next, me, open, t)?.outcome {
        WorldOutcome::Opened { .. } => {}
        o => return Err(format!("opening world {next}: {o:?}").into()),
    }
    let following = Match::connect(a, next.clone())?;
    let reason = format!("match {} over", n - 1);
    let close = WorldCommand::Close { next: Some(next.clone()), reason };
    match world_command(game.conn.zenoh(), &game.world, me, close, t)?.outcome {
        WorldOutcome::Closed { .. } => eprintln!("logic: world {} closed, match {n} in world {next}", game.world),
        o => return Err(format!("closing world {}: {o:?}", game.world).into()),
    }
    Ok(following)
}

/// The rules' answers and every client's: who joined, and every shot that hit.
fn referee(game: &mut Match, now: Instant, tally: &mut Tally) -> Result<(), Error> {
    game.conn.pump(&mut game.rules, now)?;
    for answer in game.rules.take_answers() {
        match answer.outcome {
            Outcome::Rejected(why) => {
                tally.refused += 1;
                eprintln!("logic: command {} refused: {why:?}", answer.seq);
            }
            _ => tally.acked += 1,
        }
    }
    let me = game.rules.config().client;
    while let Ok(Some(sample)) = game.heard.try_recv() {
        match decode_server(&sample) {
            Ok(ServerMessage::Welcome(w)) if w.client != me => {
                if let Some(avatar) = w.avatar {
                    let p = Player { avatar, health: 100, back_at: None, kills: 0, deaths: 0 };
                    let p = game.players.entry(w.client).or_insert(p);
                    p.avatar = avatar;
                    let values = state(p.health, p.kills, p.deaths);
                    game.send(vec![Action::SetState { entity: avatar, values }], tally);
                }
            }
            Ok(ServerMessage::RayResult(r)) => hit(game, &r, now, tally),
            _ => {}
        }
    }
    Ok(())
}

/// A shot's outcome: 25 health off the player hit, and at 0 a kill.
fn hit(game: &mut Match, r: &impact_protocol::RayResult, now: Instant, tally: &mut Tally) {
    let Some(hit) = &r.hit else { return };
    // A ghost's shots do not count; only a live player can be hit.
    if game.players.get(&r.client).is_none_or(|p| p.back_at.is_some()) {
        return;
    }
    let Some((&victim, p)) =
        game.players.iter_mut().find(|(c, p)| p.avatar == hit.entity && p.back_at.is_none() && **c != r.client)
    else {
        return;
    };
    p.health -= DAMAGE;
    if p.health > 0 {
        let hurt = GameState::from([("health", f64::from(p.health))]);
        let avatar = p.avatar;
        game.send(vec![Action::SetState { entity: avatar, values: hurt }], tally);
        return;
    }
    p.deaths += 1;
    p.back_at = Some(now + RESPAWN);
    let (avatar, down) = (p.avatar, state(0, p.kills, p.deaths));
    tally.kills += 1;
    let mut out = vec![
        Action::SetClass { entity: avatar, class: "ghost".into() },
        Action::Teleport { entity: avatar, position: LIMBO, velocity: Some([0.0; 3]) },
        Action::SetState { entity: avatar, values: down },
    ];
    if let Some(shooter) = game.players.get_mut(&r.client) {
        shooter.kills += 1;
        let kills = GameState::from([("kills", f64::from(shooter.kills))]);
        out.push(Action::SetState { entity: shooter.avatar, values: kills });
    }
    eprintln!("logic: client {} shot down client {}", r.client.0, victim.0);
    game.send(out, tally);
}
