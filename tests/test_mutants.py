"""The suite catches the one-line bugs tools/mutants.py lists: each mutant, applied in a scratch copy of the
repository, makes at least one of the tests written for it fail (slow: a pytest run per mutant)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
from tools import mutants


def test_every_mutant_names_a_line_that_is_in_its_file_once_and_tests_that_exist():
    for m in mutants.MUTANTS:
        assert (ROOT / m.path).read_text(encoding="utf-8").count(m.before) == 1, m.name
        assert m.before != m.after and m.catchers, m.name
        for selection in m.catchers + m.related:
            assert mutants.present(selection, ROOT), (m.name, selection)


@pytest.mark.slow
def test_every_mutant_is_killed_by_the_tests_written_for_it():
    done = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "mutants.py"), "--fast"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    print(done.stdout)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"{len(mutants.MUTANTS)} of {len(mutants.MUTANTS)} mutants killed" in done.stdout
    assert "SURVIVED" not in done.stdout and "STALE" not in done.stdout
