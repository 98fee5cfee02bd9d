"""Clean every recording in a folder into an MCAP archive (removed events kept on their own topics).

    python examples/clean_folder.py recordings out/clean [--denoise paper]
"""

import argparse
from pathlib import Path

import evstream

ap = argparse.ArgumentParser()
ap.add_argument("folder")
ap.add_argument("out")
ap.add_argument("--denoise", default="paper")
args = ap.parse_args()

for path in sorted(Path(args.folder).iterdir()):
    if not path.is_file() or path.suffix in (".md", ".txt", ".json"):
        continue
    pipe = evstream.build_pipeline(args.denoise)
    out = Path(args.out) / f"{path.stem}.mcap"
    try:
        source = evstream.open(path)
        meta = {"source": str(path), "pipeline": pipe.describe()}
        with evstream.open_sink(out, geometry=source.geometry, keep_noise=True, metadata=meta) as sink:
            for batch in evstream.batches(pipe, source):
                sink.write(batch)
    except evstream.EventError as e:  # not a recording evstream reads (no archive is left): say so, go on
        print(f"skipped {path}: {e}")
        continue
    signal = pipe.stats.per_class[evstream.NoiseClass.SIGNAL]
    print(f"wrote {out}: {pipe.stats.events_in:,} events, {signal:,} signal")
