//! The numerical stress cases, each with the bound `impact-bench stability` applies (the same
//! functions, `impact_server::stability`). Here the heavy cases run at a size that keeps
//! `cargo test` quick; CI also runs the full-size suite (`impact-bench stability`, which fails
//! on any missed bound): a pile of 1,000 spheres for 10,000 ticks, an elastic box for 100,000
//! ticks, 10,000 ticks of depth-16 rollbacks.

use impact_server::stability::{self, CaseResult};

fn check(r: CaseResult) {
    assert!(r.pass, "{}: {} (figures: {:?})", r.case, r.detail, r.figures);
}

#[test]
fn far_from_origin_errors_stay_within_twice_the_origin() {
    check(stability::far_from_origin(100));
}

#[test]
fn radii_from_a_millimetre_to_a_kilometre() {
    check(stability::scale(60));
}

#[test]
fn grazing_parallel_coincident_static_and_tiny_pairs() {
    check(stability::degenerate());
}

#[test]
fn bullets_from_1_to_10000_mps_never_pass_a_1cm_wall() {
    check(stability::speed(60));
}

#[test]
fn a_pile_under_gravity_stays_in_its_box_without_sinking() {
    check(stability::pile(300, 1000));
}

#[test]
fn an_elastic_box_keeps_its_energy() {
    check(stability::elastic(100, 10_000));
}

#[test]
fn depth_16_rollbacks_every_tick_stay_bit_identical() {
    check(stability::rollback_stress(1000));
}
