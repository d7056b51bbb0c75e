//! Plots for the benchmark programs (`impact-bench`, `impact-deploy-bench`): standalone SVG
//! documents, no dependencies, that BENCHMARKS.md shows.

/// One line of a plot: a name and its points.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// `(x, y)` points, drawn in order.
    pub points: Vec<(f64, f64)>,
}

/// A log-log line plot as a standalone SVG document (no dependencies; opens in any browser).
pub fn svg_loglog(title: &str, xlabel: &str, ylabel: &str, series: &[Series]) -> String {
    const W: f64 = 640.0;
    const H: f64 = 420.0;
    const L: f64 = 70.0;
    const R: f64 = 170.0;
    const T: f64 = 40.0;
    const B: f64 = 50.0;
    let all: Vec<(f64, f64)> =
        series.iter().flat_map(|s| s.points.iter().copied()).filter(|p| p.0 > 0.0 && p.1 > 0.0).collect();
    let (lx0, lx1) = decade_range(all.iter().map(|p| p.0));
    let (ly0, ly1) = decade_range(all.iter().map(|p| p.1));
    let sx = |x: f64| L + (x.log10() - lx0) / (lx1 - lx0) * (W - L - R);
    let sy = |y: f64| H - B - (y.log10() - ly0) / (ly1 - ly0) * (H - T - B);
    let mut s = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">"#
    );
    s += &format!(
        r#"<rect width="{W}" height="{H}" fill="white"/><text x="{}" y="22" font-size="15" text-anchor="middle">{title}</text>"#,
        W / 2.0
    );
    for d in (lx0 as i32)..=(lx1 as i32) {
        let x = sx(10f64.powi(d));
        s += &format!(
            r##"<line x1="{x}" y1="{T}" x2="{x}" y2="{}" stroke="#ddd"/><text x="{x}" y="{}" text-anchor="middle">1e{d}</text>"##,
            H - B,
            H - B + 16.0
        );
    }
    for d in (ly0 as i32)..=(ly1 as i32) {
        let y = sy(10f64.powi(d));
        s += &format!(
            r##"<line x1="{L}" y1="{y}" x2="{}" y2="{y}" stroke="#ddd"/><text x="{}" y="{}" text-anchor="end">1e{d}</text>"##,
            W - R,
            L - 6.0,
            y + 4.0
        );
    }
    s += &format!(r#"<text x="{}" y="{}" text-anchor="middle">{xlabel}</text>"#, L + (W - L - R) / 2.0, H - 12.0);
    s += &format!(
        r#"<text x="16" y="{}" transform="rotate(-90 16 {})" text-anchor="middle">{ylabel}</text>"#,
        T + (H - T - B) / 2.0,
        T + (H - T - B) / 2.0
    );
    let colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#7f7f7f"];
    for (k, ser) in series.iter().enumerate() {
        let c = colours[k % colours.len()];
        let pts: Vec<String> = ser
            .points
            .iter()
            .filter(|p| p.0 > 0.0 && p.1 > 0.0)
            .map(|p| format!("{:.1},{:.1}", sx(p.0), sy(p.1)))
            .collect();
        s += &format!(r#"<polyline points="{}" fill="none" stroke="{c}" stroke-width="2"/>"#, pts.join(" "));
        for p in &pts {
            let (x, y) = p.split_once(',').unwrap_or(("0", "0"));
            s += &format!(r#"<circle cx="{x}" cy="{y}" r="3" fill="{c}"/>"#);
        }
        let ly = T + 10.0 + 18.0 * k as f64;
        s += &format!(
            r#"<line x1="{}" y1="{ly}" x2="{}" y2="{ly}" stroke="{c}" stroke-width="2"/><text x="{}" y="{}">{}</text>"#,
            W - R + 10.0,
            W - R + 30.0,
            W - R + 35.0,
            ly + 4.0,
            ser.name
        );
    }
    s + "</svg>\n"
}

/// Whole decades covering the values' logs.
fn decade_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) =
        values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v.log10()), hi.max(v.log10())));
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let (lo, hi) = (lo.floor(), hi.ceil());
    if hi > lo {
        (lo, hi)
    } else {
        (lo, lo + 1.0)
    }
}
