//! The plugin in a Bevy `App` against a live server (in this process, on a loopback port): a
//! bounded number of updates, then assertions on the `World`, as Bevy's own tests do.

use bevy::ecs::message::MessageCursor;
use bevy::prelude::*;
use bevy::state::app::StatesPlugin;
use impact_bevy::{
    Answered, BodyClass, Collision, Impact, ImpactEntities, ImpactInput, ImpactPlugin, ImpactState, Interpolated,
    Predicted, Refused, Sent, ServerEntity,
};
use impact_client::transport::ConnectOptions;
use impact_client::Outcome;
use impact_core::scene::Scene;
use impact_protocol::{Action, ClientId, EntityId, RejectReason, WorldId};
use impact_server::runtime::{self, ServerOptions};
use std::collections::BTreeSet;
use std::time::{Duration, Instant};

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).map(|a| a.port()).expect("a free port")
}

/// An app with the plugin joined to `endpoint` as `client`.
fn app(endpoint: &str, client: u32) -> App {
    let connect = ConnectOptions::new(vec![endpoint.into()], WorldId::new("arena").unwrap(), ClientId(client));
    let mut app = App::new();
    app.add_plugins((MinimalPlugins, StatesPlugin, ImpactPlugin::new(connect)));
    app
}

/// Every message of type `M` the app wrote since the cursor last read.
fn read<M: Message + Clone>(app: &App, cursor: &mut MessageCursor<M>) -> Vec<M> {
    cursor.read(app.world().resource::<Messages<M>>()).cloned().collect()
}

/// Updates the app about 60 times a second until `done` or `limit` passes; whether `done` came.
fn run_until(app: &mut App, limit: Duration, mut done: impl FnMut(&mut App) -> bool) -> bool {
    let end = Instant::now() + limit;
    while Instant::now() < end {
        app.update();
        if done(app) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(16));
    }
    false
}

fn state(app: &App) -> ImpactState {
    *app.world().resource::<State<ImpactState>>().get()
}

