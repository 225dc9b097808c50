"""
Mantle profiles of a real (short) shell run.

Cycle snapshots, the plot's snapshot panel, and `pulsejet animate` (GIF frames, bad input).
"""

from __future__ import annotations

import math
from pathlib import Path
import shutil

import numpy as np
from PIL import Image
from pulsejet_sim import analysis, cli
from pulsejet_sim.analysis import profiles
from pulsejet_sim.bag.reader import BagInfo, load_series
from pulsejet_sim.bag.writer import BagWriter
from pulsejet_sim.core.model_io import Command
from pulsejet_sim.ros import messages
from pulsejet_sim.ros.bag_messages import write_message
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.runner import run_scene
import pytest

SHELL_S = 0.7  # shell_robot pulls at 1.6 Hz: 0.7 s holds the whole cycle [0, 0.625] s
PERIOD_S = 1.0 / 1.6
PUBLISH_DT_S = 0.01  # 100 Hz publication: 71 profiles over 0.7 s


@pytest.fixture(scope='module')
def shell_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('profiles') / 'shell.mcap'
    result = run_scene(load_scene('shell_robot'), SHELL_S, path)
    assert result.fault is None
    return path


@pytest.fixture(scope='module')
def lumped_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('profiles') / 'lumped.mcap'
    run_scene(load_scene('pump_cycle'), 0.1, path)
    return path


