"""Every real recording in ../shared/data/real decodes to what SOURCES.md records (events, span, ON
fraction, sensor), twins agree event for event, and `evstream info` / `replay` / `convert` work on each."""

import json

import numpy as np
import pytest
from evstream.sources import open_source

from evstream.cli import main
from evstream.events import concat

# file: (format, WxH, events, span µs, ON fraction, first event, last event) — counts, spans and ON
# fractions from SOURCES.md's table; first/last events are the same across each file's twin
# (npy, h5, txt), which other tools wrote (checked in test_twins_agree).
REAL = {
    "davis346_frames_imu_evlib.aedat4": ("aedat4", "346x260", 6_676, 169_941, 0.534,
                                         (1589163147368868, 215, 164, 1), (1589163147538809, 96, 229, 1)),
    "dvxplorer_320x240_tonic.aedat4": ("aedat4", "320x240", 111_954, 589_917, 0.491,
                                       (1605537493718345, 154, 204, 0), (1605537494308262, 88, 237, 1)),
    "dvxplorer_320x240_tonic.npy": ("npy", "320x240", 111_954, 589_917, 0.491,
                                    (1605537493718345, 154, 204, 0), (1605537494308262, 88, 237, 1)),
    "prophesee_gen3_vga_evt2_faery.raw": ("evt2", "640x480", 521_252, 95_871, 0.357,
                                          (913716224, 35, 443, 1), (913812095, 12, 471, 0)),
    "prophesee_gen3_vga_evt2_faery.h5": ("hdf5", "640x480", 521_252, 95_871, 0.357,
                                         (913716224, 35, 443, 1), (913812095, 12, 471, 0)),
    "prophesee_gen41_hd_evt3_expelliarmus.raw": ("evt3", "1280x720", 219_596, 8_801, 0.526,
                                                 (11718656, 874, 200, 0), (11727457, 1218, 572, 1)),
    "ncars_atis_sample.dat": ("dat", "304x240", 2_009, 99_952, 0.672, (0, 25, 8, 0), (99952, 75, 28, 1)),
    "nmnist_sample.bin": ("nmnist", "34x34", 4_325, 310_521, 0.496, (654, 7, 15, 1), (311175, 21, 14, 1)),
    "ncaltech101_faces_easy_0001.bin": ("nmnist", "304x240", 67_445, 299_358, 0.501,
                                        (6, 131, 2, 1), (299364, 40, 15, 1)),
    "dvsgesture_slayer_1.bs2": ("nmnist", "128x128", 63_471, 1_449_968, 0.507,
                                (28, 49, 82, 0), (1449996, 58, 79, 0)),
    "dvs128_lifetime_building.mat": ("mat", "128x128", 115_839, 1_100_005, 0.501,
                                     (0, 14, 46, 0), (1100005, 40, 8, 0)),
    "dvs128_lifetime_building_events.txt": ("text", "128x128", 115_839, 1_100_005, 0.501,
                                            (0, 14, 46, 0), (1100005, 40, 8, 0)),
    "dvs128_lifetime_garfield.mat": ("mat", "128x128", 202_235, 738_000, 0.548,
                                     (0, 28, 121, 0), (738000, 43, 108, 1)),
}
# SOURCES.md's durations, as printed there (s, rounded)
SOURCES_DURATION_S = {
    "davis346_frames_imu_evlib.aedat4": 0.170, "dvxplorer_320x240_tonic.aedat4": 0.590,
    "prophesee_gen3_vga_evt2_faery.raw": 0.0959, "prophesee_gen41_hd_evt3_expelliarmus.raw": 0.00880,
    "ncars_atis_sample.dat": 0.100, "nmnist_sample.bin": 0.311, "ncaltech101_faces_easy_0001.bin": 0.299,
    "dvsgesture_slayer_1.bs2": 1.450, "dvs128_lifetime_building.mat": 1.100,
    "dvs128_lifetime_garfield.mat": 0.738,
}