#[test]
fn bodies_come_and_go_as_entities_the_avatar_is_predicted_and_events_arrive_as_messages() {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let scene = Scene::load(&Scene::bundled_path("arena")).unwrap();
    let server = runtime::start(scene, ServerOptions { listen: vec![endpoint.clone()], ..ServerOptions::default() })
        .expect("server starts");
    let mut app = app(&endpoint, 41);
    assert_eq!(state(&app), ImpactState::Joining);
    assert!(run_until(&mut app, Duration::from_secs(15), |a| state(a) == ImpactState::Playing), "never played");

    let (mut sent_c, mut answered_c) = (MessageCursor::<Sent>::default(), MessageCursor::<Answered>::default());
    let (mut refused_c, mut collisions_c) =
        (MessageCursor::<Refused>::default(), MessageCursor::<Collision>::default());
    let (mut sent, mut answered, mut refused, mut collisions) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut seen: BTreeSet<EntityId> = BTreeSet::new();
    let mut left = 0usize;
    let avatar = app.world().resource::<Impact>().session().avatar().expect("an avatar");
    let mut k = 0u32;
    // 6 s of play: the avatar circles, so balls enter and leave its 10 m area; one input in ten
    // moves a ball it does not own (refused).
    run_until(&mut app, Duration::from_secs(6), |app| {
        k += 1;
        let t = f64::from(k) / 60.0;
        app.world_mut()
            .resource_mut::<ImpactInput>()
            .push(Action::SetVelocity { entity: avatar, velocity: [8.0 * t.cos(), 0.0, 8.0 * t.sin()] });
        if k.is_multiple_of(10) {
            let world = app.world_mut();
            let ball = world.query::<(&ServerEntity, &BodyClass)>().iter(world).find(|(_, c)| c.0 == "ball");
            if let Some((ball, _)) = ball {
                let foreign = Action::SetVelocity { entity: ball.0, velocity: [0.0; 3] };
                world.resource_mut::<ImpactInput>().actions = vec![foreign];
            }
        }
        sent.extend(read(app, &mut sent_c));
        answered.extend(read(app, &mut answered_c));
        refused.extend(read(app, &mut refused_c));
        collisions.extend(read(app, &mut collisions_c));
        let now: BTreeSet<EntityId> = app.world_mut().query::<&ServerEntity>().iter(app.world()).map(|e| e.0).collect();
        left += seen.difference(&now).count();
        seen = seen.union(&now).copied().collect();
        false
    });

    // Entities: one per body the remote world holds, found by the map, and nothing else.
    let world = app.world_mut();
    let held: BTreeSet<EntityId> = {
        let impact = world.resource::<Impact>();
        let remote = impact.session().remote().expect("a remote world");
        impact.drawn().iter().map(|d| d.entity).filter(|e| remote.info(*e).is_some()).collect()
    };
    let now: BTreeSet<EntityId> = world.query::<&ServerEntity>().iter(world).map(|e| e.0).collect();
    assert!(now.len() >= 3, "a few bodies in the area: {now:?}");
    assert_eq!(now, held, "an entity for each body drawn, no more");
    let map = world.resource::<ImpactEntities>().clone();
    for id in &now {
        let e = map.get(*id).expect("mapped");
        assert_eq!(world.get::<ServerEntity>(e).map(|s| s.0), Some(*id));
    }
    assert!(left > 0, "bodies that left the area were despawned ({} seen)", seen.len());
    assert!(seen.len() > now.len(), "bodies came into the area and went");
    let balls = world.query_filtered::<&BodyClass, With<Interpolated>>().iter(world).filter(|c| c.0 == "ball").count();
    assert!(balls >= 1, "remote balls are interpolated entities");

    // The avatar: one predicted entity, where the prediction draws it.
    let mut predicted = world.query_filtered::<(&ServerEntity, &Transform), With<Predicted>>();
    let (me, at) = predicted.single(world).expect("exactly one predicted entity");
    assert_eq!(me.0, avatar);
    let impact = world.resource::<Impact>();
    let drawn = impact.avatar_position().expect("predicted");
    assert!(at.translation.distance(Vec3::new(drawn[0] as f32, drawn[1] as f32, drawn[2] as f32)) < 1e-3);
    let pr = impact.session().prediction();
    assert!(pr.compared >= 20, "{pr:?}");
    assert!(pr.errors_untouched_m.iter().all(|&e| e == 0.0), "untouched states predicted exactly: {pr:?}");

    // Inputs: one per fixed step at most, answered; the foreign ball's refused with its reason.
    assert!(sent.len() >= 200, "about 64 inputs a second: {}", sent.len());
    let accepted = answered.iter().filter(|a| matches!(a.0.outcome, Outcome::Accepted { .. })).count();
    assert!(accepted * 10 >= sent.len() * 8, "{accepted} of {} accepted", sent.len());
    assert!(!refused.is_empty(), "the foreign ball's input was refused");
    assert!(refused.iter().all(|r| r.reason == Some(RejectReason::NotOwner)), "{refused:?}");
    // Events: the arena's balls bounce off each other and the walls all the time.
    assert!(!collisions.is_empty(), "collision events arrived as messages");
    assert_eq!(state(&app), ImpactState::Playing);
    drop(app);
    server.stop();
}

#[test]
fn no_server_is_lost_with_the_reason() {
    // A listening peer with no server for the world in it.
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut c = zenoh::Config::default();
    c.insert_json5("scouting/multicast/enabled", "false").unwrap();
    c.insert_json5("listen/endpoints", &format!("[\"{endpoint}\"]")).unwrap();
    let _host = zenoh::Wait::wait(zenoh::open(c)).unwrap();
    let connect = ConnectOptions {
        find_server: Duration::from_millis(500),
        ..ConnectOptions::new(vec![endpoint], WorldId::new("arena").unwrap(), ClientId(42))
    };
    let mut app = App::new();
    app.add_plugins((MinimalPlugins, StatesPlugin, ImpactPlugin::new(connect)));
    assert!(run_until(&mut app, Duration::from_secs(10), |a| state(a) == ImpactState::Lost), "never lost");
    let problem = app.world().resource::<Impact>().problem().map(str::to_string);
    assert!(problem.as_deref().is_some_and(|p| p.contains("arena")), "{problem:?}");
}
