#!/usr/bin/env python3
"""Watches a running impact server through a soak: its resident memory (from /proc) and its
once-a-second `stats` (tick p99, ingress queue depth, events/s), for a fixed time.

Writes one CSV row per stats message, a three-panel SVG plot, and prints a summary table and one
JSON line: resident memory and queue depth after warm-up against the end (growth must stay under
5 %; the five minutes after warm-up against the last five), tick p99 per minute. Exits 1 when memory or the queue grew by 5 % or more.

    python3 scripts/soak_watch.py --pid PID --connect tcp/127.0.0.1:7447 --world arena \
        --minutes 30 --warmup-minutes 5 --csv docs/plots/soak.csv --svg docs/plots/soak.svg
"""
import argparse
import json
import statistics
import sys
import threading
import time

import msgpack
import zenoh


def rss_mb(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS")


def svg(rows, path, warmup_s):
    """Three stacked line plots over time: RSS (MiB), tick p99 (ms), ingress queue depth."""
    panels = [("resident memory, MiB", "rss_mb"), ("tick p99, ms", "tick_ms_p99"),
              ("ingress queue depth (max per second)", "queue_depth_max")]
    w, ph, left, top = 760, 170, 70, 30
    t_end = max(r["t_s"] for r in rows) or 1.0
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{top + len(panels) * (ph + 40)}" '
           'font-family="sans-serif" font-size="11">',
           f'<text x="{left}" y="18" font-size="13">soak: {len(rows)} s, warm-up {warmup_s:.0f} s (shaded)</text>']
    for i, (title, key) in enumerate(panels):
        y0 = top + i * (ph + 40)
        vals = [r[key] for r in rows]
        hi = max(vals) * 1.1 or 1.0
        x = lambda t: left + (w - left - 20) * t / t_end
        y = lambda v: y0 + ph - ph * v / hi
        out.append(f'<rect x="{left}" y="{y0}" width="{x(warmup_s) - left:.1f}" height="{ph}" fill="#eee"/>')
        out.append(f'<rect x="{left}" y="{y0}" width="{w - left - 20}" height="{ph}" fill="none" stroke="#999"/>')
        out.append(f'<text x="{left}" y="{y0 - 4}">{title}</text>')
        for frac in (0.0, 0.5, 1.0):
            v = hi * frac
            out.append(f'<text x="{left - 6}" y="{y(v) + 4:.1f}" text-anchor="end">{v:.1f}</text>')
        pts = " ".join(f"{x(r['t_s']):.1f},{y(r[key]):.1f}" for r in rows)
        out.append(f'<polyline points="{pts}" fill="none" stroke="#1f77b4" stroke-width="1"/>')
        for m in range(0, int(t_end // 60) + 1, 5):
            out.append(f'<text x="{x(m * 60):.1f}" y="{y0 + ph + 14}" text-anchor="middle">{m} min</text>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pid", type=int, required=True, help="the impact-server process")
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447")
    ap.add_argument("--world", default="arena")
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--warmup-minutes", type=float, default=5.0)
    ap.add_argument("--csv", required=True)
    ap.add_argument("--svg", required=True)
    args = ap.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    rows, lock, t0 = [], threading.Lock(), time.time()

    def on_stats(sample):
        s = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
        try:
            rss = rss_mb(args.pid)
        except (OSError, RuntimeError):
            return
        with lock:
            rows.append({"t_s": round(time.time() - t0, 1), "tick": s["tick"], "rss_mb": round(rss, 2),
                         "tick_ms_p50": s["tick_ms_p50"], "tick_ms_p99": s["tick_ms_p99"],
                         "queue_depth_max": s["queue_depth_max"], "events_per_s": s["events_per_s"],
                         "overruns": s["overruns"]})

    sub = session.declare_subscriber(f"impact/v1/{args.world}/stats", on_stats)
    end = t0 + args.minutes * 60
    next_line = t0 + 60
    while time.time() < end:
        time.sleep(1)
        if time.time() >= next_line:
            next_line += 60
            with lock:
                last = rows[-1] if rows else None
            if last:
                print(f"  {last['t_s'] / 60:5.1f} min: rss {last['rss_mb']:.1f} MiB, tick p99 {last['tick_ms_p99']:.2f} ms, "
                      f"queue {last['queue_depth_max']}", file=sys.stderr, flush=True)
    sub.undeclare()
    session.close()
    with lock:
        rows = list(rows)
    if len(rows) < 10:
        print(f"only {len(rows)} stats messages: is the server at {args.connect} publishing {args.world}?",
              file=sys.stderr)
        return 1
    with open(args.csv, "w") as f:
        keys = list(rows[0].keys())
        f.write(",".join(keys) + "\n")
        for r in rows:
            f.write(",".join(str(r[k]) for k in keys) + "\n")
    warm = args.warmup_minutes * 60
    after = [r for r in rows if r["t_s"] >= warm]
    # The five minutes after warm-up against the last five (medians of their seconds).
    first_min = [r for r in after if r["t_s"] < warm + 300]
    last_min = [r for r in rows if r["t_s"] >= rows[-1]["t_s"] - 300]
    med = lambda rs, k: statistics.median(r[k] for r in rs)
    rss_a, rss_b = med(first_min, "rss_mb"), med(last_min, "rss_mb")
    q_a, q_b = med(first_min, "queue_depth_max"), med(last_min, "queue_depth_max")
    growth = lambda a, b: (b - a) / a * 100.0 if a > 0 else (0.0 if b == 0 else float("inf"))
    per_minute = {}
    for r in after:
        per_minute.setdefault(int(r["t_s"] // 60), []).append(r["tick_ms_p99"])
    p99_minutes = [statistics.median(v) for _, v in sorted(per_minute.items())]
    result = {
        "suite": "soak", "minutes": round(rows[-1]["t_s"] / 60, 1), "warmup_minutes": args.warmup_minutes,
        "rss_mb_after_warmup": rss_a, "rss_mb_end": rss_b, "rss_growth_pct": round(growth(rss_a, rss_b), 2),
        "queue_depth_after_warmup": q_a, "queue_depth_end": q_b,
        "tick_ms_p99_minute_median_min": min(p99_minutes), "tick_ms_p99_minute_median_max": max(p99_minutes),
        "tick_ms_p99_median": statistics.median(p99_minutes), "overruns": rows[-1]["overruns"],
    }
    svg(rows, args.svg, warm)
    print(f"{'':2}{'':28}{'after warm-up':>14}{'end':>10}")
    print(f"  {'resident memory, MiB':28}{rss_a:14.1f}{rss_b:10.1f}   growth {result['rss_growth_pct']:+.2f} %")
    print(f"  {'ingress queue depth':28}{q_a:14.0f}{q_b:10.0f}")
    print(f"  tick p99 per minute (median of its seconds): {min(p99_minutes):.2f} .. {max(p99_minutes):.2f} ms, "
          f"median {result['tick_ms_p99_median']:.2f} ms; overruns {result['overruns']}")
    print(json.dumps(result))
    # Queue depths are small integers: one input of rounding is allowed on top of the 5 %.
    ok = result["rss_growth_pct"] < 5.0 and q_b <= q_a * 1.05 + 1
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
