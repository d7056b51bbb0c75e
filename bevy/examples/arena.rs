//! The arena as a game: a top-down view of an impact world, your avatar moved with WASD, aimed
//! with the mouse, a click fires a hitscan ray; balls, players and walls drawn by shape, a flash
//! at each collision's point, your prediction error and round trip in a corner.
//!
//! ```sh
//! cargo run --release -p impact-server -- --scene scenes/arena.toml &
//! cargo run --release -p impact-bevy --example arena                       # a window
//! cargo run --release -p impact-bevy --example arena -- --headless --bot --seconds 20
//! ```
//!
//! `--bot` plays on its own (circles and fires at the nearest body, as `impact-client`'s `play`
//! example does); `--seconds` ends the game and prints the same one-line JSON summary as `play`;
//! `--screenshot FILE` saves the window after `--screenshot-after` seconds and ends.

use bevy::app::ScheduleRunnerPlugin;
use bevy::prelude::*;
use bevy::state::app::StatesPlugin;
use clap::Parser;
use impact_bevy::{
    Asleep, BodyClass, BodyOwner, BodyShape, Collision, Impact, ImpactInput, ImpactPlugin, ImpactState, RayHit,
    Refused, Sent, ServerEntity,
};
use impact_client::bot;
use impact_client::report::{p99, PlayReport};
use impact_client::transport::{ConnectOptions, Credentials, Mode};
use impact_protocol::{Action, ClientId, ShapeSpec, WorldId};
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Parser, Debug, Clone)]
#[command(about = "The arena as a game, on impact's Bevy plugin")]
struct Args {
    /// Zenoh endpoint of the server or router (repeatable).
    #[arg(long, default_value = "tcp/127.0.0.1:7447")]
    connect: Vec<String>,
    /// The world to join.
    #[arg(long, default_value = "arena")]
    world: String,
    /// End after this many seconds of play and print the summary (default: play until the
    /// window closes; headless, 20 s).
    #[arg(long)]
    seconds: Option<f64>,
    /// No window: Bevy's headless app, stepped 60 times a second.
    #[arg(long)]
    headless: bool,
    /// Play automatically: circle and fire at the nearest body drawn.
    #[arg(long)]
    bot: bool,
    /// Client id (default: one from the process id, 200,000 and up, clear of impact-sim's and
    /// `play`'s).
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
    /// Save a screenshot of the window here, then end.
    #[arg(long)]
    screenshot: Option<PathBuf>,
    /// Seconds of play before the screenshot.
    #[arg(long, default_value_t = 6.0)]
    screenshot_after: f64,
}

/// The game's own state: how long it plays and what it measured.
#[derive(Resource)]
struct Game {
    args: Args,
    /// When play started (the first frame in `Playing`).
    started: Option<Instant>,
    report: PlayReport,
    /// Fixed steps since the last input (the bot sends about 10 a second, like `play`).
    steps: u32,
    inputs: u64,
    /// Shots awaiting their `Sent` seq: the body aimed at.
    aiming: Option<impact_protocol::EntityId>,
    /// Collision points to flash, with when they were seen.
    flashes: Vec<(Vec3, Instant)>,
    /// Shots fired and awaiting their result: origin and direction, by seq.
    fired: std::collections::BTreeMap<u32, (Vec3, Vec3)>,
    /// Shots to draw: from, to, hit, when.
    tracers: Vec<(Vec3, Vec3, bool, Instant)>,
    /// Local refusals (not joined, closed) and server rejects seen.
    refused: u64,
    shot_saved: Option<PathBuf>,
    ended: bool,
}

