//! impact-bench: benchmarks as programs. Each suite prints a table for humans and, with
//! `--json`, one JSON object per line for machines. Peers (rapier) run in the same process on
//! the same scene, so ratios hold on a noisy shared machine where absolute times do not.

mod accuracy;
mod auth;
mod hitscan;
mod kernels;
mod plan;
mod report;
mod rest;
mod rollback;
mod scale;
mod stability;
mod state;
mod zenoh_rate;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// Benchmarks for impact.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    #[command(subcommand)]
    suite: Suite,
}

#[derive(Subcommand, Debug)]
enum Suite {
    /// N moving spheres: impact's core against rapier's CollisionPipeline, and the plans and
    /// broadphases against each other.
    Scale(scale::ScaleArgs),
    /// What the plan saves: an unused stage costs nothing, the sphere plan beats the general
    /// path.
    Plan(plan::PlanArgs),
    /// The cost of a rollback of depth d against the plain tick, full and selective.
    Rollback(rollback::RollbackArgs),
    /// Run time against error on scenes with known answers, rapier's CCD beside.
    Accuracy(accuracy::AccuracyArgs),
    /// Each analytic pair kernel against parry's general path: time, depth agreement, symmetry.
    Kernels(kernels::KernelsArgs),
    /// Bodies at rest under gravity (standing, a pile, a yard): impact against rapier's full
    /// physics pipeline with sleeping.
    Rest(rest::RestArgs),
    /// A lag-compensated shot rewound to the shooter's view tick, against the plain tick.
    Hitscan(hitscan::HitscanArgs),
    /// Numerical stress cases (far from the origin, scale, degenerate, speed, pile, energy,
    /// rollback).
    Stability(stability::StabilityArgs),
    /// What the state streams cost beside the tick: areas of interest, deltas, budgets.
    State(state::StateArgs),
    /// Raw Zenoh pub/sub throughput beside the event rate one subscriber receives from impact.
    Zenoh(zenoh_rate::ZenohArgs),
    /// What `--users` costs: ACL size, session open, client connect, input round trip.
    Auth(auth::AuthArgs),
}

fn main() -> Result<()> {
    match Args::parse().suite {
        Suite::Scale(a) => scale::run(&a),
        Suite::Plan(a) => plan::run(&a),
        Suite::Rollback(a) => rollback::run(&a),
        Suite::Zenoh(a) => zenoh_rate::run(&a),
        Suite::Auth(a) => auth::run(&a),
        Suite::Accuracy(a) => accuracy::run(&a),
        Suite::Kernels(a) => kernels::run(&a),
        Suite::Stability(a) => stability::run(&a),
        Suite::Rest(a) => rest::run(&a),
        Suite::Hitscan(a) => hitscan::run(&a),
        Suite::State(a) => state::run(&a),
    }
}
