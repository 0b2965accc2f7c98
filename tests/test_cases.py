"""Every case file in cases/ runs end to end on a short override, so that no case rots."""

from __future__ import annotations

import pytest

from conftest import CASES, run_case_file
from fem_impact.config.case import load_case

CASE_FILES = sorted(CASES.glob("*.yaml"))


@pytest.mark.parametrize("path", CASE_FILES, ids=[p.stem for p in CASE_FILES])
def test_case_runs(tmp_path, path):
    case = load_case(path)
    steps = 25
    summary, history = run_case_file(path, tmp_path, f"solver.t_end={steps * case.solver.dt}",
                                     f"output.every={steps // 2}")
    assert summary["steps"] == steps and len(history) == steps + 1
    assert summary["max_energy_error_relative"] < 1e-8
    assert (tmp_path / "results.pvd").is_file()


def test_there_are_cases():
    assert {"impacting_bar", "impacting_bar_steel", "signorini_bar", "two_bars", "beam_stop", "vibroconverter_free",
            "vibroconverter_forced", "vibrodrive"} <= {p.stem for p in CASE_FILES}
