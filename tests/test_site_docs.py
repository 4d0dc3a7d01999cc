"""The README and the documentation site keep their promises: a README that fits on a few
screens and points only inside the repository, and figures that are those of one whole
`make bench` run (benchmarks/results.json), never copied by hand."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import figures  # noqa: E402
import run as bench_run  # noqa: E402
from targets import SUFFIX_TARGETS, TARGETS  # noqa: E402

README = ROOT / "README.md"
PAGES = sorted((ROOT / "docs").rglob("*.md"))
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


@pytest.fixture(scope="module")
def results_doc() -> dict:
    return json.loads((ROOT / "benchmarks" / "results.json").read_text())


def test_readme_opens_with_the_two_commands_and_fits_on_a_few_screens() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= 250
    head = "\n".join(lines[:8])
    assert "make run" in head and "make test" in head


@pytest.mark.parametrize("page", [README, *PAGES], ids=lambda p: str(p.relative_to(ROOT)))
def test_links_stay_inside_the_repository_and_resolve(page: Path) -> None:
    text = page.read_text()
    assert "../shared" not in text, f"{page.name} points outside the repository"
    for target in LINK.findall(text):
        if "://" in target or target.startswith("mailto:"):
            continue
        resolved = (page.parent / target).resolve()
        assert resolved.is_relative_to(ROOT), f"{page.name}: {target} leaves the repository"
        assert resolved.exists(), f"{page.name}: {target} does not exist"


def test_results_json_was_written_whole_by_one_run_of_every_benchmark(results_doc: dict) -> None:
    assert results_doc.get("modules") == bench_run.MODULES and "failed" not in results_doc, (
        "benchmarks/results.json is not one whole `make bench` run of today's benchmarks"
    )


def test_every_target_names_a_figure_a_benchmark_writes(results_doc: dict) -> None:
    missing = [key for key in TARGETS if key not in results_doc["results"]]
    assert not missing, f"targets no benchmark writes: {missing}"


def test_every_suffix_target_applies_to_some_figure(results_doc: dict) -> None:
    unused = [s for s in SUFFIX_TARGETS if not any(k.endswith(s) for k in results_doc["results"])]
    assert not unused, f"suffix targets that match no figure: {unused}"


def test_the_benchmarks_page_is_rendered_from_results_json(results_doc: dict) -> None:
    page = ROOT / "docs" / "benchmarks.md"
    assert page.read_text() == figures.render_page(results_doc, TARGETS, SUFFIX_TARGETS), (
        "docs/benchmarks.md differs from results.json: rerun `make bench`"
    )


def test_every_tagged_figure_is_the_one_results_json_holds(results_doc: dict) -> None:
    results = results_doc["results"]
    for page in [README, *PAGES]:
        for key, value in figures.tagged(page.read_text()):
            assert key in results, f"{page.name} quotes {key}, which no benchmark writes"
            assert value == figures.fmt(results[key]), (
                f"{page.name} quotes {key} = {value}, results.json holds {figures.fmt(results[key])}"
            )


def test_a_refresh_sets_a_stale_figure_and_marks_an_unmeasured_one() -> None:
    text = "RPE <!--bench:slam.rpe-->0.9<!--/bench--> m, <!--bench:gone-->7<!--/bench-->"
    fresh = figures.refresh(text, {"slam.rpe": 0.0213456})
    assert (
        fresh
        == "RPE <!--bench:slam.rpe-->0.02135<!--/bench--> m, <!--bench:gone-->n/a<!--/bench-->"
    )