fn main() {
    let args = Args::parse();
    let world = match WorldId::new(&args.world) {
        Ok(w) => w,
        Err(e) => {
            eprintln!("arena: --world: {e}");
            std::process::exit(2);
        }
    };
    let client = ClientId(args.client.unwrap_or(200_000 + std::process::id() % 100_000));
    let mut connect = ConnectOptions::new(args.connect.clone(), world, client);
    connect.mode = if args.router { Mode::Client } else { Mode::Peer };
    connect.credentials =
        args.user.clone().zip(args.password.clone()).map(|(user, password)| Credentials { user, password });

    let mut app = App::new();
    if args.headless {
        let frame = Duration::from_secs_f64(1.0 / 60.0);
        app.add_plugins((MinimalPlugins.set(ScheduleRunnerPlugin::run_loop(frame)), StatesPlugin));
    } else {
        app.add_plugins(DefaultPlugins.set(WindowPlugin {
            primary_window: Some(Window {
                title: "impact arena".into(),
                resolution: (1280u32, 800u32).into(),
                ..default()
            }),
            ..default()
        }))
        // Full speed when unfocused too (under Xvfb nothing has focus).
        .insert_resource(bevy::winit::WinitSettings::continuous())
        .insert_resource(ClearColor(Color::srgb(0.05, 0.05, 0.08)))
        .add_systems(Startup, setup_view)
        .add_systems(Update, (dress_bodies, follow_avatar, draw_outlines, flash, hud, screenshot))
        .add_systems(FixedUpdate, player.run_if(not_bot));
    }
    app.add_plugins(ImpactPlugin::new(connect))
        .insert_resource(Game {
            args: args.clone(),
            started: None,
            report: PlayReport::new(),
            steps: 0,
            inputs: 0,
            aiming: None,
            flashes: Vec::new(),
            fired: std::collections::BTreeMap::new(),
            tracers: Vec::new(),
            refused: 0,
            shot_saved: None,
            ended: false,
        })
        .add_systems(Update, (observe, end).chain())
        .add_systems(FixedUpdate, bot_player.run_if(is_bot));
    app.run();
}

fn is_bot(game: Res<'_, Game>) -> bool {
    game.args.bot
}

fn not_bot(game: Res<'_, Game>) -> bool {
    !game.args.bot
}

/// Every frame: the report counts it (and checks the drawing twice a second), shots are matched
/// to their results, collisions become flashes.
fn observe(
    mut game: ResMut<'_, Game>,
    impact: Res<'_, Impact>,
    state: Res<'_, State<ImpactState>>,
    mut sent: MessageReader<'_, '_, Sent>,
    mut hits: MessageReader<'_, '_, RayHit>,
    mut collisions: MessageReader<'_, '_, Collision>,
    mut refused: MessageReader<'_, '_, Refused>,
) {
    let now = Instant::now();
    let game = &mut *game;
    if *state.get() == ImpactState::Playing && game.started.is_none() {
        game.started = Some(now);
    }
    let v = |p: [f64; 3]| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32);
    for s in sent.read() {
        for a in &s.actions {
            if let Action::FireRay { origin, direction, .. } = a {
                if let Some(target) = game.aiming.take() {
                    game.report.aimed(s.seq, target);
                }
                if game.fired.len() < 256 {
                    game.fired.insert(s.seq, (v(*origin), v(*direction)));
                }
            }
        }
    }
    for h in hits.read() {
        game.report.ray_result(&h.0);
        if let Some((from, dir)) = game.fired.remove(&h.0.seq) {
            let to = h.0.hit.as_ref().map_or(from + dir * bot::RANGE_M as f32, |hit| v(hit.point));
            game.tracers.push((from, to, h.0.hit.is_some(), now));
        }
    }
    game.tracers.retain(|t| now.duration_since(t.3) < Duration::from_millis(250));
    for c in collisions.read() {
        let p = c.0.point;
        game.flashes.push((Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32), now));
    }
    game.flashes.retain(|(_, at)| now.duration_since(*at) < Duration::from_millis(300));
    game.flashes.truncate(512);
    game.refused += refused.read().count() as u64;
    if game.started.is_some() {
        let report = &mut game.report;
        impact.with_connection(|conn, session| report.frame(conn, session, now, impact.drawn()));
    }
}

