"""ASCII stream load cell: line grammar, incremental parsing of recorded streams with faults,
the reader on a pty (disconnect included) and against the simulated streamer."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.loadcell import G_M_PER_S2, LB_KG
from cdcr_ctl.sensors.loadcell_ascii import (
    MAX_LINE_BYTES,
    AsciiLineParser,
    AsciiLoadCellStream,
    format_line,
    parse_line,
)
from cdcr_ctl.sensors.loadcell_sampler import LoadCellSampler
from cdcr_ctl.sim.loadcells import CAPACITY_N, AsciiLoadCellSim

KG = G_M_PER_S2

GOOD = [
    # line, value, unit, N, stable, net, overload
    (b"ST,GS,+  4.876kg", 4.876, "kg", 4.876 * KG, True, False, False),
    (b"US,NT,-  0.120kg", -0.120, "kg", -0.120 * KG, False, True, False),
    (b" st , gs , + 4.876 KG ", 4.876, "kg", 4.876 * KG, True, False, False),
    (b"ST,GS,+0004876 g", 4876.0, "g", 4.876 * KG, True, False, False),
    (b"ST,GS,   12.5N", 12.5, "N", 12.5, True, False, False),
    (b"ST,NT,+   1.00lb", 1.0, "lb", LB_KG * KG, True, True, False),
    (b"ST,GS,+ 2lbs", 2.0, "lb", 2 * LB_KG * KG, True, False, False),
    (b"ST,GS,+   .5kg", 0.5, "kg", 0.5 * KG, True, False, False),
    (b"ST,GS,+  7.kg", 7.0, "kg", 7.0 * KG, True, False, False),
    (b"ST,+  1.000kg", 1.0, "kg", 1.0 * KG, True, None, False),  # no gross/net field
    (b"OL,GS,+9999.99kg", math.inf, "kg", math.inf, None, False, True),
    (b"ST,GS,+     OLkg", math.inf, "kg", math.inf, None, False, True),
    (b"ST,GS,-     OLkg", -math.inf, "kg", -math.inf, None, False, True),
]

BAD = [
    b"",
    b"GS,+  4.876kg",  # line cut at its start (connected mid-line)
    b"876kg",
    b"ST,GS,+  4.876",  # no unit
    b"ST,GS,+  4.8.76kg",
    b"ST,GS,++4.876kg",
    b"ST,GS,+ 4 876kg",
    b"XX,GS,+  4.876kg",
    b"ST,XX,+  4.876kg",
    b"ST,GS,+  4.876kgf",
    b"ST,GS,+  4.876mg",
    b"ST;GS;+  4.876kg",
    b"ST,GS,+  4.87\xb56kg",
    b"ST,GS,+  4.876k\x00g",
    b"ST,GS,+  4.876??",
    b"ST,GS,+1234567890kg",  # more digits than any transmitter shows
]


@pytest.mark.parametrize("line,value,unit,newtons,stable,net,overload", GOOD)
def test_valid_lines(line, value, unit, newtons, stable, net, overload):
    r = parse_line(line)
    assert r is not None
    assert (r.value, r.unit, r.stable, r.net, r.overload) == (value, unit, stable, net, overload)
    assert r.reading_N == pytest.approx(newtons)


@pytest.mark.parametrize("line", BAD)
def test_invalid_lines_give_nothing(line):
    assert parse_line(line) is None


def test_format_line_is_what_the_transmitter_sends():
    assert format_line(4.876) == b"ST,GS,+  4.876kg\r\n"
    assert format_line(-0.12, stable=False, net=True) == b"US,NT,-  0.120kg\r\n"
    assert format_line(12.5, "N", decimals=1, width=6) == b"ST,GS,+  12.5N\r\n"
    assert format_line(99.0, overload=True) == b"OL,GS,+     OLkg\r\n"


RECORDED = (
    b"876kg\r\n"  # connected in the middle of a line
    b"ST,GS,+  4.876kg\r\n"
    b"\x00\xff\x13garbage\r\n"
    b"US,GS,+  4.901kg\r\n"
    b"ST,GS,+  4.9" + b"\xfe" + b"01kg\r\n"  # noise inside a line
    b"ST,GS,+  4.950kg\n"  # LF only
    b"ST,GS,+  4.951kg\r"  # CR only
    + b"Z"
    * (MAX_LINE_BYTES + 5)
    + b"ST,GS,+  9.999kg\r\n"  # tail of an overlong run: must not pass as a line
    b"OL,GS,+     OLkg\r\n"
    b"ST,NT,-  0.002kg\r\n"
    b"ST,GS,+  5.0"  # unfinished line at the end of the recording
)
EXPECTED = [
    (4.876, True),
    (4.901, False),
    (4.950, True),
    (4.951, True),
    (math.inf, None),
    (-0.002, True),
]


def _values(readings):
    return [(r.value, r.stable) for r in readings]


def test_recorded_stream_in_one_piece():
    parser = AsciiLineParser()
    assert _values(parser.feed(RECORDED)) == EXPECTED
    s = parser.stats
    assert (s.frames_ok, s.bad_frames) == (6, 4)
    assert s.discarded_bytes > MAX_LINE_BYTES


@pytest.mark.parametrize("chunk", [1, 2, 3, 7, 16, 33])
def test_recorded_stream_split_anywhere_gives_the_same_readings(chunk):
    parser = AsciiLineParser()
    out = []
    for i in range(0, len(RECORDED), chunk):
        out += parser.feed(RECORDED[i : i + chunk])
    assert _values(out) == EXPECTED
    assert parser.stats.bad_frames == 4


def reference_parse(line: bytes):
    """The line grammar again, written independently of the parser (no regex): (value, unit,
    stable, net) or None. Whitespace may surround each field and follow the sign."""
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError:
        return None
    parts = [p.strip(" \t\n\r\x0b\x0c") for p in text.split(",")]
    if len(parts) not in (2, 3) or parts[0].upper() not in ("ST", "US", "OL"):
        return None
    net = None
    if len(parts) == 3:
        if parts[1].upper() not in ("GS", "NT"):
            return None
        net = parts[1].upper() == "NT"
    last = parts[-1]
    sign = -1.0 if last[:1] == "-" else 1.0
    if last[:1] in ("+", "-"):
        last = last[1:].lstrip(" \t\n\r\x0b\x0c")
    suffixes = (("lbs", "lb"), ("lb", "lb"), ("kg", "kg"), ("g", "g"), ("n", "N"))
    found = next(((sx, u) for sx, u in suffixes if last.lower().endswith(sx)), None)
    if found is None:
        return None
    suffix, unit = found
    number = last[: -len(suffix)].rstrip(" \t\n\r\x0b\x0c")
    if number.upper() == "OL" or parts[0].upper() == "OL":
        if number.upper() != "OL" and not _is_number(number):
            return None
        return (sign * math.inf, unit, None, net)
    if not _is_number(number):
        return None
    return (sign * float(number), unit, parts[0].upper() == "ST", net)


def _is_number(text: str) -> bool:
    """Digits with at most one decimal point and at least one digit, at most 9 on each side."""
    whole, dot, frac = text.partition(".")
    if not set(whole + frac) <= set("0123456789") or len(whole) > 9 or len(frac) > 9:
        return False
    return whole != "" or (dot != "" and frac != "")


@pytest.mark.parametrize("line", [g[0] for g in GOOD] + BAD)
def test_reference_grammar_agrees_on_the_tables(line):
    r = parse_line(line)
    ref = reference_parse(line)
    assert (r is None) == (ref is None)
    if r is not None:
        assert (r.value, r.unit, r.stable, r.net) == ref


@settings(max_examples=500, deadline=None)
@given(st.lists(st.binary(max_size=80), max_size=8))
def test_random_bytes_never_crash_the_parser_nor_make_up_readings(chunks):
    # The ASCII format has no checksum: a random line that happens to follow the grammar
    # (hypothesis finds ones like b"ST,GS,0g") IS a reading. Any other random bytes must yield
    # nothing, and what does come out must be exactly what the reference grammar reads.
    parser = AsciiLineParser()
    out = []
    for chunk in chunks:
        out += parser.feed(chunk)
    data = b"".join(chunks)
    lines = data.replace(b"\r", b"\n").split(b"\n")[:-1]  # complete lines only
    expected = [ref for ln in lines if len(ln) <= MAX_LINE_BYTES and (ref := reference_parse(ln))]
    assert [(r.value, r.unit, r.stable, r.net) for r in out] == expected
    assert parser.stats.frames_ok == len(expected)


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=80))
def test_random_single_lines_parse_only_when_the_grammar_says_so(line):
    r = parse_line(line)
    ref = reference_parse(line)
    assert (r is None) == (ref is None)
    if r is not None:
        assert (r.value, r.unit, r.stable, r.net) == ref


values = st.floats(-9999.0, 9999.0, allow_nan=False).map(lambda v: round(v, 3))


@settings(max_examples=200, deadline=None)
@given(
    st.binary(max_size=60).filter(lambda b: b"\r" not in b and b"\n" not in b),
    st.lists(
        st.tuples(values, st.sampled_from(["kg", "g", "N", "lb"]), st.booleans()),
        min_size=1,
        max_size=5,
    ),
    st.integers(1, 40),
)
def test_valid_lines_after_noise_come_through_whole(noise, lines, chunk):
    stream = noise + b"\r\n" + b"".join(format_line(v, u, stable=s) for v, u, s in lines)
    parser = AsciiLineParser()
    out = []
    for i in range(0, len(stream), chunk):
        out += parser.feed(stream[i : i + chunk])
    assert [(r.value, r.unit, r.stable) for r in out] == [
        (0.0 if v == 0 else v, u, s) for v, u, s in lines
    ]


def test_reader_on_a_pty_reads_a_recording_then_fails_naming_the_port(pty_pair, open_serial):
    stream = AsciiLoadCellStream(open_serial(pty_pair.path))
    pty_pair.write(RECORDED)
    got = []
    while len(got) < len(EXPECTED):
        polled = stream.poll()
        assert all(i == 0 for i, _ in polled)
        got += [r for _, r in polled]
    assert _values(got) == EXPECTED
    pty_pair.close_master()
    with pytest.raises(SensorError) as info:
        for _ in range(100):
            stream.poll()
    assert info.value.port == pty_pair.path and pty_pair.path in str(info.value)
    with pytest.raises(SensorError, match="cannot be tared"):
        stream.tare(0)


class Truth:
    def __init__(self, value):
        self.value = value

    def __call__(self):
        return [self.value]


def test_sampler_follows_the_simulated_stream(open_serial):
    truth = Truth(20.0)
    with AsciiLoadCellSim(truth, rate_hz=500.0) as sim:
        stream = AsciiLoadCellStream(open_serial(sim.path))
        with LoadCellSampler(stream, stale_after_s=5.0) as cells:
            cells.wait_for_samples(3, timeout_s=5.0)
            (s,) = cells.latest()
            assert s.address is None and s.stable is True and not s.stale
            assert abs(s.force_N - 20.0) <= 0.5e-3 * KG
            truth.value = 2 * CAPACITY_N  # overload
            cells.wait_for_samples(s.seq + 3, timeout_s=5.0)
            (s,) = cells.latest()
            assert s.overload and s.force_N == math.inf
            truth.value = 7.0
            sim.corrupt_next(3)
            sim.inject_garbage(b"\x00\x01\x02")
            seq = cells.latest()[0].seq
            cells.wait_for_samples(seq + 6, timeout_s=5.0)
            (s,) = cells.latest()
            assert abs(s.force_N - 7.0) <= 0.5e-3 * KG
        assert stream.stats.bad_frames >= 3  # the corrupted lines, never taken as readings


def test_simulated_stream_marks_motion_unstable():
    sim = AsciiLoadCellSim(Truth(0.0), unstable_N=0.05)
    try:
        assert sim.line(10.0).startswith(b"ST,GS,+  1.020kg")  # first line: nothing to compare
        assert sim.line(10.01).startswith(b"ST")
        assert sim.line(11.0).startswith(b"US")
    finally:
        sim.stop()
