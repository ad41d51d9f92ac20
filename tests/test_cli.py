"""The command line: info, demo, exit codes and --json."""

import json
import os

import pytest

from cstorm.cli import main


def test_info_json(capsys):
    assert main(["info", "tumbler", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["nv"] == 5 and out["total_mass"] == pytest.approx(3.0)
    assert [b["joint"] for b in out["bodies"]] == ["root_x", "root_z", "root_pitch", "hip", "shoulder"]


def test_info_text_lists_shapes(capsys):
    assert main(["info", "tumbler"]) == 0
    text = capsys.readouterr().out
    assert "capsule r=0.04 length=0.3" in text and "joint 'hip': revolute" in text


def test_bad_model_exits_2(capsys):
    assert main(["info", "no_such_robot.urdf", "--json"]) == 2
    out = json.loads(capsys.readouterr().out)
    assert out["success"] is False and "no_such_robot.urdf" in out["message"]


def test_demo_writes_files(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--t-final", "0.5", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["energy_drift_rel"] < 1e-6
    for f in ("pendulum_angles.png", "pendulum_strobe.png", "pendulum_trajectory.csv", "tumbler_info.txt"):
        assert os.path.getsize(tmp_path / f) > 100