/// Ends the game after `--seconds` of play (headless: 20 by default) or when the connection is
/// lost, printing the summary.
fn end(
    mut game: ResMut<'_, Game>,
    impact: Res<'_, Impact>,
    state: Res<'_, State<ImpactState>>,
    mut exit: MessageWriter<'_, AppExit>,
) {
    if game.ended {
        return;
    }
    let seconds = game.args.seconds.or(game.args.headless.then_some(20.0));
    let played = game.started.map_or(0.0, |s| s.elapsed().as_secs_f64());
    let lost = *state.get() == ImpactState::Lost;
    let waited_too_long = game.started.is_none() && seconds.is_some_and(|s| game_age() > s + 15.0);
    let over = seconds.is_some_and(|s| played >= s);
    let shot = game.shot_saved.as_ref().is_some_and(|p| std::fs::metadata(p).is_ok_and(|m| m.len() > 0));
    if !(over || lost || waited_too_long || shot) {
        return;
    }
    game.ended = true;
    if lost || waited_too_long {
        eprintln!("arena: {}", impact.problem().unwrap_or("the server never let us play"));
        exit.write(AppExit::error());
        return;
    }
    if let Some(s) = impact.with_connection(|conn, session| game.report.summary(session, conn, played)) {
        match serde_json::to_string(&s) {
            Ok(line) => println!("{line}"),
            Err(e) => eprintln!("arena: summary: {e}"),
        }
    }
    exit.write(AppExit::Success);
}

/// Seconds since the process started (the first call).
fn game_age() -> f64 {
    static START: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_secs_f64()
}

/// The bot: about ten inputs a second, circling and firing at the nearest body drawn.
fn bot_player(mut game: ResMut<'_, Game>, impact: Res<'_, Impact>, mut input: ResMut<'_, ImpactInput>) {
    game_age();
    let (Some(started), Some(avatar)) = (game.started, impact.session().avatar()) else { return };
    game.steps += 1;
    let hz = impact.session().clock().tick_hz().unwrap_or(64);
    if game.steps < hz.div_ceil(10) {
        return;
    }
    game.steps = 0;
    game.inputs += 1;
    let character = impact.session().predictor().is_some_and(|p| p.is_character());
    let t = started.elapsed().as_secs_f64();
    let (action, target) =
        bot::next_action(impact.drawn(), impact.avatar_position(), (avatar, character), game.inputs, t);
    game.aiming = target;
    input.push(action);
}

/// A person plays: WASD sets the avatar's velocity (or walks a character), a click fires at the
/// point under the cursor, at the avatar's height.
fn player(
    mut game: ResMut<'_, Game>,
    impact: Res<'_, Impact>,
    keys: Res<'_, ButtonInput<KeyCode>>,
    mouse: Res<'_, ButtonInput<MouseButton>>,
    window: Single<'_, '_, &Window>,
    camera: Single<'_, '_, (&Camera, &GlobalTransform)>,
    mut input: ResMut<'_, ImpactInput>,
) {
    let Some(avatar) = impact.session().avatar() else { return };
    let mut dir = Vec3::ZERO;
    for (key, d) in
        [(KeyCode::KeyW, -Vec3::Z), (KeyCode::KeyS, Vec3::Z), (KeyCode::KeyA, -Vec3::X), (KeyCode::KeyD, Vec3::X)]
    {
        if keys.pressed(key) {
            dir += d;
        }
    }
    let dir = dir.normalize_or_zero();
    game.steps += 1;
    // Movement six times a second and at once when a key changes.
    let changed = keys.get_just_pressed().len() + keys.get_just_released().len() > 0;
    if changed || game.steps >= 10 {
        game.steps = 0;
        let character = impact.session().predictor().is_some_and(|p| p.is_character());
        input.push(if character {
            Action::Move {
                entity: avatar,
                direction: [f64::from(dir.x), 0.0, f64::from(dir.z)],
                jump: keys.pressed(KeyCode::Space),
            }
        } else {
            let v = dir * 8.0;
            Action::SetVelocity { entity: avatar, velocity: [f64::from(v.x), 0.0, f64::from(v.z)] }
        });
    }
    let Some(me) = impact.avatar_position() else { return };
    if !mouse.just_pressed(MouseButton::Left) {
        return;
    }
    let (camera, at) = *camera;
    let Some(ray) = window.cursor_position().and_then(|c| camera.viewport_to_world(at, c).ok()) else { return };
    let height = me[1] as f32;
    let Some(d) = ray.intersect_plane(Vec3::new(0.0, height, 0.0), InfinitePlane3d::new(Vec3::Y)) else { return };
    let aim = ray.get_point(d) - Vec3::new(me[0] as f32, height, me[2] as f32);
    let Some(direction) = aim.try_normalize() else { return };
    input.push(Action::FireRay {
        shooter: avatar,
        origin: me,
        direction: [f64::from(direction.x), f64::from(direction.y), f64::from(direction.z)],
        max_distance_m: bot::RANGE_M,
    });
}

