#!/usr/bin/env python3
"""A client that is not ours: written from PROTOCOL.md alone, with the eclipse-zenoh and
msgpack packages from PyPI.

It joins a world (a liveliness token), waits for its welcome (its avatar and the server's tick),
then plays for a second in ahead mode (PROTOCOL.md, "Timing"): it keeps a clock of the server's
tick (its view tick), stamps each input `view_tick + lead` with `view_tick` alongside, takes the
lead the acks recommend (the first outright, later ones by time dilation), and prints each ack's
arrival margin and the first event batches it sees. Exits 0 when it got the welcome, acks, at
least one event batch, an input sent after the first recommendation arrived on time, and its own
avatar in its state stream (PROTOCOL.md, "State streams").

    pip install eclipse-zenoh msgpack
    python3 examples/python/client.py --connect tcp/127.0.0.1:7447 --world arena

Against a server started with `--users FILE`, pass the user that is your client id:

    python3 examples/python/client.py --client 4242 --user player4242 --password ...
"""
import argparse
import json
import sys
import threading
import time

import msgpack
import zenoh


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447")
    ap.add_argument("--world", default="arena")
    ap.add_argument("--client", type=int, default=4242)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--user", help="Zenoh user name (a server with --users)")
    ap.add_argument("--password", help="its password")
    args = ap.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    if args.user:
        # Zenoh's user/password authentication (PROTOCOL.md, "Access control").
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(args.user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(args.password or ""))
    session = zenoh.open(conf)

    prefix = f"impact/v1/{args.world}"
    me = args.client
    state = {"welcome": None, "ack": None, "batches": 0, "events": 0, "lead": None, "target": 0.0,
             "on_time_after_lead": 0}
    sent_with_lead = set()  # seqs stamped with a recommended lead
    done = threading.Event()

    owner = {"epoch": 0, "stale": 0}

    def decode(sample):
        # After a failover the old primary may publish for a moment: every message carries its
        # owner's epoch as the attachment (8 bytes, little-endian u64, then on a published
        # message 8 more: its number on the key); drop an older one than any heard (PROTOCOL.md,
        # "Failover").
        if sample.attachment is not None:
            a = sample.attachment.to_bytes()
            if len(a) in (8, 16):
                epoch = int.from_bytes(a[:8], "little")
                if epoch < owner["epoch"]:
                    owner["stale"] += 1
                    return None
                owner["epoch"] = epoch
        # Every sample is tagged with its encoding: MessagePack by default, JSON on request.
        raw = sample.payload.to_bytes()
        if str(sample.encoding).startswith("application/json"):
            return json.loads(raw)
        return msgpack.unpackb(raw, raw=False)

    def on_ack(sample):
        msg = decode(sample)
        if msg is None:
            return
        if msg["type"] == "welcome":
            state["welcome"] = msg
            print(f"welcome: avatar {msg['avatar']} at tick {msg['tick']} ({msg['tick_hz']} Hz)")
        elif msg["type"] == "ack":
            state["ack"] = msg
            print(f"ack: input {msg['seq']} for tick {msg['applied_tick']}, server at {msg['server_tick']}: "
                  f"margin {msg['margin_ticks']} ticks, recommended lead {msg['lead_ticks']}")
            state["target"] = float(msg["lead_ticks"])
            if state["lead"] is None:
                state["lead"] = state["target"]  # the first recommendation is taken outright
            if msg["seq"] in sent_with_lead and msg["margin_ticks"] >= 0:
                state["on_time_after_lead"] += 1
        elif msg["type"] == "reject":
            # seq and tick are nil only for a payload the server could not read that far.
            print(f"reject of input {msg['seq']} (tick {msg['tick']}): {msg['reason']}: {msg['detail']}")

    def on_events(sample):
        msg = decode(sample)
        if msg is None:
            return
        state["batches"] += 1
        state["events"] += len(msg["events"])
        if state["batches"] <= 3:
            e = msg["events"][0]
            print(f"events of tick {msg['tick']}: {len(msg['events'])}, first: {e['a']} <-> {e['b']} "
                  f"{e['phase']} {e['response']} at toi {e['toi']:.4f}, normal {e['normal']}")
        if state["ack"] and state["batches"] >= 3:
            done.set()

    # The state stream (PROTOCOL.md, "State streams"): the bodies near our avatar. Keep a map
    # entity -> motion and the tick it came at (a body is where that motion, carried at its
    # velocity, puts it until a frame carries it again); full frames replace it, deltas patch it,
    # and after a gap in the frame numbers we wait for the next full frame.
    stream = {"bodies": {}, "info": {}, "frame": None, "synced": False, "frames": 0, "gaps": 0, "printed": 0}

    def on_state(sample):
        f = decode(sample)
        if f is None:
            return
        stream["frames"] += 1
        if f["full"]:
            stream["bodies"].clear()
            stream["info"].clear()
            stream["synced"] = True
        elif stream["frame"] is None or f["frame"] != (stream["frame"] + 1) % 2**32:
            stream["synced"] = False
            stream["gaps"] += 1
        stream["frame"] = f["frame"]
        if not stream["synced"]:
            return
        for e in f["left"]:
            stream["bodies"].pop(e, None)
            stream["info"].pop(e, None)
        for info in f["entered"]:
            stream["info"][info["entity"]] = info
        for entity, position, velocity, asleep in f["moved"]:
            stream["bodies"][entity] = (f["tick"], position, velocity, asleep)
        if f["full"] and stream["printed"] < 2:
            stream["printed"] += 1
            classes = {}
            for info in stream["info"].values():
                classes[info["class"]] = classes.get(info["class"], 0) + 1
            print(f"state frame {f['frame']} (tick {f['tick']}, full): {len(stream['bodies'])} bodies within "
                  f"the area around {[round(x, 1) for x in f['centre']]}: {classes}, {f['deferred']} deferred by the budget")

    ack_sub = session.declare_subscriber(f"{prefix}/client/{me}/ack", on_ack)
    state_sub = session.declare_subscriber(f"{prefix}/client/{me}/state", on_state)
    ev_sub = session.declare_subscriber(f"{prefix}/events", on_events)
    token = session.liveliness().declare_token(f"{prefix}/presence/{me}")

    deadline = time.time() + args.seconds
    while state["welcome"] is None and time.time() < deadline:
        time.sleep(0.05)
    if state["welcome"] is None or state["welcome"]["avatar"] is None:
        print("no welcome with an avatar", file=sys.stderr)
        return 1
    w = state["welcome"]
    welcomed_at = time.time()

    def view_tick():
        # The server's tick when it welcomed us, plus what our clock counted since.
        return w["tick"] + int((time.time() - welcomed_at) * w["tick_hz"])

    last = time.time()
    # Inputs through a declared publisher: the server resolves the key once (PROTOCOL.md).
    inputs = session.declare_publisher(f"{prefix}/input/{me}")
    # Seqs are nonces: start from the welcome's next_seq (PROTOCOL.md, "Replay protection").
    first_seq = w.get("next_seq", 0)
    for seq in range(first_seq, first_seq + 10):
        now = time.time()
        lead = 0.0
        if state["lead"] is not None:
            # Time dilation: move towards the recommendation by at most 10 % of the ticks elapsed.
            step = 0.1 * (now - last) * w["tick_hz"]
            state["lead"] += max(-step, min(step, state["target"] - state["lead"]))
            lead = state["lead"]
            sent_with_lead.add(seq)
        last = now
        view = view_tick()
        msg = {"type": "input", "client": me, "seq": seq, "tick": view + round(lead), "view_tick": view,
               "actions": [{"type": "set_velocity", "entity": w["avatar"], "velocity": [2.0, 0.0, 1.0]}]}
        inputs.put(msgpack.packb(msg), encoding=zenoh.Encoding("application/msgpack"))
        time.sleep(0.1)

    done.wait(max(0.0, deadline - time.time()))
    time.sleep(0.3)  # the last acks
    # The state stream showed our own avatar (the nearest body there is).
    seen_self = stream["synced"] and w["avatar"] in stream["bodies"]
    ok = state["ack"] is not None and state["batches"] > 0 and state["on_time_after_lead"] > 0 and seen_self
    print(f"{'ok' if ok else 'FAILED'}: ack {'received' if state['ack'] else 'missing'}, "
          f"{state['batches']} event batches ({state['events']} events), "
          f"{state['on_time_after_lead']} of {len(sent_with_lead)} inputs sent with a lead arrived on time, "
          f"{stream['frames']} state frames ({len(stream['bodies'])} bodies held, our avatar "
          f"{'among them' if seen_self else 'missing'}, {stream['gaps']} gaps)")
    token.undeclare()
    ack_sub.undeclare()
    state_sub.undeclare()
    ev_sub.undeclare()
    session.close()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
