"""Tests of canalsurf.experiments: the paper-reproduction runner and its Markdown report."""

from __future__ import annotations

import logging
import math
import re

import pytest

from canalsurf import experiments
from canalsurf.errors import InputError, ReconstructionError
from canalsurf.experiments import EXPERIMENTS, REPORT_NAME, SETTINGS, run_paper

#: Every figure the paper reports, as printed (they must appear verbatim in the report).
PAPER_FIGURES = ("1631", "0.984172", "1.94653324", "1.0200849",
                 "1934", "0.298778", "1.60093152", "0.814391259",
                 "1609", "1.772888", "1.0936823", "0.14423506", "0.07538086",
                 "1995", "1.4648859", "1.023708", "0.5901724", "0.2694635")


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """All four experiments, both settings, one seed (about 10 s)."""
    out = tmp_path_factory.mktemp("paper")
    messages = []
    results = run_paper(out, seeds=1, progress=messages.append)
    return out, results, (out / REPORT_NAME).read_text(encoding="utf-8"), messages


def _without_timings(text: str) -> str:
    """The report with the last cell (seconds per run) of the Runs table removed."""
    lines, in_runs = [], False
    for line in text.splitlines():
        if line.startswith("## "):
            in_runs = line == "## Runs"
        if in_runs and line.startswith("|"):
            line = line.rstrip("|").rsplit("|", 1)[0]
        lines.append(line)
    return "\n".join(lines)


def _subset(monkeypatch, *names):
    monkeypatch.setattr(experiments, "EXPERIMENTS", {n: EXPERIMENTS[n] for n in names})


def _numbers(node):
    """Every float/int leaf of a nested dict or list (seeds and counts included)."""
    if isinstance(node, dict):
        for v in node.values():
            yield from _numbers(v)
    elif isinstance(node, list):
        for v in node:
            yield from _numbers(v)
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield node


def test_report_has_the_four_experiments_and_the_papers_figures(full_run):
    _, _, text, _ = full_run
    assert "canalsurf paper -o docs/" in text.splitlines()[2]
    for name, exp in EXPERIMENTS.items():
        assert f"## {exp['title']} (`{name}`)" in text
    for figure in PAPER_FIGURES:
        assert figure in text, figure
    for section in ("## Runs", "## Failures", "## Which spine figure is honest", "## Notes"):
        assert section in text
    assert "radius of 3" in text  # the Figure 15 typo is explained
    assert not re.search(r"\b(19|20)\d\d-\d\d-\d\d\b", text), "the report must not hold a date"


def test_progress_is_called_once_per_run(full_run):
    _, _, _, messages = full_run
    assert len(messages) == len(EXPERIMENTS) * len(SETTINGS)
    assert messages[0].startswith("fig9-pipe")


def test_returned_numbers_are_finite(full_run):
    _, results, _, _ = full_run
    assert set(results) == set(EXPERIMENTS)
    for name, res in results.items():
        assert res["reported"] == EXPERIMENTS[name]["reported"]
        assert all(math.isfinite(x) for x in _numbers(res["spine"]))
        for setting in SETTINGS:
            agg = res[setting]
            assert agg["runs"] == 1
            if agg["failures"] == 0:
                assert all(math.isfinite(x) for x in _numbers(agg)), (name, setting)
                assert sum(agg["kinds"].values()) == 1
    # The automatic setting reconstructs every surface.
    assert all(res["automatic"]["failures"] == 0 for res in results.values())


def test_measured_figures_against_ground_truth(full_run):
    _, results, _, _ = full_run
    fig9 = results["fig9-pipe"]
    a, b = fig9["paper_parameters"], fig9["automatic"]
    # The paper's parameters on its own pipe: 5 moves of 0.2 and Eq. (6) within 2 % of r = 1.
    assert a["iterations"] == EXPERIMENTS["fig9-pipe"]["reported"]["iterations"]
    assert abs(a["eq6_radius"] - 1.0) < 0.02
    # Geometric spine error a few hundredths of the radius; the equal-raw-parameter figure is
    # parameterisation drift, tens of times larger (as the paper's ~1.0).
    assert b["spine_mean"]["average"] < 0.05
    assert b["raw_mean"]["average"] > 10 * b["spine_mean"]["average"]
    # The true spine against itself: large equal-parameter drift, closest point ~ sampling resolution.
    assert fig9["spine"]["drift_mean"] > 0.5
    assert fig9["spine"]["same_closest_max"] < 1e-2
    # Figure 15's true radius is 0.3, and its spine's tightest bend is about that size.
    assert results["fig15-pipe"]["spine"]["true_mean_radius"] == pytest.approx(0.3)
    assert 0.25 < results["fig15-pipe"]["spine"]["min_curvature_radius"] < 0.32


