"""The documentation's code runs: every ```python block of docs/tutorial.md, in order,
in one namespace, in a temporary directory (the tutorial writes its outputs there), so
the tutorial never goes stale. The tutorial's own asserts check its results; this test
checks the files it promises."""

import os
import re
import shutil

import pytest

ROOT = os.path.join(os.path.dirname(__file__), os.pardir)
TUTORIAL = os.path.join(ROOT, "docs", "tutorial.md")


def python_blocks(path):
    """The bodies of the ```python fenced blocks of a Markdown file, in order."""
    text = open(path, encoding="utf-8").read()
    return re.findall(r"^```python\n(.*?)^```\s*$", text, flags=re.S | re.M)


def test_tutorial_has_code():
    blocks = python_blocks(TUTORIAL)
    assert len(blocks) >= 8 and "cs.solve(" in "".join(blocks) and "cs.ModelBuilder(" in blocks[1]


def test_tutorial_runs(tmp_path, monkeypatch):
    os.makedirs(tmp_path / "examples")
    shutil.copy(os.path.join(ROOT, "examples", "acrobot.urdf"), tmp_path / "examples")  # its URDF example
    monkeypatch.chdir(tmp_path)
    ns = {"__name__": "tutorial"}
    for i, block in enumerate(python_blocks(TUTORIAL)):
        try:
            exec(compile(block, f"docs/tutorial.md (python block {i + 1})", "exec"), ns)
        except Exception as e:  # name the block in the failure
            pytest.fail(f"docs/tutorial.md python block {i + 1} failed: {type(e).__name__}: {e}\n{block}")
    sol, summary = ns["sol"], ns["summary"]
    assert sol.success and sol.trajectory["q"].shape == (101, 2)
    for f in ("summary.json", "solution.npz", "trajectory.csv", "paths.png", "contacts.png", "animation.gif"):
        assert os.path.getsize(tmp_path / "tutorial-out" / f) > 1000, f
    assert os.path.exists(tmp_path / "press.npz")
    # the figures the tutorial shows are in docs/img
    text = open(TUTORIAL, encoding="utf-8").read()
    for img in re.findall(r"\]\((img/[^)]+)\)", text):
        assert os.path.exists(os.path.join(ROOT, "docs", img)), img
