"""The report and help, read closely: round-off shown as 0, base names without round-off terms, every --help
without Python reprs, the validation figure's title above its panels naming what they hold."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ineid.report.roundoff import ROUND_OFF_TEXT, is_round_off, shown_value


def test_round_off_is_shown_as_zero_and_a_small_real_value_is_not():
    # an inertia (scale 1e-3 kg*m^2) of 9.4e-17 with std 2e-5: round-off; 3e-9 is a number (tiny, but above it)
    assert shown_value(9.4e-17, 1e-3, 2e-5) == ROUND_OFF_TEXT
    assert shown_value(-3e-16, 1.0) == ROUND_OFF_TEXT
    assert shown_value(3e-9, 1e-3, 2e-5) == "3e-09"
    assert shown_value(0.0, 1.0) == "0" and shown_value(math.nan, 1.0) == "-"
    assert not is_round_off(1e-17, math.nan) and is_round_off(1e-17, math.nan, 1e-3)  # no scale: the std judges


def test_the_report_and_the_summary_show_a_round_off_estimate_as_zero(run, tmp_path, capsys):
    """An estimate at floating-point noise (9.4e-17, as the solvers leave a parameter the data pin at zero) is
    shown as 0 (round-off) in the report's table and in the summary of a recording (no truth), its neighbours
    as numbers."""
    from ineid.cli.output import print_results
    from ineid.identify import load_results
    from ineid.report import sections

    data, out = tmp_path / "d.h5", tmp_path / "r.h5"
    r = run("-q", "data", "generate", "--n-configs", 1, "--n-frames", 40, "--out", data)
    assert r.exit_code == 0, r.output
    r = run("-q", "solve", data, "--backend", "casadi", "--out", out)
    assert r.exit_code == 0, r.output
    res = load_results(out)
    res.theta_hat[0, 1] = 9.4e-17
    rows = sections.estimates_section(res, 0)["rows"]
    assert rows[1]["estimate"] == ROUND_OFF_TEXT and rows[0]["estimate"] == f"{res.theta_hat[0, 0]:.4g}"
    res.theta_true = None
    capsys.readouterr()
    print_results(res, out)
    printed = capsys.readouterr().out
    line = next(x for x in printed.splitlines() if f" {res.param_names[1]} " in x)
    assert ROUND_OFF_TEXT in line and "e-17" not in printed


def test_base_names_leave_out_round_off_terms_and_keep_the_numbers():
    from ineid.identify.identifiability import NAME_RTOL, base_parameters_from_regressor

    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(50, 1)), rng.normal(size=(50, 1))
    names = ("p0", "p1", "p2")
    for tiny, named in ((5e-8, False), (3e-5, True)):
        # column 2 = column 0 + tiny * column 1: one dependent parameter, moving base parameter 1 by `tiny`
        w = np.hstack([a, b, a + tiny * b])
        base = base_parameters_from_regressor(w, names, np.ones(3))
        assert base.names[0] == "p0 + p2"
        assert base.names[1] == (f"p1 + {tiny:.4g}*p2" if named else "p1"), base.names
        assert base.B[1, 2] == pytest.approx(tiny, rel=1e-6)  # the numbers keep the term
        assert (tiny >= NAME_RTOL) == named


def _all_help():
    """``(command path, --help text)`` of every ineid command and group."""
    import click
    from click.testing import CliRunner

    from ineid.cli import main

    runner, out = CliRunner(), []

    def walk(cmd, path):
        r = runner.invoke(main, [*path, "--help"], terminal_width=200)
        assert r.exit_code == 0, (path, r.output)
        out.append((" ".join(path), r.output))
        if isinstance(cmd, click.Group):
            for name, sub in cmd.commands.items():
                walk(sub, [*path, name])

    walk(main, [])
    return out


def test_no_help_text_shows_a_python_repr_or_markup():
    texts = _all_help()
    assert len(texts) > 20
    for path, text in texts:
        for bad in ("None", "x<=None", "``", ":func:", ":class:", "9223372036854775807"):
            assert bad not in text, (path, bad)
    gravity = dict(texts)["data generate"]
    assert "--gravity GX GY GZ|standard" in gravity and "0 0 -9.80665" in gravity and "0 0 -9.81" in gravity


def test_the_validation_figure_names_what_it_shows_above_its_panels():
    from ineid.report.figures import validation_figure
    from ineid.report.plot import Validation

    n, axes = 40, ("shoulder_pitch", "elbow")
    t = np.arange(n) * 0.01
    y = np.column_stack([np.sin(t), np.cos(t)])
    v = Validation(
        t,
        y,
        y + 1e-3,
        np.full(2, 1e-3),
        True,
        0,
        "base",
        axes,
        ("N*m", "N*m"),
        series=True,
        blocks=(("tau", 0, 2, "joint_torque"),),
        source="held-out frames",
    )
    fig = validation_figure(v, title="a robot with a long name that takes room, linear: ")
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    title = fig._suptitle
    words = " ".join(title.get_text().split())
    assert "configuration 0: joint torques 'tau' (whole span)" in words and " frame " not in words
    box = title.get_window_extent(renderer)
    for ax in fig.axes:
        for text in (ax.title, ax.yaxis.label):
            other = text.get_window_extent(renderer)
            assert not box.overlaps(other) or not text.get_text(), text.get_text()
        assert box.y0 >= ax.get_window_extent(renderer).y1
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_fitted_channels_and_rms_lines_of_each_kind():
    from ineid.report.fitted import fitted_channels, held_out_error_name, rms_lines

    old = {}  # a file of ineid 0.1 records no channels: the base wrench
    assert fitted_channels(old) == "base wrench 'wrench'" and "wrench error" in held_out_error_name(old)
    current = {"channels": [{"kind": "motor_current", "key": "current"}]}
    assert fitted_channels(current) == "motor currents 'current'"
    assert held_out_error_name(current).startswith("relative error of motor currents 'current'")
    assert rms_lines(current, ("j1", "j2"), ("A", "A"), np.array([0.5, np.nan])) == [
        "motor currents 'current' (A): j1 0.5, j2 -"
    ]
    mixed = {"channels": [{"kind": "wrench", "key": "wrench"}, {"kind": "link_wrench", "key": "w2", "link": "hand"}]}
    axes = ("wrench.fx", "wrench.mz", "w2.fx", "extra")
    lines = rms_lines(mixed, axes, ("N", "N*m", "N", "N"), np.array([1.0, 2.0, 3.0, 4.0]))
    assert lines == [
        "base wrench 'wrench': fx 1 N, mz 2 N*m",
        "wrench at link 'hand' 'w2' (N): fx 3",
        "other axes (N): extra 4",
    ]
