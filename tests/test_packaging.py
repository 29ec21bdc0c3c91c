"""The built wheel carries assets/ and envs/ and gives a working gym.make from any directory."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_wheel_ships_data_and_makes_env(tmp_path):
    wheel_dir = tmp_path / "wheel"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(wheel_dir),
            str(ROOT),
        ],
        check=True,
    )
    (wheel,) = wheel_dir.glob("simn_sim-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "simn_sim/_data/assets/robot.xml" in names
    assert "simn_sim/_data/envs/office_reference.json" in names
    target = tmp_path / "site"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--no-deps",
            "-q",
            "--target",
            str(target),
            str(wheel),
        ],
        check=True,
    )
    code = (
        "import gymnasium as gym, simn_sim, pathlib;"
        "assert pathlib.Path(simn_sim.__file__).resolve().is_relative_to(pathlib.Path(r'%s').resolve()), simn_sim.__file__;"
        "e = gym.make('SimnOffice-v0', config={'width': 64, 'height': 48});"
        "o, i = e.reset(seed=0); e.step(e.action_space.sample()); print('OK', o['rgb'].shape)"
    ) % target
    env = {**os.environ, "PYTHONPATH": str(target)}
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert "OK (48, 64, 3)" in out.stdout
