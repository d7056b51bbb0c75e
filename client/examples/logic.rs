//! A game's rules as a process of their own: a deathmatch on `scenes/field.toml`, run by a client
//! with the game-logic role.
//!
//! ```sh
//! cargo run --release -p impact-server -- --scene scenes/field.toml --logic-client 900 &
//! cargo run --release -p impact-client --example logic -- --world field --seconds 60 &
//! cargo run --release -p impact-client-sim --bin impact-sim -- --world field --clients 20 --behaviour shooter --duration 60s
//! ```
//!
//! It hears every client's answers (`client/*/ack`: who joined with which avatar, every shot and
//! what it hit). A hit costs the player hit 25 health; at 0 the shooter scores a kill and the
//! player becomes a ghost (`set_class`), lifted out of the game (`teleport`), and three seconds
//! later is put back at a spawn point as a player with full health. Every `--match-s` seconds the
//! match ends: the scores are printed and cleared, and everyone starts again at a spawn point.
//! Its commands are inputs: acked with their tick, rolled back and recorded like any other. At
//! the end it prints a one-line JSON summary (`kills`, `respawns`, `matches`, `commands_sent`,
//! `commands_acked`, `commands_refused`, `players`).
//!
//! Health and scores live in this process for now: the per-body game state the state streams
//! would carry to players is still to come (issue 28).

use clap::Parser;
use impact_client::transport::{decode_server, ConnectOptions, Connection};
use impact_client::{Outcome, Session, SessionConfig, Status};
use impact_protocol::{Action, ClientId, EntityId, ServerMessage, WorldId};
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

fn run(a: &Args) -> Result<(), Box<dyn std::error::Error>> {
    let world = WorldId::new(&a.world)?;
    let me = ClientId(a.client);
    // The rules draw nothing and predict nothing: no state stream, no scene.
    let opts =
        ConnectOptions { state: false, scene: false, ..ConnectOptions::new(a.connect.clone(), world.clone(), me) };
    let conn = Connection::open(&opts)?;
    let every_ack = format!("impact/{}/{}/client/*/ack", impact_protocol::keys::VERSION, world.as_str());
    let heard = conn.zenoh().declare_subscriber(every_ack).wait().map_err(|e| e.to_string())?;
    let mut rules = Session::new(SessionConfig { predict: None, ..SessionConfig::new(me) });
    let joined_by = Instant::now() + Duration::from_secs(10);
    while rules.status() != Status::Playing {
        conn.pump(&mut rules, Instant::now())?;
        if Instant::now() > joined_by {
            return Err("not welcomed within 10 s: is the server running this world?".into());
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    if rules.avatar().is_some() {
        return Err(format!("client {} got an avatar: start the server with --logic-client {}", me.0, me.0).into());
    }
    eprintln!("logic: running the deathmatch of world {} as client {}", a.world, me.0);

    let mut players: BTreeMap<ClientId, Player> = BTreeMap::new();
    let mut tally = Tally::default();
    let mut next_spawn = 0usize;
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(a.seconds);
    let mut match_end = start + Duration::from_secs_f64(a.match_s);
    let send = |rules: &mut Session, actions: Vec<Action>, tally: &mut Tally| {
        if rules.input(actions, Instant::now()).is_ok() {
            tally.sent += 1;
        }
    };
    while Instant::now() < end {
        let now = Instant::now();
        conn.pump(&mut rules, now)?;
        for answer in rules.take_answers() {
            match answer.outcome {
                Outcome::Rejected(why) => {
                    tally.refused += 1;
                    eprintln!("logic: command {} refused: {why:?}", answer.seq);
                }
                _ => tally.acked += 1,
            }
        }
        while let Ok(Some(sample)) = heard.try_recv() {
            match decode_server(&sample) {
                Ok(ServerMessage::Welcome(w)) if w.client != me => {
                    if let Some(avatar) = w.avatar {
                        let p = Player { avatar, health: 100, back_at: None, kills: 0, deaths: 0 };
                        players.entry(w.client).or_insert(p).avatar = avatar;
                    }
                }
                Ok(ServerMessage::RayResult(r)) => {
                    let Some(hit) = r.hit else { continue };
                    // A ghost's shots do not count; only a live player can be hit.
                    if players.get(&r.client).is_none_or(|p| p.back_at.is_some()) {
                        continue;
                    }
                    let Some((&victim, p)) = players
                        .iter_mut()
                        .find(|(c, p)| p.avatar == hit.entity && p.back_at.is_none() && **c != r.client)
                    else {
                        continue;
                    };
                    p.health -= DAMAGE;
                    if p.health > 0 {
                        continue;
                    }
                    p.deaths += 1;
                    p.back_at = Some(now + RESPAWN);
                    let avatar = p.avatar;
                    tally.kills += 1;
                    if let Some(shooter) = players.get_mut(&r.client) {
                        shooter.kills += 1;
                    }
                    eprintln!("logic: client {} shot down client {}", r.client.0, victim.0);
                    let out = vec![
                        Action::SetClass { entity: avatar, class: "ghost".into() },
                        Action::Teleport { entity: avatar, position: LIMBO, velocity: Some([0.0; 3]) },
                    ];
                    send(&mut rules, out, &mut tally);
                }
                _ => {}
            }
        }
        // Respawns that are due, and the match's end.
        let new_match = now >= match_end;
        if new_match {
            tally.matches += 1;
            let scores: BTreeMap<u32, (u32, u32)> = players.iter().map(|(c, p)| (c.0, (p.kills, p.deaths))).collect();
            println!("{}", serde_json::json!({"match": tally.matches, "scores (kills, deaths)": scores}));
            match_end += Duration::from_secs_f64(a.match_s);
        }
        for p in players.values_mut() {
            if new_match || p.back_at.is_some_and(|t| t <= now) {
                if new_match {
                    (p.kills, p.deaths) = (0, 0);
                }
                let at = spawn_point(next_spawn);
                next_spawn += 1;
                let out = vec![
                    Action::Teleport { entity: p.avatar, position: at, velocity: Some([0.0; 3]) },
                    Action::SetClass { entity: p.avatar, class: "player".into() },
                ];
                send(&mut rules, out, &mut tally);
                tally.respawns += u64::from(p.back_at.is_some());
                (p.health, p.back_at) = (100, None);
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let summary = serde_json::json!({
        "kills": tally.kills,
        "respawns": tally.respawns,
        "matches": tally.matches,
        "commands_sent": tally.sent,
        "commands_acked": tally.acked,
        "commands_refused": tally.refused,
        "players": players.len(),
    });
    println!("{summary}");
    conn.close();
    Ok(())
}