def test_snapshots_span_one_cycle(shell_file: Path) -> None:
    info = BagInfo(shell_file)
    series = load_series(shell_file, info=info)
    period_s, origin_s, source = profiles.cycle_period(shell_file, series, info)
    assert (period_s, origin_s, source) == (pytest.approx(PERIOD_S), 0.0, 'scene')
    read = profiles.read_profiles(shell_file)
    assert (
        len(read) == round(SHELL_S / PUBLISH_DT_S) + 1 and read.topic == '/pulsejet/mantle_profile'
    )
    cycle = profiles.last_cycle(read.time_s[0], read.time_s[-1], period_s, origin_s, source)
    assert cycle.complete and (cycle.start_s, cycle.end_s) == (
        pytest.approx(0.0),
        pytest.approx(PERIOD_S),
    )
    chosen = profiles.snapshot_indices(read.time_s, cycle, 8)
    times = read.time_s[chosen]
    assert len(chosen) == 8 and np.all(np.diff(times) > 0)
    assert times[0] == pytest.approx(0.0) and times[-1] == pytest.approx(
        7 / 8 * PERIOD_S, abs=PUBLISH_DT_S
    )
    assert np.allclose(np.diff(times), PERIOD_S / 8, atol=PUBLISH_DT_S)
    # the snapshots differ: the cable squeezes the mantle and lets it go within the cycle
    radii = np.array(
        [read.radius_m[i].max() - read.radius_m[i][len(read.radius_m[i]) // 2] for i in chosen]
    )
    assert np.ptp(radii) > 1e-3


def test_period_from_the_radius_signal_and_partial_cycle() -> None:
    time_s = np.arange(0.0, 3.0, 0.01)
    radius_m = 0.02 + 0.001 * np.sin(2 * math.pi * 1.6 * time_s) + 0.0005 * time_s  # drifting
    assert profiles.radius_period_s(time_s, radius_m) == pytest.approx(PERIOD_S, abs=0.01)
    assert profiles.radius_period_s(time_s, np.full_like(time_s, 0.02)) is None
    # without a known origin: the last period; shorter than a period: what there is, marked partial
    last = profiles.last_cycle(0.0, 3.0, PERIOD_S, None)
    assert (last.start_s, last.end_s, last.complete) == (pytest.approx(3.0 - PERIOD_S), 3.0, True)
    short = profiles.last_cycle(0.0, 0.4, 1.0, 0.0)
    assert (short.start_s, short.end_s, short.complete) == (0.0, 0.4, False)


def test_plot_has_the_snapshot_panel(shell_file: Path, tmp_path: Path) -> None:
    fig = analysis.plot_figure(shell_file)
    panel = [ax for ax in fig.axes if ax.get_label() == analysis.SNAPSHOT_AXES_LABEL]
    assert len(fig.axes) == 5 and len(panel) == 1
    ax = panel[0]
    lines = [line for line in ax.get_lines() if line.get_gid() == 'mantle snapshot']
    assert len(lines) == 8
    assert ax.get_aspect() == 1.0 and 'mm' in ax.get_xlabel() and 'mm' in ax.get_ylabel()
    # mm: the mantle is 16 cm long and 21.9 mm in radius
    z_mm = np.concatenate([line.get_xdata() for line in lines])
    r_mm = np.concatenate([line.get_ydata() for line in lines])
    assert 155 < z_mm.max() < 175 and 20 < r_mm.max() < 23
    assert len({line.get_color() for line in lines}) == 8  # one colour per phase
    legend = [text.get_text() for text in ax.get_legend().get_texts()]
    assert legend[0].startswith('0.000 s') and len(legend) == 8
    # the PNG the CLI writes is the taller figure with the panel
    png = tmp_path / 'shell.png'
    assert cli.main(['plot', str(shell_file), '--out', str(png)]) == 0
    with Image.open(png) as image:
        assert image.size == (900, 1200)


def test_lumped_plot_is_unchanged(lumped_file: Path) -> None:
    fig = analysis.plot_figure(lumped_file)
    assert len(fig.axes) == 4 and tuple(fig.get_size_inches()) == (8, 9)
    assert not any(ax.get_label() == analysis.SNAPSHOT_AXES_LABEL for ax in fig.axes)


def _frame(path: Path, k: int) -> np.ndarray:
    with Image.open(path) as image:
        image.seek(k)
        return np.asarray(image.convert('RGB'), dtype=int)


def test_animate_writes_gif_frames(
    shell_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gif = tmp_path / 'clip.gif'
    assert (
        cli.main(['animate', str(shell_file), '-o', str(gif), '--fps', '10', '--stride', '7']) == 0
    )
    assert str(gif) in capsys.readouterr().out
    with Image.open(gif) as image:
        assert image.n_frames == math.ceil(71 / 7) and image.info['duration'] == 100
    # the mantle moves: frames differ below the title (the time in the title changes anyway)
    first, squeezed = _frame(gif, 0), _frame(gif, 4)  # t = 0 and t = 0.28 s (most squeezed)
    body = slice(first.shape[0] // 8, None)
    assert np.count_nonzero(np.any(first[body] != squeezed[body], axis=2)) > 500
    # default stride: about real time at --fps (20 fps of 0.01 s profiles -> every 5th), in a
    # window
    window = tmp_path / 'window.gif'
    assert (
        profiles.main_animate(
            [str(shell_file), '-o', str(window), '--fps', '20', '--start', '0.1', '--end', '0.5']
        )
        == 0
    )
    with Image.open(window) as image:
        assert image.n_frames == math.ceil(41 / 5) and image.info['duration'] == 50


def test_animate_refuses_bad_input(
    shell_file: Path, lumped_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    assert profiles.main_animate([str(lumped_file)]) == 2
    err = capsys.readouterr().err
    assert (
        repr(str(lumped_file)) in err
        and 'lumped' in err
        and 'allowed: a shell-model recording' in err
    )
    bare = tmp_path / 'no_profiles.mcap'
    with BagWriter(bare) as bag:
        for topic, msg in messages.command_messages(Command()):
            write_message(bag, topic, msg, 0)
    assert profiles.main_animate([str(bare)]) == 2
    err = capsys.readouterr().err
    assert repr(str(bare)) in err and 'holds no pulsejet/mantle_profile' in err
    assert profiles.main_animate([str(shell_file), '-o', str(tmp_path / 'x.avi')]) == 2
    err = capsys.readouterr().err
    assert "'.avi'" in err and '.gif, .mp4' in err
    assert profiles.main_animate([str(shell_file), '--start', '0.5', '--end', '0.2']) == 2
    assert '--start 0.5 >= --end 0.2' in capsys.readouterr().err
    assert profiles.main_animate([str(shell_file), '--start', '5', '--end', '6']) == 2
    assert '0.000-0.700 s' in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        profiles.main_animate([str(shell_file), '--fps', '0'])
    assert exit_info.value.code == 2 and "--fps: '0' rejected" in capsys.readouterr().err
    if shutil.which('ffmpeg') is None:
        assert profiles.main_animate([str(shell_file), '-o', str(tmp_path / 'x.mp4')]) == 2
        assert 'ffmpeg' in capsys.readouterr().err
    assert not list(tmp_path.glob('x.*'))
