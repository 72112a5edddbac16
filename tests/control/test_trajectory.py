"""Trajectories: file loaders and their errors, interpolation, built-ins and the paper's rates."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cdcr_ctl.control import trajectory as tr
from cdcr_ctl.control.trajectory import Trajectory
from cdcr_ctl.errors import ConfigError, RigError

DEG = math.pi / 180


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


# ============================================================================ loaders, valid
CSV_OK = """# planar bend, two segments
t_s,seg1_theta_rad,seg1_phi_rad,seg2_theta_rad,seg2_phi_rad

0.0,0.0,0.0,0.0,1.5
1.0,0.25,0.0,0.1,1.5
2.5,0.5,-0.5,0.2,1.5
"""


def test_csv_loads_values_and_names_from_the_file(tmp_path):
    traj = tr.load_csv(_write(tmp_path, "bend.csv", CSV_OK), n_segments=2)
    assert traj.name == "bend" and traj.n_segments == 2 and traj.n_samples == 3
    assert traj.t_s.tolist() == [0.0, 1.0, 2.5]
    assert traj.psi[2].tolist() == [[0.5, -0.5], [0.2, 1.5]]
    assert traj.duration_s == 2.5


YAML_OK = """name: demo
n_segments: 1
samples:
  - t_s: 0.0
    segments: [[0.0, 0.0]]
  - {t_s: 2, segments: [[0.5, 1.0]]}
