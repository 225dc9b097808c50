"""
`pulsejet fit`: known parameters recovered, bad fit files refused, calibration kept.

`pulsejet fit`: recovers known parameters from a synthetic recording (a real MCAP written by the
project's writer and read back) and from target figures; refuses bad fit files naming the key;
the calibrated robot scene swims as docs/validation/calibration.md reports. Real runner, no mocks.
"""

from pathlib import Path

from pulsejet_sim.cli import main as cli_main
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies import fit
from pulsejet_sim.studies.runner import run_scene
import pytest
import yaml

TRUTH = {'material.stiffness_n_m': 1500.0, 'fluid.drag_coefficient': 0.25}  # pump_cycle: 2094, 0.1
START = {k: 1.3 * v for k, v in TRUTH.items()}  # +30 %
BOUNDS = {'material.stiffness_n_m': (500.0, 5000.0), 'fluid.drag_coefficient': (0.02, 1.0)}
ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    """4 s of the lumped pump/valve scene at the true values: inflation, hold and most of a jet."""
    out = tmp_path_factory.mktemp('fit') / 'truth.mcap'
    scene = load_scene('pump_cycle', fit.dotted_overrides(TRUTH))
    result = run_scene(scene, 4.0, out)
    assert result.fault is None
    return out


def write_fit(path: Path, body: dict) -> Path:
    path.write_text(yaml.safe_dump(body, sort_keys=False))
    return path


def parameters(start=START, **extra):
    return {k: dict(low=BOUNDS[k][0], high=BOUNDS[k][1], initial=start[k], **extra) for k in TRUTH}


@pytest.mark.timeout(120)
def test_recovers_parameters_from_a_synthetic_recording(recording, tmp_path):
    path = write_fit(
        tmp_path / 'rec.yaml',
        {'scene': 'pump_cycle', 'parameters': parameters(), 'recording': {'file': recording.name}},
    )
    (tmp_path / recording.name).symlink_to(recording)  # relative to the fit file
    spec = fit.load_fit(path)
    assert spec.duration_s == pytest.approx(4.0)
    assert len(spec.recorded['velocity'][0]) == 401 and len(spec.recorded['volume'][0]) == 401
    res = fit.run_fit(spec)
    for key, truth in TRUTH.items():
        assert res.fitted[key] == pytest.approx(truth, rel=0.02), (key, res.fitted[key])
        assert res.initial[key] == pytest.approx(1.3 * truth)
    assert res.cost < 1e-6 * res.cost_initial
    ident = res.sensitivity['fit']
    assert not ident['not_identifiable'] and ident['condition_number'] < 1e3
    paths = fit.write_results(res, tmp_path / 'out')
    stored = yaml.safe_load(paths['results'].read_text())
    assert stored['mode'] == 'recording' and stored['simulator_runs'] == res.runs
    assert [p['key'] for p in stored['parameters']] == list(TRUTH)
    scene = yaml.safe_load(paths['scene'].read_text())
    assert scene['material']['stiffness_n_m'] == pytest.approx(1500.0, rel=0.02)
    assert scene['fluid']['drag_coefficient'] == pytest.approx(0.25, rel=0.02)
    assert (
        '# The vehicle of paper 001' in paths['scene'].read_text()
    )  # the scene's comments are kept
    load_scene(paths['scene'])  # and it is a valid scene
    assert 'identifiable' in paths['report'].read_text()


@pytest.mark.timeout(120)
def test_recovers_parameters_from_target_figures(tmp_path):
    base = {'scene': 'pump_cycle', 'duration_s': 4.0, 'figures': {'start_s': 0.0, 'end_s': 4.0}}
    probe = fit.load_fit(
        write_fit(
            tmp_path / 'probe.yaml',
            dict(base, parameters=parameters(TRUTH), targets={'mean_speed_m_s': 1.0}),
        )
    )
    truth = fit.figures(probe, fit.simulate(probe, TRUTH))
    targets = {
        name: {'value': truth[name], 'tolerance': 0.01}
        for name in ('mean_speed_m_s', 'burst_speed_m_s', 'stroke_volume_m3')
    }
    spec = fit.load_fit(
        write_fit(
            tmp_path / 'targets.yaml',
            dict(
                base,
                parameters=parameters(),
                targets=targets,
                predict={'peak_thrust_n': {'value': 1.0}},
            ),
        )
    )
    res = fit.run_fit(spec)
    for key, value in TRUTH.items():
        assert res.fitted[key] == pytest.approx(value, rel=0.02), (key, res.fitted[key])
    figs = res.as_dict()['figures']
    assert {n for n, f in figs.items() if f['role'] == 'fitted'} == set(targets)
    assert figs['peak_thrust_n']['role'] == 'predicted'
    table = res.sensitivity['figures']
    assert set(table) == set(fit.FIGURES)
    # a stiffer shell empties further within the window: the stroke grows with the stiffness
    assert table['stroke_volume_m3']['material.stiffness_n_m'] > 0


