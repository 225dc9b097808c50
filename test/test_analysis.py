"""Summarize / plot / CLI entry points on a real MCAP with known signals."""

from __future__ import annotations

from pathlib import Path

from pulsejet_sim import analysis
from pulsejet_sim.bag.writer import BagWriter
from pulsejet_sim.core.model_io import Command, Observation
from pulsejet_sim.ros import messages
from pulsejet_sim.ros.bag_messages import write_message
import pytest

DT_S = 0.01
DURATION_S = 2.0
SPEED_M_S = 0.5  # constant -> distance 1.0 m over 2 s
THRUST_N = 2.0  # for the first 1 s, then 0 -> impulse 2.0 N s (+ half a step of ramp)


def observation(t: float) -> Observation:
    return Observation(
        time_s=t,
        position_m=SPEED_M_S * t,
        velocity_m_s=SPEED_M_S,
        acceleration_m_s2=0.0,
        mantle_radius_m=0.05 + 0.01 * t,
        volume_m3=1e-4 * (1.0 + t),
        fluid_mass_kg=0.1 + 0.05 * t,
        thrust_n=THRUST_N if t <= 1.0 + 1e-9 else 0.0,
        added_mass_force_n=0.0,
        drag_n=0.0,
        jet_speed_m_s=0.0,
        cavity_pressure_pa=0.0,
        pump_flow_m3_s=0.0,
        valve_opening=1.0,
    )


@pytest.fixture(scope='module')
def run_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('analysis') / 'run.mcap'
    n = round(DURATION_S / DT_S)
    with BagWriter(path) as bag:
        for i in range(n + 1):
            t = i * DT_S
            log_ns = messages.stamp_ns(t)
            for topic, msg in messages.observation_messages(
                observation(t)
            ) + messages.command_messages(Command()):
                write_message(bag, topic, msg, log_ns)
            if i % 50 == 0:
                ledger = {
                    'stored_elastic': 0.1 * t,
                    'in_actuation_work': 0.2 * t,
                    'closure_error': 0.0,
                    'closure_relative': 0.0 if t < 1.5 else 0.08,
                }
                write_message(
                    bag, 'pulsejet/energy_ledger', messages.ledger_message(ledger, t), log_ns
                )
    return path


def test_summary_numbers(run_file: Path) -> None:
    s = analysis.summarize(run_file)
    assert s['duration_s'] == pytest.approx(DURATION_S)
    assert s['distance_m'] == pytest.approx(SPEED_M_S * DURATION_S, abs=1e-9)
    assert s['peak_speed_m_s'] == pytest.approx(SPEED_M_S)
    assert s['mean_speed_m_s'] == pytest.approx(SPEED_M_S)
    assert s['thrust_impulse_n_s'] == pytest.approx(THRUST_N * 1.0, abs=THRUST_N * DT_S)
    assert s['fluid_mass_min_kg'] == pytest.approx(0.1) and s[
        'fluid_mass_max_kg'
    ] == pytest.approx(0.2)
    n = round(DURATION_S / DT_S) + 1
    assert s['message_counts']['/pulsejet/velocity'] == n and s['message_counts']['/clock'] == n
    assert s['message_counts']['/pulsejet/energy_ledger'] == 5
    assert s['energy_ledger_j'] == {
        'stored_elastic': pytest.approx(0.2),
        'in_actuation_work': pytest.approx(0.4),
        'closure_error': 0.0,
        'closure_relative': 0.08,
    }
    assert s['energy_ledger_level'] == 'WARN'
    assert not s['truncated']
    assert (
        s['real_time_factor'] != s['real_time_factor']
    )  # NaN: offline, log time is simulation time


def test_format_summary_has_units(run_file: Path) -> None:
    text = analysis.format_summary(analysis.summarize(run_file))
    for fragment in (
        'distance travelled',
        '1 m',
        'thrust impulse',
        'N s',
        'peak speed',
        '0.5 m/s',
        'fluid mass max',
        'kg',
        '/pulsejet/velocity',
        'final energy ledger (WARN)',
        'stored_elastic',
    ):
        assert fragment in text


def test_plot_writes_png_next_to_file(run_file: Path, tmp_path: Path) -> None:
    png = analysis.plot(run_file)
    assert png == run_file.with_suffix('.png')
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 10_000
    out = tmp_path / 'sub' / 'x.png'
    assert analysis.main_plot([str(run_file), '--out', str(out)]) == 0
    assert out.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_main_summary_ok(run_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert analysis.main_summary([str(run_file)]) == 0
    assert 'thrust impulse' in capsys.readouterr().out


@pytest.mark.parametrize('kind', ['missing', 'not_mcap', 'no_pulsejet_topics', 'directory'])
@pytest.mark.parametrize('entry', ['summary', 'plot'])
def test_bad_input_one_line_error_exit_2(
    kind: str, entry: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / 'bad.mcap'
    if kind == 'not_mcap':
        path.write_text('this is not an mcap file\n')
    elif kind == 'no_pulsejet_topics':
        with BagWriter(path) as bag:
            write_message(
                bag, 'other/topic', messages.message_class('pulsejet/volume')(data=1.0), 0
            )
    elif kind == 'directory':
        path.mkdir()
    main = analysis.main_summary if entry == 'summary' else analysis.main_plot
    assert main([str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'Traceback' not in err
    assert str(path) in err and 'expected' in err


def test_real_time_factor_of_a_live_recording(tmp_path: Path) -> None:
    """
    A live recording has a real-time factor; an offline one has none.

    A live recording logs wall time: 2 s simulated over 4 s of (epoch) wall time is a factor 0.5;
    an offline one (log time = simulation time) has none.
    """
    path = tmp_path / 'live.mcap'
    wall0_ns = 1_800_000_000 * 10**9
    with BagWriter(path) as bag:
        for i in range(round(DURATION_S / DT_S) + 1):
            t = i * DT_S
            for topic, msg in messages.observation_messages(observation(t)):
                write_message(bag, topic, msg, wall0_ns + round(2 * t * 1e9))
    assert analysis.summarize(path)['real_time_factor'] == pytest.approx(0.5)
    assert 'real-time factor    0.5' in analysis.format_summary(analysis.summarize(path))


def test_plots_leave_the_callers_matplotlib_alone(run_file: Path, tmp_path: Path) -> None:
    """
    The plot functions draw on Figures of their own and leave pyplot alone.

    analysis.plot, sweep.plot_bars draw on Figures of their own: the caller's backend stays and
    no pyplot figure is left open.
    """
    import matplotlib
    import matplotlib.pyplot as plt
    from pulsejet_sim.studies.sweep import plot_bars, RunRow

    matplotlib.use('svg')
    try:
        before = len(plt.get_fignums())
        assert analysis.plot(run_file, tmp_path / 'a.png').stat().st_size > 0
        row = RunRow(name='s/x', study='s', labels={'x': 'a'}, metrics={'peak_speed_m_s': 1.0})
        assert plot_bars([row], 'peak_speed_m_s', tmp_path / 'b.png').stat().st_size > 0
        assert matplotlib.get_backend() == 'svg' and len(plt.get_fignums()) == before
    finally:
        matplotlib.use('agg')
