"""samples.csv's direct join (formats.csv_line) writes what the csv module writes, or defers."""

from __future__ import annotations

import csv
import io

from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.runlog.writer.formats import _cell, csv_line

FIELD = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(_cell),
    st.integers().map(_cell),
    st.text(alphabet=st.sampled_from(list("ab ,\"\r\n\t\x00;'é")), max_size=6),
    st.just(""),
)


def _csv_module(cells: list[str]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue()


@settings(max_examples=2000, deadline=None)
@given(st.lists(FIELD, max_size=6))
def test_direct_join_is_the_csv_modules_line(cells):
    line = csv_line(cells)
    if line is not None:
        assert line == _csv_module(cells)


def test_float_rows_take_the_direct_join():
    cells = [_cell(v) for v in (0.1, -2.5e-300, float("inf"), float("nan"), 3, None)]
    assert csv_line(cells) == _csv_module(cells) == "0.1,-2.5e-300,inf,,3,\n"
    assert csv_line([""]) is None and csv_line(["a,b", "c"]) is None
