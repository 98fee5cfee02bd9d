"""Replay a recording through the paper's cascade and count the events of each noise class.

    python examples/replay_count.py recordings/turntable.npz [--denoise stcf] [--set tau_us=10000]
"""

import argparse

import evstream

ap = argparse.ArgumentParser()
ap.add_argument("recording")
ap.add_argument("--denoise", default="paper")
ap.add_argument("--set", action="append", default=[], metavar="PARAM=VALUE")
args = ap.parse_args()

source = evstream.open(args.recording)  # any supported file or MCAP log, read chunk by chunk
stage = evstream.stage(**evstream.set_params({"kind": args.denoise}, args.set))
counts = {c.name.lower(): 0 for c in evstream.NoiseClass}
for chunk in source:
    classes = evstream.classify(stage, chunk)  # the stage keeps its state from chunk to chunk
    for c in evstream.NoiseClass:
        counts[c.name.lower()] += int((classes == c).sum())

total = sum(counts.values())
print(f"{args.recording} ({source.geometry}): {total:,} events")
for name, n in counts.items():
    print(f"  {name:<11} {n:>10,}  {100 * n / max(total, 1):5.1f} %")