"""


def test_yaml_loads_mapping_and_bare_list_forms(tmp_path):
    traj = tr.load_yaml(_write(tmp_path, "a.yaml", YAML_OK), n_segments=1)
    assert traj.name == "demo"
    assert traj.t_s.tolist() == [0.0, 2.0]
    assert traj.psi[:, 0].tolist() == [[0.0, 0.0], [0.5, 1.0]]
    bare = "- {t_s: 0.5, segments: [[0.1, 0.2]]}\n- {t_s: 1.5, segments: [[0.3, 0.2]]}\n"
    traj2 = tr.load_trajectory(_write(tmp_path, "b.yml", bare))
    assert traj2.name == "b" and traj2.psi[1, 0].tolist() == [0.3, 0.2]


def test_csv_and_yaml_round_trip_exactly(tmp_path):
    traj = tr.random_smooth(2, 3.0, 1.2, 0.8, seed=11)
    for suffix in (".csv", ".yaml"):
        back = tr.load_trajectory(traj.write(tmp_path / f"t{suffix}"), n_segments=2)
        assert np.array_equal(back.t_s, traj.t_s)
        assert np.array_equal(back.psi, traj.psi)


def test_unknown_suffix_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"csv, \.yaml"):
        tr.load_trajectory(_write(tmp_path, "t.txt", CSV_OK))


def test_missing_file_names_the_file(tmp_path):
    with pytest.raises(ConfigError) as err:
        tr.load_csv(tmp_path / "nope.csv")
    assert err.value.file.endswith("nope.csv") and "cannot read" in str(err.value)


# ============================================================================ loaders, errors
H1 = "t_s,seg1_theta_rad,seg1_phi_rad\n"


@pytest.mark.parametrize(
    ("text", "kwargs", "key", "message"),
    [
        ("t_s,seg1_theta,seg1_phi_rad\n0,0,0\n", {}, "line 1, column 2", "seg1_theta_rad"),
        ("t_s,seg1_theta_rad\n0,0\n", {}, "line 1", "header must be"),
        (H1 + "0,0,0\n1,0.1,x\n", {}, "line 3, seg1_phi_rad", "not a number"),
        (H1 + "0,0,0\n1,0.1\n", {}, "line 3", "2 fields for 3 columns"),
        (H1 + "0,0,0\n1,0.1,0\n1,0.2,0\n", {}, "line 4, t_s", "(previous sample at 1.0 s)"),
        (H1 + "# c\n0,0,0\n\n1,-0.1,0\n", {}, "line 5, seg1_theta_rad", "must be >= 0"),
        (H1 + "0,0,0\n1,inf,0\n", {}, "line 3, seg1_theta_rad", "not a number"),
        (H1 + "0,0,0\n1,1e999,0\n", {}, "line 3, seg1_theta_rad", "not finite"),
        (H1 + "-1,0,0\n", {}, "line 2, t_s", ">= 0"),
        (H1 + "0,0,0\n", {"n_segments": 2}, "header", "has 1 segment(s), the rig has 2"),
        (H1 + "0,0,0\n9,1.6,0\n", {"bend_limit_rad": 1.5}, "line 3, seg1_theta_rad", "limit"),
        (H1 + "0,0,0\n1,0.5,0\n", {"max_rate_rad_s": 0.4}, "line 3, seg1_theta_rad", "rate"),
        (H1, {}, "", "no samples"),
        ("# only a comment\n", {}, "", "no header"),
    ],
)
def test_csv_errors_name_line_and_column(tmp_path, text, kwargs, key, message):
    path = _write(tmp_path, "bad.csv", text)
    with pytest.raises(ConfigError) as err:
        tr.load_csv(path, **kwargs)
    assert err.value.file == str(path)
    assert err.value.key == key
    assert message in str(err.value)


def test_csv_rate_limit_names_the_segment_that_moves_too_fast(tmp_path):
    text = "t_s,seg1_theta_rad,seg1_phi_rad,seg2_theta_rad,seg2_phi_rad\n"
    text += "0,0.3,0,0.3,0\n2,0.3,0.5,0.3,3.0\n"  # seg2 sweeps 3 rad at theta 0.3
    with pytest.raises(ConfigError) as err:
        tr.load_csv(_write(tmp_path, "r.csv", text), max_rate_rad_s=0.2)
    assert err.value.key == "line 3, seg2_theta_rad"


def test_csv_not_utf8_names_the_line(tmp_path):
    p = tmp_path / "b.csv"
    p.write_bytes(H1.encode() + b"0,0,0\n1,\xff,0\n")
    with pytest.raises(ConfigError) as err:
        tr.load_csv(p)
    assert err.value.key == "line 3"


@pytest.mark.parametrize(
    ("text", "kwargs", "key", "message"),
    [
        ("samples: [\n", {}, "line 2", "YAML syntax error"),
        ("name: x\nsampels: []\n", {}, "sampels (line 2)", "unknown key"),
        ("name: x\n", {}, "samples", "missing"),
        ("samples: []\n", {}, "samples (line 1)", "non-empty list"),
        ("samples:\n  - {t_s: 0}\n", {}, "samples[0] (line 2)", "needs t_s and segments"),
        (
            "samples:\n  - {t_s: 0, segments: [[0, 0]]}\n"
            "  - {t_s: 1, segments: [[0, 0], [1, 0]]}\n",
            {},
            "samples[1].segments (line 3)",
            "2 segment(s), the first sample says 1",
        ),
        (
            "samples:\n  - t_s: 0\n    segments:\n      - [0.1, '0.2']\n",
            {},
            "samples[0].segments[0][1] (line 4)",
            "not a finite number",
        ),
        (
            "samples:\n  - {t_s: true, segments: [[0, 0]]}\n",
            {},
            "samples[0].t_s (line 2)",
            "not a finite number",
        ),
        (
            "samples:\n  - {t_s: 0, segments: [[0, 0]]}\n  - {t_s: 1, segments: [[0.1]]}\n",
            {},
            "samples[1].segments[0] (line 3)",
            "[theta_rad, phi_rad]",
        ),
        (
            "samples:\n  - {t_s: 0, segments: [[0, 0]]}\n"
            "  - {t_s: 1,\n     segments: [[2.0, 0]]}\n",
            {"bend_limit_rad": 1.5},
            "samples[1].segments[0][0] (line 4)",
            "above the limit",
        ),
        (
            "samples:\n  - {t_s: 1, segments: [[0, 0]]}\n  - {t_s: 0.5, segments: [[0, 0]]}\n",
            {},
            "samples[1].t_s (line 3)",
            "time must increase",
        ),
        (
            "n_segments: 2\nsamples:\n  - {t_s: 0, segments: [[0, 0]]}\n",
            {},
            "samples[0].segments (line 3)",
            "n_segments says 2",
        ),
        (
            "samples:\n  - {t_s: .nan, segments: [[0, 0]]}\n",
            {},
            "samples[0].t_s (line 2)",
            "finite",
        ),
        ("- {t_s: 0, segments: [[0, 0]], x: 1}\n", {}, "[0].x (line 1)", "unknown key"),
    ],
)
def test_yaml_errors_name_field_and_line(tmp_path, text, kwargs, key, message):
    path = _write(tmp_path, "bad.yaml", text)
    with pytest.raises(ConfigError) as err:
        tr.load_yaml(path, **kwargs)
    assert err.value.file == str(path)
    assert err.value.key == key
    assert message in str(err.value)


def test_from_samples_errors_name_the_position():
    with pytest.raises(ConfigError) as err:
        tr.from_samples([[0, 0, 0], [1, float("nan"), 0]], source="request 'x'")
    assert (err.value.file, err.value.key) == ("request 'x'", "samples[1][1]")
    with pytest.raises(ConfigError, match=r"samples\[0\]: 4 values"):
        tr.from_samples([[0, 0, 0, 1]])
    with pytest.raises(ConfigError) as err:
        tr.from_samples([[0, 0, 0], [1, 0.9, 0]], n_segments=1, bend_limit_rad=0.5)
    assert err.value.key == "samples[1][1]"
    traj = tr.from_samples(np.array([[0, 0, 0], [1, 0.4, 2.0]]), n_segments=1)
    assert traj.psi[1, 0].tolist() == [0.4, 2.0]


# ============================================================================ fuzz
_TMP = st.shared(st.just(None))

TOKENS = st.sampled_from(
    [
        "t_s",
        "seg1_theta_rad",
        "seg1_phi_rad",
        "seg2_theta_rad",
        ",",
        "\n",
        "#",
        "0",
        "1.5",
        "-2",
        "1e400",
        "nan",
        "inf",
        " ",
        "\r\n",
        "x",
        "samples:",
        "- ",
        "t_s: ",
        "segments: ",
        "[[0, 0]]",
        "[",
        "]",
        "{",
        "}",
        ":",
        "&a ",
        "*a",
        "!!python/object ",
        "'",
        '"',
        "\t",
        ".inf",
        "true",
        "null",
        "n_segments: ",
        "99999999999999999999999999999999999999" * 10,
    ]
)
TEXTS = st.one_of(st.text(max_size=300), st.lists(TOKENS, max_size=60).map("".join))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=TEXTS, suffix=st.sampled_from([".csv", ".yaml"]))
def test_fuzzed_files_load_or_raise_config_error(tmp_path_factory, text, suffix):
    path = tmp_path_factory.getbasetemp() / f"fuzz{suffix}"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        traj = tr.load_trajectory(path, bend_limit_rad=2.0, max_rate_rad_s=10.0)
    except ConfigError as exc:
        assert exc.file == str(path)
    else:
        assert np.all(np.isfinite(traj.psi)) and np.all(np.diff(traj.t_s) > 0)


@settings(max_examples=100, deadline=None)
@given(
    rows=st.lists(
        st.lists(
            st.one_of(st.floats(), st.integers(), st.booleans(), st.text(max_size=3), st.none()),
            max_size=5,
        ),
        max_size=5,
    )
)
def test_fuzzed_request_samples_load_or_raise_config_error(rows):
    try:
        tr.from_samples(rows, n_segments=1, bend_limit_rad=2.0, max_rate_rad_s=10.0)
    except ConfigError as exc:
        assert exc.file == "samples"


# ============================================================================ interpolation
def _traj(rows: list[list[float]]) -> Trajectory:
    arr = np.array(rows, dtype=float)
    return Trajectory(arr[:, 0], arr[:, 1:].reshape(len(arr), -1, 2))


def test_phi_wraps_the_short_way():
    traj = _traj([[0, 0.5, 350 * DEG], [1, 0.5, 10 * DEG]])
    psi = traj.sample_many(np.linspace(0, 1, 101))[:, 0]
    # Continuous on the branch of the first sample: 350 deg -> 370 deg, never back through 180;
    # the samples themselves come back exactly as given (10 deg = 370 deg - 2 pi).
    assert np.all(np.diff(psi[:-1, 1]) > 0)
    assert psi[0, 1] == 350 * DEG and psi[-1, 1] == 10 * DEG
    assert psi[1:-1, 1].min() > 350 * DEG and psi[1:-1, 1].max() < 370 * DEG
    mid = traj.sample(0.5)[0]
    assert mid[1] == pytest.approx(2 * math.pi)
    # Chord of the bending vectors: theta dips by theta (1 - cos(dphi/2)) mid-way.
    assert mid[0] == pytest.approx(0.5 * math.cos(10 * DEG))


def test_from_straight_keeps_the_target_direction_and_theta_is_linear():
    traj = _traj([[0, 0.0, 0.0], [2, 0.4, 1.2]])
    for t in (0.5, 1.0, 1.5):
        th, ph = traj.sample(t)[0]
        assert th == pytest.approx(0.2 * t) and ph == pytest.approx(1.2)
    assert traj.sample(0.0)[0].tolist() == [0.0, 0.0]  # the sample itself


def test_passing_through_straight_flips_direction_continuously():
    # (0.3, 0) -> (0.3, pi): the bending vector passes through zero; the pose is continuous.
    traj = _traj([[0, 0.3, 0.0], [1, 0.3, math.pi]])
    assert traj.sample(0.25)[0] == pytest.approx([0.15, 0.0])
    assert traj.sample(0.5)[0, 0] == pytest.approx(0.0, abs=1e-15)
    # phi comes out on the first sample's branch (pi or -pi: the same plane).
    assert tr.bend_vectors(traj.sample(0.75))[0] == pytest.approx([-0.15, 0.0], abs=1e-15)


def test_straight_to_straight_stays_straight():
    traj = _traj([[0, 0.0, 1.0], [1, 0.0, 2.0]])
    assert traj.sample(0.3)[0].tolist() == [0.0, 1.0]
    assert traj.sample(0.7)[0].tolist() == [0.0, 2.0]


def test_holds_before_first_and_after_last_sample():
    traj = _traj([[1.0, 0.1, 0.2], [2.0, 0.3, 0.2]])
    assert traj.sample(0.0).tolist() == [[0.1, 0.2]]
    assert traj.sample(float("nan")).tolist() == [[0.1, 0.2]]
    assert traj.sample(5.0).tolist() == [[0.3, 0.2]]
    assert traj.duration_s == 2.0


@settings(max_examples=200, deadline=None)
@given(
    knots=st.lists(st.tuples(st.floats(0.0, 2.0), st.floats(-10.0, 10.0)), min_size=2, max_size=6),
    u=st.floats(0.0, 1.0),
)
def test_sample_is_the_linear_step_of_the_bending_vector(knots, u):
    t = np.arange(len(knots), dtype=float) * 0.7
    traj = Trajectory(t, np.array(knots)[:, None, :])
    tq = u * t[-1]
    got = traj.sample(tq)
    assert np.array_equal(got, traj.sample_many([tq])[0]) or np.allclose(
        got, traj.sample_many([tq])[0], rtol=0, atol=1e-12
    )
    k = min(int(tq // 0.7), len(knots) - 2)
    s = (tq - t[k]) / (t[k + 1] - t[k])
    x = traj.x[k, 0] + s * (traj.x[k + 1, 0] - traj.x[k, 0])
    assert tr.bend_vectors(got)[0] == pytest.approx(x, abs=1e-12)
    assert got[0, 0] >= 0.0


def test_sample_at_sample_times_is_exact():
    traj = tr.random_smooth(1, 2.0, 1.0, 1.0, seed=5)
    idx = [0, 7, 100, traj.n_samples - 1]
    for n in idx:
        assert np.array_equal(traj.sample(float(traj.t_s[n])), traj.psi[n])
    assert np.array_equal(traj.sample_many(traj.t_s[idx]), traj.psi[idx])


# ============================================================================ built-ins
def test_planar_bend_is_qi2023_section_5_1():
    traj = tr.planar_bend()
    # beta = phi = 0, theta 0 -> 90 deg at pi/10 rad/s: 5 s.
    assert traj.duration_s == pytest.approx(5.0)
    assert traj.max_rate_rad_s() == pytest.approx([math.pi / 10])
    for t in (0.0, 1.25, 2.5, 5.0):
        assert traj.sample(t)[0] == pytest.approx([math.pi / 10 * t, 0.0])
    back = tr.planar_bend(back=True, hold_s=1.0)
    assert back.duration_s == pytest.approx(11.0)
    assert back.sample(8.5)[0] == pytest.approx([math.pi / 4, 0.0])
    assert back.psi[-1, 0, 0] == 0.0


def test_planar_bend_per_segment_parameters():
    traj = tr.planar_bend(
        2, theta_max_rad=[math.pi / 2, math.pi / 4], rate_rad_s=[0.5, 0.1], phi_rad=[0.0, 2.0]
    )
    assert traj.duration_s == pytest.approx((math.pi / 4) / 0.1)
    assert traj.max_rate_rad_s() == pytest.approx([0.5, 0.1])
    end = traj.sample(traj.duration_s)
    assert end.ravel() == pytest.approx([math.pi / 2, 0.0, math.pi / 4, 2.0])
    assert traj.sample(1.0)[0, 0] == pytest.approx(0.5)
    with pytest.raises(RigError, match="theta_max_rad"):
        tr.planar_bend(3, theta_max_rad=[1.0, 1.0])


def test_go_and_return():
    traj = tr.go_and_return(theta_max_rad=1.0, rate_rad_s=0.5, phi_rad=0.7)
    assert traj.duration_s == pytest.approx(4.0)
    assert traj.sample(2.0)[0] == pytest.approx([1.0, 0.7])
    assert traj.sample(3.0)[0] == pytest.approx([0.5, 0.7])
    assert traj.psi[0, 0, 0] == 0.0 and traj.psi[-1, 0, 0] == 0.0
    assert traj.max_rate_rad_s() == pytest.approx([0.5])


def test_spatial_circle_sweeps_a_full_turn_at_the_given_rate():
    th, rate, lead = 0.6, 0.4, 0.3
    traj = tr.spatial_circle(theta_rad=th, phi_rate_rad_s=rate, lead_in_rate_rad_s=lead)
    T_in = math.pi * th / (2 * lead)
    T_sweep = 2 * math.pi / rate
    assert traj.duration_s == pytest.approx(2 * T_in + T_sweep)
    t = np.linspace(T_in, T_in + T_sweep, 997)
    psi = traj.sample_many(t)[:, 0]
    assert psi[:, 0] == pytest.approx(np.full(t.size, th), rel=1e-4)  # chord dip only
    assert np.diff(psi[:, 1]) / np.diff(t) == pytest.approx(np.full(t.size - 1, rate), rel=1e-3)
    assert psi[-1, 1] - psi[0, 1] == pytest.approx(2 * math.pi)
    # Smooth lead-in from straight: zero rate at the start, peak at the lead-in rate.
    assert traj.psi[0, 0, 0] == 0.0
    assert traj.sample(0.01)[0, 0] < 1e-3 * th
    rates = np.abs(np.diff(traj.psi[:, 0, 0])) / np.diff(traj.t_s)
    assert rates[traj.t_s[1:] <= T_in].max() == pytest.approx(lead, rel=1e-3)
    assert traj.max_rate_rad_s()[0] <= max(lead, th * rate) * (1 + 1e-9)
    assert traj.psi[-1, 0, 0] == 0.0
    traj.validate(1, bend_limit_rad=th, max_rate_rad_s=max(lead, th * rate))


def test_spatial_circle_per_segment():
    traj = tr.spatial_circle(2, theta_rad=[0.5, 0.0], phi_rate_rad_s=[0.5, 0.5], lead_out=False)
    assert np.all(traj.psi[:, 1, 0] == 0.0)
    assert traj.psi[-1, 0] == pytest.approx([0.5, 2 * math.pi])


def test_random_smooth_is_seeded_and_within_limits():
    a = tr.random_smooth(2, 20.0, [1.0, 0.5], 0.4, seed=1)
    b = tr.random_smooth(2, 20.0, [1.0, 0.5], 0.4, seed=1)
    c = tr.random_smooth(2, 20.0, [1.0, 0.5], 0.4, seed=2)
    assert np.array_equal(a.psi, b.psi) and not np.array_equal(a.psi, c.psi)
    a.validate(2, bend_limit_rad=[1.0, 0.5], max_rate_rad_s=0.4)
    assert np.all(a.psi[[0, -1], :, 0] == 0.0)  # starts and ends straight
    peak = a.psi[..., 0].max(axis=0)
    assert np.all(peak <= [0.9, 0.45]) and np.any(
        np.isclose(peak, [0.9, 0.45]) | np.isclose(a.max_rate_rad_s(), 0.36)
    )


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    limit=st.floats(0.05, 3.0),
    rate=st.floats(0.01, 5.0),
    duration=st.floats(0.5, 20.0),
)
def test_random_smooth_always_validates(seed, limit, rate, duration):
    traj = tr.random_smooth(1, duration, limit, rate, seed=seed)
    traj.validate(1, bend_limit_rad=limit, max_rate_rad_s=rate)


def test_move_and_lead_in():
    m = tr.move([[0.2, 1.0]], [[0.5, -1.0]], speed_rad_s=0.3)
    assert m.psi[0].tolist() == [[0.2, 1.0]] and m.psi[-1].tolist() == [[0.5, -1.0]]
    dist = np.linalg.norm(
        tr.bend_vectors(np.array([0.5, -1.0])) - tr.bend_vectors(np.array([0.2, 1.0]))
    )
    assert m.duration_s == pytest.approx(math.pi * dist / (2 * 0.3))
    assert m.max_rate_rad_s()[0] == pytest.approx(0.3, rel=1e-3)
    assert tr.move([[0.1, 0.0]], [[0.1, 0.0]]).duration_s == 0.0

    traj = tr.planar_bend()
    assert tr.with_lead_in([[0.0, 0.0]], traj) is traj
    led = tr.with_lead_in([[0.3, 2.0]], traj, speed_rad_s=0.5)
    T = math.pi * 0.3 / (2 * 0.5)
    assert led.duration_s == pytest.approx(T + traj.duration_s)
    assert led.psi[0].tolist() == [[0.3, 2.0]]
    assert led.sample(T + 2.5) == pytest.approx(traj.sample(2.5))
    assert led.max_rate_rad_s()[0] <= 0.5 * (1 + 1e-6)
    with pytest.raises(RigError, match="segment"):
        tr.with_lead_in([[0.0, 0.0], [0.0, 0.0]], traj)


def test_rows_are_the_daemon_request_form():
    traj = tr.planar_bend(2, theta_max_rad=[1.0, 0.5])
    again = tr.from_samples(traj.rows(), n_segments=2)
    assert np.array_equal(again.psi, traj.psi) and np.array_equal(again.t_s, traj.t_s)


def test_sample_is_the_same_on_the_list_path_and_the_array_path(monkeypatch):
    """A trajectory up to LIST_SAMPLES samples keeps flat Python lists for the loop's sample()
    (made a slice at a time, issue #21); a longer one samples its arrays. Both paths do the same
    float64 operations in the same order, so they agree to rounding (1e-12 rad is far above
    float64 rounding of angles of order 1 and far below any pose change that matters)."""
    core = tr.core

    rng = np.random.default_rng(3)
    n = 3 * core.TOLIST_SLICE + 7  # several slices and a partial one
    t = np.cumsum(rng.uniform(0.001, 0.01, n))
    psi = np.stack((rng.uniform(0, 1.2, (n, 2)), rng.uniform(-3, 3, (n, 2))), axis=-1)
    psi[5, 1, 0] = 0.0  # a straight sample
    listed = Trajectory(t, psi)
    monkeypatch.setattr(core, "LIST_SAMPLES", 10)
    arrays = Trajectory(t, psi)
    assert isinstance(listed._xl, list) and not isinstance(arrays._xl, list)
    assert listed._xl == arrays._x.reshape(-1).tolist()
    for q in np.concatenate((rng.uniform(t[0] - 1, t[-1] + 1, 500), t[:20], [t[5] + 1e-4])):
        np.testing.assert_allclose(listed.sample(q), arrays.sample(q), rtol=0, atol=1e-12)
