//! `impact-bench stability`: the numerical stress cases at full size, one row and one JSON line
//! each. The CI tests (`server/tests/stability.rs`) run the same cases with the same bounds.

use super::report::{json_line, progress};
use anyhow::{bail, Result};
use clap::Args;
use impact_server::stability::{self, CaseResult};
use serde_json::json;
use std::time::Instant;

/// Options.
#[derive(Args, Debug)]
pub struct StabilityArgs {
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
    /// Run only these cases (by name, comma-separated).
    #[arg(long, value_delimiter = ',')]
    case: Vec<String>,
    /// Ticks for the pile case.
    #[arg(long, default_value_t = 10_000)]
    pile_ticks: u32,
}

/// A case to run.
type Case<'a> = Box<dyn Fn() -> CaseResult + 'a>;

/// Runs every case; fails if any bound is missed.
pub fn run(a: &StabilityArgs) -> Result<()> {
    println!("stability: numerical stress cases (NaN/infinity checked every tick in every case)");
    println!("{:<18} {:<6} {:>8}  figures", "case", "pass", "seconds");
    let cases: Vec<(&str, Case<'_>)> = vec![
        ("far from origin", Box::new(|| stability::far_from_origin(300))),
        ("scale", Box::new(|| stability::scale(200))),
        ("degenerate", Box::new(stability::degenerate)),
        ("speed", Box::new(|| stability::speed(200))),
        ("pile", Box::new(|| stability::pile(1000, a.pile_ticks))),
        ("elastic", Box::new(|| stability::elastic(300, 100_000))),
        ("rollback stress", Box::new(|| stability::rollback_stress(10_000))),
    ];
    let mut failed = Vec::new();
    for (name, case) in cases {
        if !a.case.is_empty() && !a.case.iter().any(|c| c.as_str() == name || c.replace('_', " ") == name) {
            continue;
        }
        progress(name);
        let t = Instant::now();
        let r = case();
        let secs = t.elapsed().as_secs_f64();
        let figures: Vec<String> = r.figures.iter().map(|(k, v)| format!("{k}={v:.3e}")).collect();
        println!("{:<18} {:<6} {secs:>8.1}  {}", r.case, if r.pass { "yes" } else { "NO" }, figures.join(" "));
        if !r.pass {
            println!("{:<18} {:<6} {:>8}  {}", "", "", "", r.detail);
            failed.push(r.case);
        }
        if a.json {
            let mut v =
                json!({"suite": "stability", "case": r.case, "pass": r.pass, "seconds": secs, "detail": r.detail});
            for (k, x) in &r.figures {
                v[k] = json!(x);
            }
            json_line(&v);
        }
    }
    if !failed.is_empty() {
        bail!("stability cases failed: {}", failed.join(", "));
    }
    Ok(())
}
