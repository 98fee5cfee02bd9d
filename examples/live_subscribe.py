"""Subscribe to a live stream from Python: the paper's cascade on every packet of every camera, counts
printed when each camera's publisher ends.

    evstream router --listen tcp/127.0.0.1:7447 &
    python examples/live_subscribe.py --connect tcp/127.0.0.1:7447 &
    evstream publish recordings/ball.npz --key evstream/cam0/events --connect tcp/127.0.0.1:7447 --wait-subscribers 10
"""

import argparse

import evstream

ap = argparse.ArgumentParser()
ap.add_argument("--connect", default="tcp/127.0.0.1:7447")
ap.add_argument("--key", default="evstream/*/events")
ap.add_argument("--cameras", type=int, default=1, help="stop once this many publishers have ended")
ap.add_argument("--idle-s", type=float, default=60.0, help="stop after this long without a packet")
args = ap.parse_args()

pipelines = {}  # one pipeline (its own state) per camera
with evstream.subscribe(args.key, connect=args.connect, idle_s=args.idle_s) as stream:
    print(f"subscribed to {args.key} via {args.connect}", flush=True)
    ended = 0
    for item in stream:
        if not hasattr(item, "chunk"):  # an End mark: that camera's publisher has finished
            pipe = pipelines.get(item.camera)
            if pipe is not None:
                c = pipe.stats.per_class
                print(f"{item.camera}: {pipe.stats.events_in:,} events: signal {c[0]:,}, "
                      f"background {c[1]:,}, hot pixel {c[2]:,}", flush=True)
            ended += 1
            if ended >= args.cameras:
                break
            continue
        if item.camera not in pipelines or item.restart:
            pipelines[item.camera] = evstream.build_pipeline("paper")
        pipelines[item.camera].process(item.chunk)