def _event(c, i):
    return int(c.t[i]), int(c.x[i]), int(c.y[i]), int(c.p[i])


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_file_decodes_as_sources_md_says(real_data, name):
    fmt, geom, n, span, on, first, last = REAL[name]
    src = open_source(real_data / name, chunk_events=20_000)
    chunks, read = [], []
    for c in src:
        chunks.append(c)
        read.append(src.fraction_read)
    ev = concat(chunks, src.geometry)
    # how far into the file (the progress line's percent): rising to the whole file, or unknown (AEDAT4)
    if fmt == "aedat4":
        assert set(read) == {None}
    else:
        assert read == sorted(read) and 0 < read[0] and read[-1] == pytest.approx(1.0, abs=1e-4)
    assert src.format == fmt and str(src.geometry) == geom and not src.has_labels
    assert len(ev) == n
    assert int(ev.t[-1] - ev.t[0]) == span
    if name in SOURCES_DURATION_S:
        assert span / 1e6 == pytest.approx(SOURCES_DURATION_S[name], abs=0.0006)
    assert ev.p.mean() == pytest.approx(on, abs=0.0006)
    assert _event(ev, 0) == first and _event(ev, -1) == last
    assert np.all(np.diff(ev.t) >= 0)
    # chunks of the requested size, watermarks that never go back and never lie
    assert all(len(c) == 20_000 for c in chunks[:-1])
    for a, b in zip(chunks, chunks[1:]):
        assert a.t_end <= b.t[0] and a.t_end >= a.t[-1]
    info = src.info()
    assert info["format"] == fmt and info["width"] == src.geometry.width


def test_twins_agree_event_for_event(real_data):
    for a, b in [("dvxplorer_320x240_tonic.aedat4", "dvxplorer_320x240_tonic.npy"),
                 ("prophesee_gen3_vga_evt2_faery.raw", "prophesee_gen3_vga_evt2_faery.h5"),
                 ("dvs128_lifetime_building.mat", "dvs128_lifetime_building_events.txt")]:
        ea, eb = (concat(list(open_source(real_data / f))) for f in (a, b))
        for k in "txyp":
            np.testing.assert_array_equal(getattr(ea, k), getattr(eb, k), err_msg=f"{a} vs {b}: {k}")


def test_aedat4_matches_faery(real_data):
    import faery  # declared (dev) dependency: a broken install fails
    for name in ("davis346_frames_imu_evlib.aedat4", "dvxplorer_320x240_tonic.aedat4"):
        ours = concat(list(open_source(real_data / name)))
        ref = np.concatenate(list(faery.events_stream_from_file(real_data / name)))
        np.testing.assert_array_equal(ours.t, ref["t"].astype(np.int64))
        np.testing.assert_array_equal(ours.x, ref["x"])
        np.testing.assert_array_equal(ours.p, ref["on"].astype(np.uint8))


def test_chunks_by_duration_on_a_real_file(real_data):
    src = open_source(real_data / "prophesee_gen3_vga_evt2_faery.raw", chunk_us=10_000)
    chunks = list(src)
    assert sum(map(len, chunks)) == 521_252
    assert all(c.duration_us < 10_000 for c in chunks)
    assert len(chunks) == 10  # 95.9 ms in 10 ms bins


def test_cli_info_replay_convert_on_every_real_file(real_data, tmp_path, capsys):
    for name, (fmt, geom, n, span, *_rest) in sorted(REAL.items()):
        assert main(["info", str(real_data / name), "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert (out["format"], f"{out['width']}x{out['height']}", out["events"], out["duration_us"]) == (
            fmt, geom, n, span), name
        assert out["source"]["format"] == fmt
        rrd = tmp_path / f"{name}.rrd"
        assert main(["replay", str(real_data / name), "--denoise", "none", "--save", str(rrd), "--json"]) == 0
        stats = json.loads(capsys.readouterr().out)
        assert stats["events_in"] == n and rrd.stat().st_size > 0, name
        raw = tmp_path / f"{name}.raw"
        assert main(["convert", str(real_data / name), str(raw), "--json"]) == 0
        capsys.readouterr()
        back = concat(list(open_source(raw)))
        want = concat(list(open_source(real_data / name)))
        assert str(back.geometry) == geom
        for k in "txyp":
            np.testing.assert_array_equal(getattr(back, k), getattr(want, k), err_msg=f"{name}: {k}")
