"""Runs every rostest integration test in test/ros/*.test as its own pytest case.

Each runs `rostest <abs path to .test>` in a subprocess (rostest starts its own
master on a free port). Needs the environment of scripts/env.sh (as under `make test`).
Per-test timeout: $MMM_ROSTEST_TIMEOUT seconds (default 300).
"""
import os
import re
import shutil
import signal
import subprocess
from pathlib import Path

import pytest

ROS_DIR = Path(__file__).resolve().parent / "ros"
ROS_TESTS = sorted(ROS_DIR.glob("*.test"))
TIMEOUT = float(os.environ.get("MMM_ROSTEST_TIMEOUT", "300"))


def _summary_count(output: str, key: str):
    output = re.sub(r"\x1b\[[0-9;]*m", "", output)  # rosunit colours failing lines
    m = re.findall(rf"^\s*\*\s*{key}:\s*(\d+)\s*$", output, re.MULTILINE)
    return int(m[-1]) if m else None


@pytest.mark.skipif(shutil.which("rostest") is None, reason="rostest not on PATH (use scripts/env.sh)")
@pytest.mark.parametrize("test_file", ROS_TESTS, ids=[p.name for p in ROS_TESTS])
def test_rostest(test_file: Path, tmp_path: Path):
    # Absolute path alone (`rostest PKG /abs/path` is rejected); rostest infers the package.
    cmd = ["rostest", "--results-base-dir", str(tmp_path), str(test_file)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        output, _ = proc.communicate(timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGINT)  # let roslaunch shut its nodes down
        try:
            output, _ = proc.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            output, _ = proc.communicate()
        pytest.fail(f"{' '.join(cmd)} timed out after {TIMEOUT:.0f}s\n{output}")

    tests = _summary_count(output, "TESTS")
    errors = _summary_count(output, "ERRORS")
    failures = _summary_count(output, "FAILURES")
    ok = (proc.returncode == 0 and tests is not None and tests >= 1
          and errors == 0 and failures == 0)
    if not ok:
        print(output)  # shown by pytest in "Captured stdout" for the failed case
    assert ok, (f"{' '.join(cmd)}: exit {proc.returncode}, tests={tests}, errors={errors}, "
                f"failures={failures}\n--- rostest output (tail) ---\n"
                + "\n".join(output.splitlines()[-80:]))
