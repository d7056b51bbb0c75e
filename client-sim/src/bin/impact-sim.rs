//! impact-sim: load-test an impact server with simulated clients behind a modelled network.

use anyhow::{bail, Context, Result};
use clap::Parser;
use impact_client::netsim::Link;
use impact_client_sim::load::{self, Behaviour, Faults, LoadConfig};
use impact_client_sim::net;
use impact_client_sim::report::latency_svg;
use impact_client_sim::timing::Timing;
use impact_protocol::{Encoding, WorldId};
use std::path::PathBuf;
use std::time::Duration;

/// Simulated clients for load tests.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Server (or router) endpoint(s).
    #[arg(long, default_value = "tcp/127.0.0.1:7447")]
    connect: Vec<String>,
    /// A Zenoh configuration file instead of --connect.
    #[arg(long)]
    zenoh_config: Option<PathBuf>,
    /// World name.
    #[arg(long, default_value = "arena")]
    world: String,
    /// Number of clients (at least 1).
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..))]
    clients: u32,
    /// Id of the first client (run several sims side by side with different ranges).
    #[arg(long, default_value_t = 1000)]
    first_client: u32,
    /// Zenoh sessions the clients share (default: one per 100 clients; with --users one each).
    #[arg(long)]
    sessions: Option<u32>,
    /// The server's users file: each client authenticates as the user that is its client id,
    /// over a session of its own.
    #[arg(long)]
    users: Option<PathBuf>,
    /// Length of the load, e.g. 30s or 2m.
    #[arg(long, default_value = "10s", value_parser = parse_duration)]
    duration: Duration,
    /// One-way latency, ms (each direction).
    #[arg(long, default_value_t = 80.0)]
    latency_ms: f64,
    /// Jitter, ms (latency +- jitter, uniform).
    #[arg(long, default_value_t = 20.0)]
    jitter_ms: f64,
    /// Probability an input is lost on the way to the server.
    #[arg(long, default_value_t = 0.0)]
    loss: f64,
    /// What players do.
    #[arg(long, value_enum, default_value_t = Behaviour::Mixed)]
    behaviour: Behaviour,
    /// How clients stamp inputs: `ahead` runs their clocks ahead of the server by the lead its
    /// acks recommend (inputs arrive on time, no rollback); `behind` stamps the tick they see
    /// (every input is late and rolled back). See PROTOCOL.md, "Timing".
    #[arg(long, value_enum, default_value_t = Timing::Ahead)]
    timing: Timing,
    /// Inputs per second per client.
    #[arg(long, default_value_t = 10.0)]
    input_hz: f64,
    /// Encoding of inputs (msgpack or json).
    #[arg(long, default_value = "msgpack")]
    encoding: Encoding,
    /// Write the JSON report here (and an SVG latency histogram beside it).
    #[arg(long)]
    report: Option<PathBuf>,
    /// Exit non-zero if the input-to-ack p99 exceeds this, ms.
    #[arg(long)]
    assert_p99_ms: Option<f64>,
    /// Exit non-zero if any client's view of its events differs from the confirmed stream, or a
    /// delivered input was never answered (with --outages: an input is still awaited, neither
    /// answered nor known to its client as lost).
    #[arg(long)]
    assert_views: bool,
    /// The run goes through outages the simulator does not make (a failover, a router restart,
    /// --drop-every): what they cut off may go unanswered, and must then be known lost.
    #[arg(long)]
    outages: bool,
    /// Every this long, one Zenoh session's clients drop and come back (sessions 1, 2, ... in
    /// turn; needs --sessions 2 or more): a phone's handover in a long run.
    #[arg(long, value_parser = parse_duration)]
    drop_every: Option<Duration>,
    /// How long each --drop-every drop lasts.
    #[arg(long, default_value = "1s", value_parser = parse_duration)]
    drop_for: Duration,
    /// Zenoh session mode: `client` talks only to the router it connects to (a deployment
    /// behind zenohd); `peer` may also connect to the servers directly.
    #[arg(long, value_enum, default_value_t = net::Mode::Peer)]
    zenoh_mode: net::Mode,
    /// Subscribe every client to its state stream (`client/{id}/state`) and report its bytes
    /// per client per second.
    #[arg(long)]
    state: bool,
    /// Game clients among them, spread over the ids: each reads its state stream, predicts its
    /// avatar with the core and draws at 60 frames a second; the report gives their prediction
    /// and interpolation errors. Each costs the load generator a predictor (a sample keeps
    /// 1,000 clients on one core). Default 0; with --demo, every client.
    #[arg(long)]
    predict: Option<u32>,
    /// Predict with this scene file instead of the rules and static world the server sends
    /// (`query/scene`); its hash must match the server's.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Seed for behaviour and the network model.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The demo: start a server on the arena scene in this process (on loopback, port 7447 when
    /// free, another otherwise),
    /// drive it with the clients, and print both reports. Defaults to 300 clients for 20 s with
    /// 80 +- 20 ms latency and 1 % loss, state streams on and every client predicting, unless
    /// those flags are given.
    #[arg(long)]
    demo: bool,
    /// With --demo: serve the live viewer here (`host:port`; a free port if this one is taken).
    #[arg(long, default_value = "127.0.0.1:8080")]
    viewer: String,
    /// With --demo: serve the play page here (an impact-gateway in this process, guests in the
    /// arena; a free port if this one is taken).
    #[arg(long, default_value = "127.0.0.1:8088")]
    play: String,
}

