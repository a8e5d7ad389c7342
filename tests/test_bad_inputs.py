"""Every bad input: non-zero exit, one line `scenelabel: error: ...` naming the problem, no traceback.

The cases live in tests/bad_input_cases.py; tools/errors_table.py runs the same cases and writes
the table of messages in docs/errors.md.
"""

import subprocess
import sys

import pytest
from bad_input_cases import CASES


def run_cli(args):
    return subprocess.run([sys.executable, "-m", "scenelabel", *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_input_gives_one_clean_line(case, tmp_path):
    proc = run_cli(case.setup(tmp_path))
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("scenelabel: error:")]
    assert len(lines) == 1, proc.stderr
    for needle in case.expect:
        assert needle in lines[0], lines[0]