def test_rerun_is_identical_apart_from_timings(tmp_path, monkeypatch):
    _subset(monkeypatch, "fig9-pipe")
    first, second = tmp_path / "one", tmp_path / "two"
    r1 = run_paper(first, seeds=1)
    r2 = run_paper(second, seeds=1)
    t1 = (first / REPORT_NAME).read_text(encoding="utf-8")
    t2 = (second / REPORT_NAME).read_text(encoding="utf-8")
    assert _without_timings(t1) == _without_timings(t2)
    for res in (r1, r2):
        for setting in SETTINGS:
            res["fig9-pipe"][setting].pop("seconds")
    assert repr(r1) == repr(r2)
    # Only the seconds column differs: the Runs rows keep their other five cells.
    runs_rows = [ln for ln in _without_timings(t1).splitlines() if ln.startswith("| fig9-pipe | (")]
    assert len(runs_rows) == 2 and all(ln.count("|") == 5 for ln in runs_rows)


def test_a_failing_run_is_counted_not_raised(tmp_path, monkeypatch):
    _subset(monkeypatch, "fig9-pipe")
    real = experiments.reconstruct

    def flaky(points, **kwargs):
        if kwargs.get("stop") == "paper":
            raise ReconstructionError("shrinking did not stop (test)")
        return real(points, **kwargs)

    monkeypatch.setattr(experiments, "reconstruct", flaky)
    level = logging.getLogger("canalsurf.pipeline").level
    results = run_paper(tmp_path, seeds=2)
    text = (tmp_path / REPORT_NAME).read_text(encoding="utf-8")
    a, b = results["fig9-pipe"]["paper_parameters"], results["fig9-pipe"]["automatic"]
    assert (a["runs"], a["failures"], b["runs"], b["failures"]) == (2, 2, 2, 0)
    assert [f["seed"] for f in a["failure_reasons"]] == [0, 1]
    assert a["failure_reasons"][0]["reason"] == "ReconstructionError: shrinking did not stop (test)"
    assert math.isnan(a["iterations"]) and a["spine_mean"]["worst_seed"] is None
    assert "seed 1: ReconstructionError: shrinking did not stop (test)" in text
    assert "| fig9-pipe | (a) paper parameters |" in text
    assert math.isfinite(b["spine_mean"]["average"])
    assert logging.getLogger("canalsurf.pipeline").level == level


def test_failure_records_how_the_shrinking_ended(tmp_path, monkeypatch):
    # A run that fails after shrinking reports the pipeline's stop rule (read from its log record).
    _subset(monkeypatch, "fig9-pipe")
    real = experiments.reconstruct

    def fails_after_shrinking(points, **kwargs):
        real(points, **kwargs)
        raise ReconstructionError("rejected afterwards (test)")

    monkeypatch.setattr(experiments, "reconstruct", fails_after_shrinking)
    results = run_paper(tmp_path, seeds=1)
    failure = results["fig9-pipe"]["paper_parameters"]["failure_reasons"][0]
    assert failure["stop_rule"] == "mu" and failure["iterations"] == 5
    assert "(shrinking: 5 moves, stopped by `mu`)" in (tmp_path / REPORT_NAME).read_text(encoding="utf-8")


@pytest.mark.parametrize("seeds", [0, -1, 1.5, True, "3"])
def test_bad_seeds_are_rejected(tmp_path, seeds):
    with pytest.raises(InputError, match="seeds must be a positive integer, got"):
        run_paper(tmp_path, seeds=seeds)


def test_outdir_that_is_a_file_is_rejected(tmp_path):
    target = tmp_path / "file.md"
    target.write_text("x")
    with pytest.raises(InputError, match="is not a folder"):
        run_paper(target, seeds=1)


def test_missing_outdir_is_created(tmp_path, monkeypatch):
    _subset(monkeypatch, "fig9-pipe")

    def fails(points, **kwargs):
        raise ReconstructionError("not run (test)")

    monkeypatch.setattr(experiments, "reconstruct", fails)
    out = tmp_path / "new" / "docs"
    run_paper(out, seeds=1)
    assert (out / REPORT_NAME).is_file()
    assert [p.name for p in out.iterdir()] == [REPORT_NAME]  # no temporary file left behind