/// Where the camera sits relative to the avatar it follows: above and a little behind, seeing the
/// player's area (the state stream's, 10 m around it by default) and some floor beyond.
const CAMERA_OFFSET: Vec3 = Vec3::new(0.0, 26.0, 9.0);

fn setup_view(mut commands: Commands<'_, '_>) {
    commands.spawn((Camera3d::default(), Transform::from_translation(CAMERA_OFFSET).looking_at(Vec3::ZERO, Vec3::Y)));
    commands.spawn((
        DirectionalLight { illuminance: 8_000.0, ..default() },
        Transform::from_xyz(20.0, 60.0, 10.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
    commands.spawn((
        Text::new("joining"),
        Node { position_type: PositionType::Absolute, top: Val::Px(8.0), left: Val::Px(8.0), ..default() },
        Hud,
    ));
}

/// The corner text.
#[derive(Component)]
struct Hud;

/// The camera follows the own avatar as drawn (predicted).
fn follow_avatar(impact: Res<'_, Impact>, mut camera: Single<'_, '_, &mut Transform, With<Camera3d>>) {
    let Some(p) = impact.avatar_position() else { return };
    let me = Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32);
    **camera = Transform::from_translation(me + CAMERA_OFFSET).looking_at(me, Vec3::Y);
}

/// A fixed body drawn as an outline (walls and ceilings would hide the arena from above).
#[derive(Component)]
struct Outline;

/// Meshes for bodies as they appear: by shape, coloured by kind (you, other players, balls,
/// walls). Static bodies above the floor are outlines, not solids.
fn dress_bodies(
    mut commands: Commands<'_, '_>,
    impact: Res<'_, Impact>,
    new: Query<'_, '_, (Entity, &Transform, &BodyShape, &BodyClass, &BodyOwner), Added<ServerEntity>>,
    mut meshes: ResMut<'_, Assets<Mesh>>,
    mut materials: ResMut<'_, Assets<StandardMaterial>>,
) {
    let me = impact.session().config().client;
    for (e, at, shape, class, owner) in &new {
        let mine = owner.0 == Some(me);
        if shape.fixed && at.translation.y + shape.offset.y + shape.half_extents.y > 0.5 {
            commands.entity(e).insert(Outline);
            continue;
        }
        let mesh = match &shape.local {
            Some(ShapeSpec::Sphere { radius_m }) => meshes.add(Sphere::new(*radius_m as f32)),
            Some(ShapeSpec::Capsule { half_height_m, radius_m }) => {
                meshes.add(Capsule3d::new(*radius_m as f32, 2.0 * *half_height_m as f32))
            }
            Some(ShapeSpec::Cuboid { half_extents_m }) => meshes.add(Cuboid::new(
                2.0 * half_extents_m[0] as f32,
                2.0 * half_extents_m[1] as f32,
                2.0 * half_extents_m[2] as f32,
            )),
            _ => meshes.add(Cuboid::from_size(2.0 * shape.half_extents)),
        };
        let color = if mine {
            Color::srgb(0.2, 0.9, 0.3)
        } else if owner.0.is_some() {
            Color::srgb(0.3, 0.5, 1.0)
        } else if shape.fixed {
            Color::srgb(0.16, 0.17, 0.2)
        } else if class.0 == "ball" {
            Color::srgb(1.0, 0.6, 0.2)
        } else {
            Color::srgb(0.8, 0.8, 0.8)
        };
        commands.entity(e).insert((Mesh3d(mesh), MeshMaterial3d(materials.add(color))));
    }
}

/// Walls as outlines, a 5 m grid on the floor, sleeping bodies ringed.
fn draw_outlines(
    mut gizmos: Gizmos<'_, '_>,
    walls: Query<'_, '_, (&Transform, &BodyShape), With<Outline>>,
    asleep: Query<'_, '_, (&Transform, &BodyShape), With<Asleep>>,
) {
    let grid = Color::srgba(0.5, 0.55, 0.6, 0.25);
    for k in -6..=6 {
        let x = k as f32 * 5.0;
        gizmos.line(Vec3::new(x, 0.01, -30.0), Vec3::new(x, 0.01, 30.0), grid);
        gizmos.line(Vec3::new(-30.0, 0.01, x), Vec3::new(30.0, 0.01, x), grid);
    }
    for (t, shape) in &walls {
        let box_ = Transform::from_translation(t.translation + shape.offset).with_scale(2.0 * shape.half_extents);
        gizmos.cube(box_, Color::srgb(0.6, 0.6, 0.65));
    }
    for (t, shape) in &asleep {
        gizmos.circle(
            Isometry3d::new(t.translation, Quat::from_rotation_x(std::f32::consts::FRAC_PI_2)),
            shape.half_extents.x * 1.3,
            Color::srgb(0.5, 0.5, 1.0),
        );
    }
}

/// A flash at each collision's point; each shot's ray, red where it hit.
fn flash(game: Res<'_, Game>, mut gizmos: Gizmos<'_, '_>) {
    let now = Instant::now();
    for (from, to, hit, _) in &game.tracers {
        gizmos.line(*from, *to, if *hit { Color::srgb(1.0, 0.2, 0.2) } else { Color::srgb(0.7, 0.7, 0.7) });
        if *hit {
            gizmos.sphere(Isometry3d::from_translation(*to), 0.25, Color::srgb(1.0, 0.2, 0.2));
        }
    }
    for (p, at) in &game.flashes {
        let age = now.duration_since(*at).as_secs_f32() / 0.3;
        gizmos.sphere(Isometry3d::from_translation(*p), 0.3 + age, Color::srgba(1.0, 1.0, 0.3, 1.0 - age));
    }
}

/// The corner: state, round trip, prediction error, bodies.
fn hud(
    impact: Res<'_, Impact>,
    game: Res<'_, Game>,
    state: Res<'_, State<ImpactState>>,
    mut text: Single<'_, '_, &mut Text, With<Hud>>,
) {
    let s = impact.session();
    let pr = s.prediction();
    let recent = &pr.errors_m[pr.errors_m.len().saturating_sub(256)..];
    let untouched = &pr.errors_untouched_m[pr.errors_untouched_m.len().saturating_sub(256)..];
    let line = format!(
        "{:?}  client {}\nround trip {:.0}-{:.0} ms, lead {:.1} ticks\nprediction error p99 {:.1} mm, untouched {:.1} mm ({} states)\n{} bodies, {} hits, {} refused",
        state.get(),
        s.config().client.0,
        s.stats().sync_rtt_min_s * 1e3,
        s.stats().sync_rtt_max_s * 1e3,
        s.clock().lead().unwrap_or(0.0),
        p99(recent).unwrap_or(0.0) * 1e3,
        p99(untouched).unwrap_or(0.0) * 1e3,
        pr.compared,
        impact.drawn().len(),
        s.stats().hits,
        game.refused,
    );
    if text.0 != line {
        text.0 = line;
    }
}

/// `--screenshot`: the window after `--screenshot-after` seconds of play, saved once; the game
/// ends once the file is written.
fn screenshot(mut commands: Commands<'_, '_>, mut game: ResMut<'_, Game>) {
    use bevy::render::view::screenshot::{save_to_disk, Screenshot, ScreenshotCaptured};
    let (Some(path), Some(started)) = (game.args.screenshot.clone(), game.started) else { return };
    if game.shot_saved.is_some() || started.elapsed().as_secs_f64() < game.args.screenshot_after {
        return;
    }
    let _ = std::fs::remove_file(&path);
    let mut save = save_to_disk(path.clone());
    commands.spawn(Screenshot::primary_window()).observe(
        move |shot: On<'_, '_, ScreenshotCaptured>, mut exit: MessageWriter<'_, AppExit>| {
            save(shot);
            exit.write(AppExit::Success);
        },
    );
    game.shot_saved = Some(path);
}
