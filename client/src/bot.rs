//! A scripted player, for examples and tests that play on their own (`play`, the Bevy `arena
//! --bot`): it moves in a circle and fires at the nearest body it draws.

use crate::remote::DrawnBody;
use impact_protocol::{Action, EntityId};

/// How far a bot's rays reach, metres.
pub const RANGE_M: f64 = 60.0;

/// A bot's next input, its `inputs`-th, `t` seconds into play: every third fires at the nearest
/// other body drawn, from where the avatar is drawn (`me`, predicted; or as the stream shows it),
/// and says which; the others circle at 6 m/s, bobbing up and down, or, for a character (moved
/// by the server from intents), walk in a circle and jump now and then.
pub fn next_action(
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
            let fire = Action::FireRay { shooter: avatar, origin: p, direction, max_distance_m: RANGE_M };
            return (fire, Some(b.entity));
        }
    }
    if character {
        let direction = [(0.7 * t).cos(), 0.0, (0.7 * t).sin()];
        return (Action::Move { entity: avatar, direction, jump: inputs % 7 == 0 }, None);
    }
    let velocity = [6.0 * (0.7 * t).cos(), 2.0 * (1.3 * t).sin(), 6.0 * (0.7 * t).sin()];
    (Action::SetVelocity { entity: avatar, velocity }, None)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(id: u32, x: f64) -> DrawnBody {
        DrawnBody {
            entity: EntityId(id),
            position: [x, 0.0, 0.0],
            velocity: [0.0; 3],
            extrapolated: false,
            steady: true,
            asleep: false,
        }
    }

    #[test]
    fn fires_at_the_nearest_other_body_every_third_input_and_moves_otherwise() {
        let drawn = [body(1, 0.0), body(2, 5.0), body(3, -2.0)];
        let (a, target) = next_action(&drawn, None, (EntityId(1), false), 3, 0.0);
        assert_eq!(target, Some(EntityId(3)));
        let Action::FireRay { direction, .. } = a else { panic!("a shot: {a:?}") };
        assert_eq!(direction, [-1.0, 0.0, 0.0]);
        let (a, target) = next_action(&drawn, None, (EntityId(1), false), 4, 0.0);
        assert!(target.is_none() && matches!(a, Action::SetVelocity { .. }), "{a:?}");
        let (a, _) = next_action(&drawn, None, (EntityId(1), true), 7, 0.0);
        assert!(matches!(a, Action::Move { jump: true, .. }), "a character walks and jumps: {a:?}");
    }
}