fn parse_duration(s: &str) -> Result<Duration, String> {
    let (num, unit) = s.split_at(s.find(|c: char| !c.is_ascii_digit() && c != '.').unwrap_or(s.len()));
    let v: f64 = num.parse().map_err(|_| format!("{s:?} is not a duration like 30s or 2m"))?;
    let secs = match unit {
        "" | "s" => v,
        "ms" => v / 1000.0,
        "m" => v * 60.0,
        _ => return Err(format!("{s:?}: unit must be ms, s or m")),
    };
    Ok(Duration::from_secs_f64(secs))
}

/// How many clients predict, and the scene file they predict with if one was given.
fn prediction(a: &Args) -> Result<(u32, Option<impact_core::scene::SceneRules>)> {
    let predict = a.predict.unwrap_or(0).min(a.clients);
    let Some(path) = a.scene.as_ref().filter(|_| predict > 0) else { return Ok((predict, None)) };
    let scene = impact_core::scene::Scene::load(path)
        .map_err(anyhow::Error::msg)
        .with_context(|| format!("--scene {}", path.display()))?;
    Ok((predict, Some(scene.rules())))
}

/// What the demo runs beside the load: the server, the live viewer and the play page's gateway.
struct Demo {
    server: impact_server::runtime::ServerHandle,
    viewer: impact_client_sim::web::Viewer,
    play: impact_gateway::gateway::Running,
    _session: zenoh::Session,
}

/// The demo's server (the arena, in this process), live viewer and play page; sets the demo's
/// defaults on `a` where the flags were not given.
fn start_demo(a: &mut Args) -> Result<Demo> {
    let given = |name: &str| std::env::args().any(|x| x == name || x.starts_with(&format!("{name}=")));
    if !given("--clients") {
        a.clients = 300;
    }
    if !given("--duration") {
        a.duration = Duration::from_secs(20);
    }
    if !given("--loss") {
        a.loss = 0.01;
    }
    a.state = true;
    a.predict = a.predict.or(Some(a.clients));
    // Zenoh's usual port when it is free, so a game started with its defaults (the Bevy
    // `arena`, `play`) joins the demo; any free port otherwise.
    let port = std::net::TcpListener::bind("127.0.0.1:7447")
        .or_else(|_| std::net::TcpListener::bind("127.0.0.1:0"))?
        .local_addr()?
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let scene = impact_core::scene::Scene::load(&impact_core::scene::Scene::bundled_path("arena"))
        .map_err(anyhow::Error::msg)?;
    eprintln!(
        "demo: impact-server on {endpoint}, arena scene ({} balls), 64 Hz, rollback 250 ms",
        scene.world.bodies.len()
    );
    let opts = impact_server::runtime::ServerOptions { listen: vec![endpoint.clone()], ..Default::default() };
    let server = impact_server::runtime::start(scene, opts)?;
    a.connect = vec![endpoint.clone()];
    a.world = "arena".into();
    std::thread::sleep(Duration::from_millis(300));
    let session = net::open(std::slice::from_ref(&endpoint), None, None, net::Mode::Peer)?;
    let world = WorldId::new("arena").map_err(anyhow::Error::msg)?;
    let viewer = impact_client_sim::web::Viewer::start(&session, &world, &a.viewer)
        .or_else(|_| impact_client_sim::web::Viewer::start(&session, &world, "127.0.0.1:0"))?;
    eprintln!("demo: watch it live at {}", viewer.url());
    let play = start_play(&session, world, &a.play)?;
    eprintln!(
        "demo: play in the browser at http://{}/ (WASD moves, Q/E down and up, a click on a body fires at it; \
         the demo runs {} s: --duration 10m for longer)",
        play.addr,
        a.duration.as_secs()
    );
    eprintln!(
        "demo: play in it (another terminal): cargo run --release -p impact-bevy --example arena -- --connect {endpoint}"
    );
    Ok(Demo { server, viewer, play, _session: session })
}

