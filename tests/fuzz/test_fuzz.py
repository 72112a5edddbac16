"""Fuzz sample for CI: every parser of outside input against random and mutated inputs (config
loader, trajectory loader, control-socket protocol, Modbus and ASCII load cells, NatNet, tracker
line stream, WitMotion attitude, EMCY decoding, the emulated slcan adapter). Each input must be
accepted or refused with the parser's documented error; any other exception fails the test.
``benchmarks/fuzz.py`` runs the same targets with 10,000 inputs each."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from targets import TARGETS, Target, check

#: Inputs per target in CI (the benchmark runs 10,000).
CI_EXAMPLES = 150


@pytest.mark.parametrize("target", TARGETS, ids=[t.name for t in TARGETS])
def test_parser_survives_fuzzing(target: Target) -> None:
    seen: list[int] = []

    @settings(
        max_examples=CI_EXAMPLES,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(target.strategy())
    def run(value) -> None:
        seen.append(1)
        check(target, value)

    run()
    assert len(seen) >= CI_EXAMPLES // 2  # hypothesis really fed inputs
