"""Denoise inside a training data pipeline: `evstream.Denoise` is a tonic-style transform, a callable on
a numpy structured array (t, x, y, p) that returns the events it keeps, same dtype.

It drops into `tonic.transforms.Compose([evstream.Denoise(sensor_size=...), tonic.transforms.ToFrame(...)])`
or a torch `Dataset.__getitem__` as it is; this example needs neither library: its Compose and Dataset
are the few lines those libraries' protocols ask for.

    python examples/dataset_transform.py recordings/ball.npz
"""

import argparse

import numpy as np

import evstream

# tonic's event dtype (x, y, t in µs, p): what tonic datasets hand to their transforms
TONIC_DTYPE = np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "<i1")])


class Compose:  # tonic.transforms.Compose / torchvision.transforms.Compose: apply in order
    def __init__(self, transforms):
        self.transforms = transforms

    def __call__(self, events):
        for transform in self.transforms:
            events = transform(events)
        return events


class EventSamples:  # a torch-style map Dataset: __len__ and __getitem__ (torch.utils.data.Dataset)
    def __init__(self, path, sample_us, transform=None):
        events = evstream.read(path)
        self.sensor_size = (events.geometry.width, events.geometry.height, 2)  # tonic's convention
        arr = np.zeros(len(events), TONIC_DTYPE)
        for name in "xytp":
            arr[name] = getattr(events, name)
        edges = np.searchsorted(arr["t"], np.arange(arr["t"][0], arr["t"][-1] + sample_us, sample_us))
        self.samples = [arr[a:b] for a, b in zip(edges[:-1], edges[1:])]
        self.transform = transform

    def __len__(self):
        return len(self.samples)

    def __getitem__(self, i):
        events = self.samples[i]
        return self.transform(events) if self.transform else events


def event_count_frame(events, sensor_size=(346, 260, 2)):  # stands in for tonic.transforms.ToFrame
    frame = np.zeros(sensor_size[1::-1], np.int32)
    np.add.at(frame, (events["y"], events["x"]), 1)
    return frame


ap = argparse.ArgumentParser()
ap.add_argument("recording")
ap.add_argument("--sample-ms", type=float, default=250.0)
args = ap.parse_args()

raw = EventSamples(args.recording, int(args.sample_ms * 1000))
denoise = evstream.Denoise(sensor_size=raw.sensor_size, kind="paper")
dataset = EventSamples(args.recording, int(args.sample_ms * 1000), transform=Compose([denoise]))
for i in range(len(dataset)):
    kept = dataset[i]
    frame = event_count_frame(kept, raw.sensor_size)
    print(f"sample {i}: {len(raw[i]):,} events -> {len(kept):,} kept ({kept.dtype.names}), "
          f"frame {frame.shape[1]}x{frame.shape[0]} holding {int(frame.sum()):,}")
