"""Every ```python block of docs/api.md, docs/transforms.md and README.md runs as written, from a directory
holding the recordings."""

import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "docs" / "api.md", ROOT / "docs" / "transforms.md", ROOT / "README.md"]
BLOCKS = [(doc, code) for doc in DOCS
          for code in re.findall(r"^```python\n(.*?)^```$", doc.read_text(encoding="utf-8"), re.S | re.M)]


def test_the_doc_has_python_blocks():
    assert len([b for b in BLOCKS if b[0].name == "api.md"]) >= 5 and len(BLOCKS) > 5


@pytest.mark.parametrize("doc, code", BLOCKS, ids=[f"{d.name}-{i}" for i, (d, _) in enumerate(BLOCKS)])
def test_python_block_runs(doc, code, tmp_path, capsys):
    (tmp_path / "recordings").symlink_to(ROOT / "recordings")
    here = os.getcwd()
    os.chdir(tmp_path)
    try:
        namespace = {"__name__": "__main__"}
        exec(compile(code, str(doc), "exec"), namespace)
    finally:
        os.chdir(here)
    assert capsys.readouterr().out.strip() or doc.name == "README.md"  # the API doc's blocks show something
    assert "kept" not in namespace or len(namespace["kept"])


def test_the_iterable_dataset_block_reads_each_window_once_across_workers(tmp_path, capsys):
    """docs/api.md's torch-style IterableDataset (torch is not a dependency: the plain iterable torch would
    subclass): every window of every recording, each once when split between workers, each its own array."""
    code = next(code for doc, code in BLOCKS if "class VoxelWindows" in code)
    (tmp_path / "recordings").symlink_to(ROOT / "recordings")
    here = os.getcwd()
    os.chdir(tmp_path)
    try:
        namespace = {"__name__": "__main__"}
        exec(compile(code, "docs/api.md", "exec"), namespace)
        whole = [(x, t) for x, t in namespace["dataset"]]
        halves = [[(x, t) for x, t in half] for half in namespace["halves"]]
    finally:
        os.chdir(here)
    assert capsys.readouterr().out == "50 windows of {(5, 260, 346)}\n[30, 20]\n"
    assert len({id(x) for x, _ in whole}) == len(whole) == 50  # own arrays: torch.from_numpy may keep each
    split = sorted((t, x.tobytes()) for half in halves for x, t in half)
    assert split == sorted((t, x.tobytes()) for x, t in whole)