/// The play page: a gateway in this process whose guests play in `world`.
fn start_play(session: &zenoh::Session, world: WorldId, listen: &str) -> Result<impact_gateway::gateway::Running> {
    use impact_gateway::{auth::Authenticator, page::GuestPolicy, token::Secret, Config, Gateway};
    let config = Config {
        auth: Authenticator { users: None, secret: Some(Secret::random()?) },
        guests: Some(GuestPolicy::new(world)),
        ..Config::default()
    };
    let gw = Gateway::new(config, session.clone());
    let play = impact_gateway::gateway::start(gw.clone(), listen, 1)
        .or_else(|_| impact_gateway::gateway::start(gw, "127.0.0.1:0", 1))?;
    Ok(play)
}

fn main() -> Result<()> {
    let mut a = Args::parse();
    let mut demo = if a.demo { Some(start_demo(&mut a)?) } else { None };
    if !(0.0..=1.0).contains(&a.loss) {
        bail!("--loss {} must be in [0, 1]", a.loss);
    }
    let ms = |x: f64| Duration::from_secs_f64(x.max(0.0) / 1000.0);
    let (predict, scene) = prediction(&a)?;
    let sessions =
        if a.users.is_some() { a.clients } else { a.sessions.unwrap_or_else(|| a.clients.div_ceil(100).max(1)) };
    let drops = match a.drop_every {
        Some(_) if sessions < 2 => {
            bail!("--drop-every needs 2 or more sessions (--sessions): the first is never dropped")
        }
        Some(every) => Faults::periodic_drops(a.duration, sessions as usize, every, a.drop_for),
        None => Vec::new(),
    };
    let cfg = LoadConfig {
        connect: if a.zenoh_config.is_some() { Vec::new() } else { a.connect.clone() },
        zenoh_config: a.zenoh_config.clone(),
        mode: a.zenoh_mode,
        world: WorldId::new(a.world.clone()).map_err(anyhow::Error::msg)?,
        clients: a.clients,
        first_client: a.first_client,
        sessions,
        users: a.users.as_deref().map(impact_server::runtime::auth::load).transpose()?,
        duration: a.duration,
        uplink: Link { latency: ms(a.latency_ms), jitter: ms(a.jitter_ms), loss: a.loss },
        downlink: Link { latency: ms(a.latency_ms), jitter: ms(a.jitter_ms), loss: 0.0 },
        behaviour: a.behaviour,
        timing: a.timing,
        input_hz: a.input_hz,
        encoding: a.encoding,
        seed: a.seed,
        // Long enough for the last inputs to be acked and their ticks confirmed.
        settle: ms(4.0 * (a.latency_ms + a.jitter_ms) + 1500.0),
        progress: true,
        faults: Faults { drops: drops.clone(), ..Default::default() },
        state: a.state,
        predict,
        scene,
    };
    eprintln!(
        "impact-sim: {} clients ({} predicting, {:?}, timing {:?}) over {} sessions -> {}, {} s, latency {} +- {} ms, loss {}",
        cfg.clients,
        cfg.predict,
        cfg.behaviour,
        cfg.timing,
        cfg.sessions,
        a.connect.join(","),
        cfg.duration.as_secs_f64(),
        a.latency_ms,
        a.jitter_ms,
        a.loss
    );
    let report = load::run(&cfg)?;
    println!("{report}");
    if let Some(Demo { server, viewer, play, _session }) = demo.take() {
        drop(play);
        drop(viewer);
        println!("server:\n{}", server.stop());
    }
    if let Some(path) = &a.report {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
        let svg = path.with_extension("svg");
        std::fs::write(&svg, latency_svg(&report))?;
        println!("report: {} and {}", path.display(), svg.display());
    }
    if report.clients_welcomed < report.clients {
        eprintln!(
            "warning: {} of {} clients were never welcomed (is the server running the same world?)",
            report.clients - report.clients_welcomed,
            report.clients
        );
    }
    let outages = a.outages || !drops.is_empty();
    let silent = if outages { report.inputs_awaited } else { report.inputs_unanswered };
    if a.assert_views && (report.views_mismatched > 0 || silent > 0 || report.views_matched == 0) {
        bail!(
            "{} views differed from the confirmed stream ({} matched), {} {}",
            report.views_mismatched,
            report.views_matched,
            silent,
            if outages { "inputs still awaited (neither answered nor known lost)" } else { "inputs unanswered" }
        );
    }
    if let Some(bound) = a.assert_p99_ms {
        if report.latency_ms_p99 > bound || report.acks == 0 {
            bail!(
                "input-to-ack p99 {:.1} ms exceeds the bound {bound} ms (acks: {})",
                report.latency_ms_p99,
                report.acks
            );
        }
    }
    Ok(())
}
