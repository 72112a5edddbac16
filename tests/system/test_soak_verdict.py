"""The soak's verdict (``benchmarks/soak.py``, ``soakverdict.py``): a staged lockout, an unexpected
trip and a recovery no run followed each fail it, naming the rule; a healthy record passes."""

from __future__ import annotations

from soakverdict import LOCKOUT_RUNS, SoakRun, count_failures, run_failures, verdict

SLACK = "tension_low:cable1: 0.03 N below 0.1 N (slack)"


def _counts(**over):
    out = {
        "samples_expected": 1000,
        "samples_logged": 1000,
        "log_gaps": 0,
        "faults_missed": [],
        "faults_injected": 1,
        "faults_tripped": 1,
        "faults_safe": 1,
        "faults_recovered": 1,
        "rss_growth_pct": 1.0,
        "daemon_alive": True,
        "recovery_errors": [],
    }
    return {**out, **over}


def test_a_staged_lockout_after_a_recovery_fails_the_soak():
    """The record of the lockout the soak once passed: an over-current EMCY, its recovery, then
    every run tripping on a slack cable 1 in its first cycle (counts all in order)."""
    runs = [SoakRun(f"soak{i}", "completed", None) for i in range(10)]
    runs.append(SoakRun("soak10", "tripped", "emcy:over_current", "emcy:node1:0x2310: ..."))
    runs.append(SoakRun("soak11", "tripped", None, SLACK, after_recovery=True))
    runs += [SoakRun(f"soak{i}", "tripped", None, SLACK) for i in range(12, 449)]
    failures = verdict(_counts(), runs)
    assert not count_failures(_counts())  # the counts alone passed, as the old verdict did
    lockouts = [f for f in failures if f.startswith("lockout")]
    assert len(lockouts) == 1 and "438 runs in a row" in lockouts[0], failures
    assert "tension_low:cable1" in lockouts[0]
    assert any(f.startswith("no completed run after recovery: soak11") for f in failures)
    assert sum(f.startswith("unexpected trip") for f in failures) == 438


def test_the_verdict_rules_one_by_one():
    ok = [SoakRun("a", "completed", None), SoakRun("b", "tripped", "bus_off", "bus: node 2")]
    assert verdict(_counts(), [*ok, SoakRun("c", "completed", None, after_recovery=True)]) == []
    # A recovery no run followed.
    assert run_failures(ok, recovery_pending=True) == [
        "no completed run after recovery: the soak ended before one ran"
    ]
    # One unexpected trip: that, not a lockout; LOCKOUT_RUNS in a row: a lockout.
    one = [*ok, SoakRun("c", "tripped", None, SLACK, after_recovery=True)]
    got = run_failures(one)
    assert len(got) == 2 and not any(f.startswith("lockout") for f in got)
    streak = [SoakRun(f"r{i}", "tripped", None, SLACK) for i in range(LOCKOUT_RUNS)]
    assert any(f.startswith("lockout: 3 runs") for f in run_failures(streak))
    # A completed run ends a streak; a run tripped by its injected fault does not.
    broken = [*streak[:2], SoakRun("x", "completed", None), *streak[:2]]
    assert not any(f.startswith("lockout") for f in run_failures(broken))
    kept = [*streak[:2], SoakRun("x", "tripped", "bus_off", "bus"), streak[0]]
    assert any(f.startswith("lockout") for f in run_failures(kept))
    # The counts' own rules.
    assert count_failures(_counts(faults_recovered=0)) == ["faults: 1 injected, 0 recovered"]
    assert count_failures(_counts(log_gaps=2))[0].startswith("log:")
    assert count_failures(_counts(daemon_alive=False)) == ["daemon not alive at the end"]
