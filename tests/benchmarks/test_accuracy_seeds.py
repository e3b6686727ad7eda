"""The accuracy benchmark's streets stay unseen: seeds 10001-19999 are its own
(``benchmarks/accuracy.py``), so no training drive, test, example or figure may name one."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: The benchmark, this test, and the texts that say which streets its figures come from.
OWNERS = {
    "benchmarks/accuracy.py",
    "tests/benchmarks/test_accuracy_seeds.py",
    "README.md",
    "docs/explanation/figures.md",
    "CHANGELOG.md",
    "benchmarks/README.md",
}
#: A seed of the reserved range: ``--seed 10001``, ``seed=12345``, ``seeds 10001-10010``,
#: ``random_scene_spec(10001, ...)``, or one of the benchmark's drive names (``street_10001``).
RESERVED = re.compile(
    r"(seeds?[\s=:_(\"']*|random_scene_spec\(\s*|street_)1(?!0000\b)\d{4}\b", re.IGNORECASE
)


def reserved_seeds_named(text: str) -> list[str]:
    """The lines of ``text`` that name a seed of the reserved range."""
    return [line.strip() for line in text.splitlines() if RESERVED.search(line)]


def test_the_rule_finds_a_reserved_seed_and_passes_others() -> None:
    assert reserved_seeds_named("guardrail simulate d --seed 10001 --length 300")
    assert reserved_seeds_named("spec = random_scene_spec(seed=19999, length=300)")
    assert not reserved_seeds_named("guardrail simulate d --seed 201 --length 10001")
    assert not reserved_seeds_named("seed 10000 or 20000")
    assert not reserved_seeds_named("10001 points")
    assert reserved_seeds_named("random_scene_spec(12345, 300.0)")
    assert reserved_seeds_named("benchmarks/data/accuracy/street_10004")
    assert reserved_seeds_named('{"seed": 10002}')


def test_no_other_file_names_a_seed_of_the_accuracy_benchmark() -> None:
    files = subprocess.run(
        ["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    named = {}
    for name in files:
        path = ROOT / name
        if name in OWNERS or not path.is_file() or path.suffix in {".npz", ".jpg", ".png", ".laz"}:
            continue
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        found = reserved_seeds_named(text)
        if found:
            named[name] = found
    assert not named, f"seeds 10001-19999 belong to benchmarks/accuracy.py alone: {named}"