BAD = [
    ({'bogus': 1}, 'bogus: unknown key'),
    (
        {'parameters': {'fluid.drag_coefficient': {'low': 1.0, 'high': 0.5}}},
        'parameters.fluid.drag_coefficient: bounds',
    ),
    (
        {'parameters': {'fluid.nothing': {'low': 0.1, 'high': 1.0}}},
        'parameters.fluid.nothing: not found',
    ),
    (
        {'parameters': {'options.energy_model': {'low': 0.1, 'high': 1.0}}},
        'parameters.options.energy_model',
    ),
    (
        {'parameters': {'fluid.drag_coefficient': {'low': 0.1, 'high': 1.0, 'initial': 5.0}}},
        'parameters.fluid.drag_coefficient.initial: 5.0',
    ),
    (
        {'parameters': {'fluid.drag_coefficient': {'low': 0.1, 'hi': 1.0}}},
        'parameters.fluid.drag_coefficient.hi',
    ),
    ({'recording': 'missing.mcap', 'targets': None}, 'recording.file'),
    ({'targets': {'top_speed': 1.0}}, 'targets.top_speed: unknown figure'),
    (
        {'targets': {'mean_speed_m_s': {'value': 0.1, 'sigma': -1}}},
        'targets.mean_speed_m_s.sigma: -1',
    ),
    ({'scene': 'no_such_scene'}, 'scene:'),
]


@pytest.mark.parametrize('change,message', BAD, ids=[m.split(':')[0] for _, m in BAD])
def test_bad_fit_files_are_refused_naming_the_key(tmp_path, capsys, change, message):
    body = {
        'scene': 'pump_cycle',
        'parameters': {'fluid.drag_coefficient': {'low': 0.02, 'high': 1.0}},
        'targets': {'mean_speed_m_s': 0.1},
        'figures': {'start_s': 0.0, 'end_s': 2.0},
        'duration_s': 2.0,
    }
    body.update(change)
    body = {k: v for k, v in body.items() if v is not None}
    path = write_fit(tmp_path / 'bad.yaml', body)
    with pytest.raises(fit.FitError, match=None) as err:
        fit.load_fit(path)
    assert message in str(err.value), str(err.value)
    assert cli_main(['fit', str(path)]) == 2
    assert message in capsys.readouterr().err


def test_cli_refuses_a_missing_fit_file(capsys):
    assert cli_main(['fit', 'no/such/fit.yaml']) == 2
    assert 'not found' in capsys.readouterr().err


def test_robot_fit_file_is_valid():
    spec = fit.load_fit('shell_robot')
    assert [q.key for q in spec.varied] == ['fluid.drag_coefficient', 'actuation.amplitude']
    assert fit.window_of(spec) == pytest.approx((15.0, 20.0))


@pytest.mark.timeout(300)
def test_calibrated_robot_swims_within_30_percent_of_the_measured_speeds():
    """
    The shipped scene at its own resolution, over the fit's window.

    The window: [15, 20] s of a 20 s run.
    """
    stored = yaml.safe_load(
        (
            ROOT / 'benchmarks' / 'results' / 'calibration' / 'calibrated_scene_figures.yaml'
        ).read_text()
    )
    spec = fit.load_fit('shell_robot')
    spec.scene = str(ROOT / 'config' / 'shell_robot_calibrated.yaml')
    figs = fit.figures(spec, fit.simulate(spec, {}))  # the scene's own values, no override
    for name, value in stored['figures'].items():  # what docs/validation/calibration.md reports
        assert figs[name] == pytest.approx(value, rel=1e-3), name
    assert abs(figs['mean_speed_m_s'] / 0.135 - 1) < 0.30
    assert abs(figs['burst_speed_m_s'] / 0.2 - 1) < 0.30
    assert abs(figs['stroke_volume_m3'] / 35e-6 - 1) < 0.30
