#!/usr/bin/env python3
"""Watches a running impact deployment through a soak: the resident memory of its processes
(from /proc), the world's once-a-second `stats` (tick p99, ingress queue depth, events/s) and,
with --confirmed, every confirmed batch (a tick missing, or published twice and different, is a
confirmed event lost), for a fixed time.

Processes: --pid PID (the server, named `server`) and --watch NAME=PID or NAME=@FILE (the pid
read from FILE every second: a role whose process changes, as the primary's does at a failover;
each process a role had is its own series). Writes one CSV row per stats message, an SVG plot
(memory of every series, tick p99, queue depth), and prints a table per --table-minutes, a
summary and one JSON line. A series' memory growth compares the median of a window after its own
warm-up with its last window (windows of 5 minutes, shorter on a short run). Exits 1 when a
series grew by --max-growth-pct or more, the queue grew, or a confirmed tick was lost.

    python3 scripts/soak_watch.py --pid PID --connect tcp/127.0.0.1:7447 --world arena \\
        --minutes 30 --warmup-minutes 5 --csv docs/plots/soak.csv --svg docs/plots/soak.svg
"""
import argparse
import hashlib
import json
import statistics
import sys
import threading
import time

import msgpack
import zenoh

COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf"]


def rss_mb(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS")


class Role:
    """A watched role: a fixed pid, or one read from a file each time."""

    def __init__(self, spec):
        name, _, where = spec.partition("=")
        if not name or not where:
            raise SystemExit(f"--watch {spec!r}: expected NAME=PID or NAME=@FILE")
        self.name, self.where = name, where

    def pid(self):
        if not self.where.startswith("@"):
            return int(self.where)
        try:
            with open(self.where[1:]) as f:
                return int(f.read().strip())
        except (OSError, ValueError):
            return None


class Confirmed:
    """Every confirmed batch heard, in the order heard: a tick past the one after the highest
    leaves the ticks between missing, until asked for again (`query/confirmed`: the server keeps
    the last half minute of batches, and a standby those its primary confirmed); a tick heard
    again is compared (by a digest of its events) with the first, kept for the last KEPT ticks.
    A tick still missing after its query is a confirmed event lost."""

    KEPT = 4096
    GAPS = 100

    def __init__(self):
        self.digests, self.highest, self.ticks = {}, None, 0
        self.repeated, self.changed, self.recovered = 0, 0, 0
        self.lost = set()  # ticks missing, until recovered
        self.to_ask = []  # (first, last) ranges to ask for
        self.gaps = []  # (seconds into the run, first missing tick, ticks missing), the first GAPS

    @property
    def missing(self):
        return len(self.lost)

    def heard(self, tick, events, t_s=0.0, recovered=False):
        d = hashlib.sha1(msgpack.packb(events)).hexdigest()
        if recovered and tick in self.lost:
            self.lost.discard(tick)
            self.recovered += 1
            self.ticks += 1
            self.digests[tick] = d
            return
        if self.highest is not None and tick <= self.highest:
            old = self.digests.get(tick)
            if old is not None:
                self.repeated += not recovered
                self.changed += old != d
            return
        if recovered:
            return  # asked for, and heard on the stream since
        if self.highest is not None and tick > self.highest + 1:
            first, n = self.highest + 1, tick - self.highest - 1
            self.lost.update(range(first, tick))
            self.to_ask.append((first, tick - 1))
            if len(self.gaps) < self.GAPS:
                self.gaps.append((t_s, first, n))
            print(f"  {t_s / 60:5.1f} min: confirmed ticks {first}..{tick - 1} missing: asking for them",
                  file=sys.stderr, flush=True)
        self.highest, self.ticks = tick, self.ticks + 1
        self.digests[tick] = d
        while len(self.digests) > self.KEPT:
            self.digests.pop(next(iter(self.digests)))


def ask_confirmed(session, world, first, last, confirmed, lock, t_s):
    """Asks the world's server for the confirmed batches of ticks first..last it kept."""
    selector = f"impact/v1/{world}/query/confirmed?from={first};to={last}"
    # One reply per tick, all on the query's key: Zenoh would keep only the latest.
    for reply in session.get(selector, consolidation=zenoh.ConsolidationMode.NONE, timeout=2.0):
        if reply.ok is None:
            continue
        b = msgpack.unpackb(reply.ok.payload.to_bytes(), raw=False)
        if b.get("type") == "confirmed":
            with lock:
                confirmed.heard(b["tick"], b.get("events", []), t_s, recovered=True)
    with lock:
        still = sum(1 for t in range(first, last + 1) if t in confirmed.lost)
    print(f"  confirmed ticks {first}..{last}: {last - first + 1 - still} recovered, {still} lost",
          file=sys.stderr, flush=True)


def svg(rows, series, path, warmup_s):
    """Three stacked plots over time: memory of every series, tick p99, ingress queue depth."""
    w, ph, left, top = 760, 170, 70, 30
    t_end = max(r["t_s"] for r in rows) or 1.0
    x = lambda t: left + (w - left - 20) * t / t_end
    panels = [("resident memory, MiB", None), ("tick p99, ms", "tick_ms_p99"),
              ("ingress queue depth (max per second)", "queue_depth_max")]
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{top + len(panels) * (ph + 40) + 20}" '
           'font-family="sans-serif" font-size="11">',
           f'<text x="{left}" y="18" font-size="13">soak: {t_end / 60:.0f} min, warm-up {warmup_s / 60:.0f} min (shaded)</text>']
    for i, (title, key) in enumerate(panels):
        y0 = top + i * (ph + 40)
        lines = ([(f"{n} ({pid})", pts) for (n, pid), pts in series.items()] if key is None
                 else [(key, [(r["t_s"], r[key]) for r in rows])])
        hi = max((v for _, pts in lines for _, v in pts), default=1.0) * 1.1 or 1.0
        y = lambda v: y0 + ph - ph * v / hi
        out.append(f'<rect x="{left}" y="{y0}" width="{x(warmup_s) - left:.1f}" height="{ph}" fill="#eee"/>')
        out.append(f'<rect x="{left}" y="{y0}" width="{w - left - 20}" height="{ph}" fill="none" stroke="#999"/>')
        out.append(f'<text x="{left}" y="{y0 - 4}">{title}</text>')
        for frac in (0.0, 0.5, 1.0):
            out.append(f'<text x="{left - 6}" y="{y(hi * frac) + 4:.1f}" text-anchor="end">{hi * frac:.1f}</text>')
        for k, (label, pts) in enumerate(lines):
            colour = COLOURS[k % len(COLOURS)]
            poly = " ".join(f"{x(t):.1f},{y(v):.1f}" for t, v in pts)
            out.append(f'<polyline points="{poly}" fill="none" stroke="{colour}" stroke-width="1"/>')
            if key is None:
                out.append(f'<text x="{left + 8 + 150 * (k % 4)}" y="{y0 + 14 + 12 * (k // 4)}" fill="{colour}">{label}</text>')
        step = max(1, int(t_end // 60 // 12))
        for m in range(0, int(t_end // 60) + 1, step):
            out.append(f'<text x="{x(m * 60):.1f}" y="{y0 + ph + 14}" text-anchor="middle">{m} min</text>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out))


def growth(pts, warmup_s):
    """A series' memory after its own warm-up against its end: (after, end, %), or None when the
    series is too short to tell."""
    if not pts:
        return None
    start, end = pts[0][0], pts[-1][0]
    steady = end - (start + warmup_s)
    if steady < 30:
        return None
    window = min(300.0, steady / 3)
    first = [v for t, v in pts if start + warmup_s <= t < start + warmup_s + window]
    last = [v for t, v in pts if t >= end - window]
    a, b = statistics.median(first), statistics.median(last)
    return a, b, (b - a) / a * 100.0 if a > 0 else 0.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pid", type=int, help="the impact-server process (watched as `server`)")
    ap.add_argument("--watch", action="append", default=[], help="NAME=PID or NAME=@PIDFILE, repeatable")
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447")
    ap.add_argument("--mode", default="peer", choices=["peer", "client"])
    ap.add_argument("--world", default="arena")
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--warmup-minutes", type=float, default=5.0)
    ap.add_argument("--table-minutes", type=float, default=10.0)
    ap.add_argument("--max-growth-pct", type=float, default=5.0)
    ap.add_argument("--bound", action="append", default=[],
                    help="a role whose memory growth is bounded, repeatable (default: every one)")
    ap.add_argument("--confirmed", action="store_true", help="check every confirmed tick arrives, once")
    ap.add_argument("--csv", required=True)
    ap.add_argument("--svg", required=True)
    ap.add_argument("--json", help="also write the result's JSON line here")
    args = ap.parse_args()
    roles = ([Role(f"server={args.pid}")] if args.pid else []) + [Role(s) for s in args.watch]
    if not roles:
        raise SystemExit("nothing to watch: give --pid or --watch")

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(args.mode))
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    rows, series, lock, t0 = [], {}, threading.Lock(), time.time()
    confirmed = Confirmed()

    def on_stats(sample):
        s = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
        with lock:
            rows.append({"t_s": round(time.time() - t0, 1), "tick": s["tick"],
                         "tick_ms_p50": s["tick_ms_p50"], "tick_ms_p99": s["tick_ms_p99"],
                         "queue_depth_max": s["queue_depth_max"], "events_per_s": s["events_per_s"],
                         "overruns": s["overruns"]})

    def on_confirmed(sample):
        b = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
        with lock:
            confirmed.heard(b["tick"], b.get("events", []), round(time.time() - t0, 1))

    subs = [session.declare_subscriber(f"impact/v1/{args.world}/stats", on_stats)]
    if args.confirmed:
        subs.append(session.declare_subscriber(f"impact/v1/{args.world}/confirmed", on_confirmed))
    end = t0 + args.minutes * 60
    next_line = t0 + 60
    while time.time() < end:
        time.sleep(1)
        now = round(time.time() - t0, 1)
        with lock:
            asks, confirmed.to_ask = confirmed.to_ask, []
        for first, last in asks:
            ask_confirmed(session, args.world, first, last, confirmed, lock, now)
        for role in roles:
            pid = role.pid()
            try:
                mb = rss_mb(pid) if pid else None
            except (OSError, RuntimeError):
                mb = None
            if mb is not None:
                with lock:
                    series.setdefault((role.name, pid), []).append((now, round(mb, 2)))
        if time.time() >= next_line:
            next_line += 60
            with lock:
                last = rows[-1] if rows else None
                mem = ", ".join(f"{n} {pts[-1][1]:.0f}" for (n, _), pts in series.items() if pts[-1][0] >= now - 2)
            if last:
                print(f"  {now / 60:5.1f} min: tick p99 {last['tick_ms_p99']:.2f} ms, queue {last['queue_depth_max']}, "
                      f"MiB: {mem}", file=sys.stderr, flush=True)
    for s in subs:
        s.undeclare()
    session.close()
    with lock:
        rows = list(rows)
    if len(rows) < 10:
        print(f"only {len(rows)} stats messages: is {args.world} published at {args.connect}?", file=sys.stderr)
        return 1
    with open(args.csv, "w") as f:
        keys = list(rows[0].keys())
        f.write(",".join(keys) + "\n")
        for r in rows:
            f.write(",".join(str(r[k]) for k in keys) + "\n")
    warm = args.warmup_minutes * 60
    after = [r for r in rows if r["t_s"] >= warm]
    first_q = [r["queue_depth_max"] for r in after if r["t_s"] < warm + 300]
    last_q = [r["queue_depth_max"] for r in rows if r["t_s"] >= rows[-1]["t_s"] - 300]
    q_a, q_b = statistics.median(first_q or [0]), statistics.median(last_q)

    # The table: per period, the tick p99 (median and worst of its seconds) and each series'
    # memory at its end.
    period = args.table_minutes * 60
    names = [f"{n} ({pid})" for n, pid in series]
    print(f"  {'minutes':>9} {'tick p99 median':>16} {'worst':>8}  " + "  ".join(f"{n:>16}" for n in names))
    periods = []
    for k in range(int(rows[-1]["t_s"] // period) + 1):
        rs = [r["tick_ms_p99"] for r in rows if k * period <= r["t_s"] < (k + 1) * period]
        if not rs:
            continue
        mems = []
        for pts in series.values():
            inside = [v for t, v in pts if k * period <= t < (k + 1) * period]
            mems.append(inside[-1] if inside else None)
        periods.append({"from_min": round(k * period / 60, 1), "tick_ms_p99_median": statistics.median(rs),
                        "tick_ms_p99_max": max(rs), "rss_mb": dict(zip(names, mems))})
        cells = "  ".join(f"{m:>16.1f}" if m is not None else f"{'-':>16}" for m in mems)
        print(f"  {k * period / 60:4.0f}-{(k + 1) * period / 60:<4.0f} {statistics.median(rs):16.2f} {max(rs):8.2f}  {cells}")

    grew = {}
    for (n, pid), pts in series.items():
        g = growth(pts, warm)
        if g:
            grew[f"{n} ({pid})"] = {"after_warmup_mb": g[0], "end_mb": g[1], "growth_pct": round(g[2], 2),
                                    "bounded": not args.bound or n in args.bound}
    for name, g in grew.items():
        print(f"  {name:28} memory after warm-up {g['after_warmup_mb']:8.1f} MiB, end {g['end_mb']:8.1f} MiB, "
              f"growth {g['growth_pct']:+.2f} %{'' if g['bounded'] else ' (not bounded on this run)'}")
    p99 = [r["tick_ms_p99"] for r in after] or [0.0]
    result = {
        "suite": "soak", "minutes": round(rows[-1]["t_s"] / 60, 1), "warmup_minutes": args.warmup_minutes,
        "memory": grew,
        "max_growth_pct": max((g["growth_pct"] for g in grew.values() if g["bounded"]), default=0.0),
        "queue_depth_after_warmup": q_a, "queue_depth_end": q_b,
        "tick_ms_p99_median": statistics.median(p99), "tick_ms_p99_max": max(p99),
        "overruns": rows[-1]["overruns"], "periods": periods,
    }
    if args.confirmed:
        result.update({"confirmed_ticks": confirmed.ticks, "confirmed_missing": confirmed.missing,
                       "confirmed_recovered": confirmed.recovered,
                       "confirmed_repeated": confirmed.repeated, "confirmed_changed": confirmed.changed,
                       "confirmed_gaps": [{"t_s": t, "from_tick": a, "ticks": n} for t, a, n in confirmed.gaps]})
        print(f"  confirmed ticks heard {confirmed.ticks} ({confirmed.recovered} asked for again): missing {confirmed.missing}, "
              f"published twice {confirmed.repeated} (changed {confirmed.changed})")
    print(f"  tick p99 after warm-up: median {result['tick_ms_p99_median']:.2f} ms, worst second "
          f"{result['tick_ms_p99_max']:.2f} ms; ingress queue {q_a:.0f} -> {q_b:.0f}; overruns {result['overruns']}")
    svg(rows, series, args.svg, warm)
    line = json.dumps(result)
    print(line)
    if args.json:
        with open(args.json, "w") as f:
            f.write(line + "\n")
    # Queue depths are small integers: one input of rounding is allowed on top of the 5 %.
    ok = result["max_growth_pct"] < args.max_growth_pct and q_b <= q_a * 1.05 + 1
    if args.confirmed:
        ok = ok and confirmed.missing == 0 and confirmed.changed == 0 and confirmed.ticks > 0
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
