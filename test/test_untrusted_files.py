"""
Files pulsejet did not write are data, never code.

Scene, sweep and fit files and the scene stored in a recording are parsed with yaml.SafeLoader only
(no Python tags), within size, alias-expansion and depth limits; a path stored in a recording is
never followed; a recording of a newer format is refused with a clear message.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from pulsejet_sim import analysis
from pulsejet_sim.bag import writer as bag_writer
from pulsejet_sim.bag.reader import bag_info, BagInfo, BagReadError, iter_bag
from pulsejet_sim.bag.repair import repair_file
from pulsejet_sim.bag.writer import BagWriter
from pulsejet_sim.core.schema import MAX_YAML_BYTES, safe_load_yaml, YAMLInputError
from pulsejet_sim.ros import replay
from pulsejet_sim.scene import load_scene, load_scene_data, SceneError
from pulsejet_sim.studies import resim
import pytest
import yaml

BOMB = (
    '\n'.join(
        ['a0: &a0 [x, x, x, x, x, x, x, x, x]']
        + [f'a{i}: &a{i} [' + ', '.join([f'*a{i - 1}'] * 9) + ']' for i in range(1, 10)]
    )
    + '\n'
)


def _quiet(fn, *args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = fn(*args)
    return code, out.getvalue(), err.getvalue()


# ---- YAML ---------------------------------------------------------------------------------------
@pytest.mark.timeout(20)
@pytest.mark.parametrize(
    'text, expected',
    [
        ('!!python/object/apply:os.system ["touch {marker}"]\n', 'not valid YAML'),
        ('model: !!python/name:os.system\n', 'not valid YAML'),
        (BOMB, 'expands to more than'),
        ('a: &x [1, *x]\n', 'refers to a value containing itself'),
        ('a: ' + '[' * 200 + ']' * 200 + '\n', 'nested'),
        ('a: 1\n---\nb: 2\n', 'not valid YAML'),
    ],
)
def test_scene_yaml_is_data_only_and_bounded(tmp_path: Path, text: str, expected: str) -> None:
    marker = tmp_path / 'executed'
    path = tmp_path / 'evil.yaml'
    path.write_text(text.replace('{marker}', str(marker)))
    with pytest.raises(SceneError, match=expected) as err:
        load_scene(path)
    assert 'allowed' in str(err.value) and len(str(err.value)) < 1000
    assert not marker.exists()


def test_oversized_and_binary_scene_files_are_refused(tmp_path: Path) -> None:
    big = tmp_path / 'big.yaml'
    big.write_text('model: lumped\n' + '#' * (MAX_YAML_BYTES + 10) + '\n')
    with pytest.raises(SceneError, match=f'allowed: at most {MAX_YAML_BYTES} bytes'):
        load_scene(big)
    binary = tmp_path / 'bin.yaml'
    binary.write_bytes(b'model: \xff\xfe lumped\n')
    with pytest.raises(SceneError, match='not UTF-8'):
        load_scene(binary)
    with pytest.raises(SceneError, match='not a name'):
        load_scene('bad\x00name')
    with pytest.raises(SceneError, match='does not exist'):
        load_scene(tmp_path / 'a directory.yaml')


def test_safe_load_yaml_accepts_ordinary_anchors() -> None:
    data = safe_load_yaml('base: &b {k: 1}\nother: *b\nmerged: {<<: *b, j: 2}\n', 'test')
    assert data == {'base': {'k': 1}, 'other': {'k': 1}, 'merged': {'k': 1, 'j': 2}}
    with pytest.raises(YAMLInputError, match='test: not valid YAML'):
        safe_load_yaml('!!python/tuple [1, 2]', 'test')


def test_long_bad_values_are_shortened_in_messages(tmp_path: Path) -> None:
    data, _ = load_scene_data('escape')
    data['material']['stiffness_n_m'] = 'x' * 100_000
    path = tmp_path / 's.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(
        SceneError, match=r"material.stiffness_n_m: 'x+\.\.\.x+' is not a number; allowed"
    ) as err:
        load_scene(path)
    assert len(str(err.value)) < 300


def test_sweep_and_fit_files_use_the_safe_loader(tmp_path: Path) -> None:
    from pulsejet_sim.studies.fit import FitError, load_fit
    from pulsejet_sim.studies.sweep import load_sweep, SweepError

    marker = tmp_path / 'executed'
    evil = tmp_path / 'evil.yaml'
    evil.write_text(f'studies: !!python/object/apply:os.system ["touch {marker}"]\n')
    with pytest.raises(SweepError, match='not valid YAML.*python/object/apply'):
        load_sweep(evil)
    with pytest.raises((FitError, yaml.YAMLError, ValueError)):
        load_fit(evil)
    assert not marker.exists()


# ---- recordings ---------------------------------------------------------------------------------
@pytest.fixture(scope='module')
def run_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from pulsejet_sim.studies.runner import run_scene

    path = tmp_path_factory.mktemp('untrusted') / 'run.mcap'
    run_scene(load_scene('escape'), 0.05, path)
    return path


def rewrite(src: Path, dst: Path, metadata: dict[str, str] | None) -> Path:
    """Return a copy of src with its `pulsejet` metadata record replaced (None: removed)."""
    info = bag_info(src)
    with BagWriter(dst) as bag:
        for topic, type_name in info.topics.items():
            bag.add_topic(
                topic,
                type_name,
                definition=info.definitions[type_name],
                channel_metadata=info.channel_metadata[topic],
            )
        if metadata is not None:
            bag.add_metadata('pulsejet', metadata)
        for m in iter_bag(src, decode=False):
            bag.write(m.topic, m.msg, m.log_time_ns)
    return dst


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    'metadata, expected',
    [
        ({'scene': '/etc/passwd'}, 'paths stored in a recording are not followed'),
        ({'scene': '../config/escape'}, 'paths stored in a recording are not followed'),
        ({'scene': '{outside}'}, 'paths stored in a recording are not followed'),
        ({'scene_yaml': '!!python/object/apply:os.system ["touch {marker}"]'}, 'not valid YAML'),
        ({'scene_yaml': '[1, 2, 3]'}, 'list'),
        ({'scene_yaml': BOMB}, 'expands to more than'),
        ({'scene_yaml': 'model: lumped\ngeometry: {length_m: -1}\n'}, 'geometry'),
    ],
)
def test_stored_scene_is_validated_and_paths_not_followed(
    run_file: Path, tmp_path: Path, metadata: dict, expected: str
) -> None:
    marker = tmp_path / 'executed'
    outside = tmp_path / 'outside.yaml'  # a valid scene, but outside the project
    outside.write_text((Path(resim.__file__).parents[2] / 'config' / 'escape.yaml').read_text())
    metadata = {
        k: v.replace('{marker}', str(marker)).replace('{outside}', str(outside))
        for k, v in metadata.items()
    }
    bad = rewrite(run_file, tmp_path / 'bad.mcap', metadata)
    code, out, err = _quiet(resim.main_resim, [str(bad)])
    assert code == 2 and expected in err and 'Traceback' not in err, err
    assert not marker.exists()
    # with a scene given explicitly, the same file re-simulates (the stored one is not needed)
    code, out, err = _quiet(resim.main_resim, [str(bad), '--scene', 'escape'])
    assert code == 0, out + err


def test_stored_scene_name_under_config_is_used(run_file: Path, tmp_path: Path) -> None:
    named = rewrite(run_file, tmp_path / 'named.mcap', {'scene': 'escape'})
    assert resim.resimulate(named).bit_identical


@pytest.fixture
def newer_format(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setattr(bag_writer, 'LIBRARY', 'pulsejet_sim.bag pulsejet-format=99 (future)')
    path = tmp_path / 'future.mcap'
    with BagWriter(path) as bag:
        bag.add_topic('pulsejet/volume', 'std_msgs/msg/Float64')
        bag.write('pulsejet/volume', b'\x00\x01\x00\x00' + b'\0' * 8, 0)
    return path


def test_newer_format_version_is_refused_clearly(newer_format: Path) -> None:
    expected = 'pulsejet recording format 99, newer than this pulsejet'
    with pytest.raises(BagReadError, match=expected):
        bag_info(newer_format)
    for main in (analysis.main_summary, resim.main_resim):
        code, _, err = _quiet(main, [str(newer_format)])
        assert code == 2 and expected in err, err
    with pytest.raises(BagReadError, match=expected):
        replay.load_recording(newer_format)
    with pytest.raises(BagReadError, match='newer than this pulsejet'):
        repair_file(newer_format)


def test_current_files_carry_the_format_version(run_file: Path) -> None:
    from pulsejet_sim.bag.records import FORMAT_VERSION, format_version

    info = BagInfo(run_file)
    list(iter_bag(run_file, info=info, decode=False))
    assert format_version(info.library) == FORMAT_VERSION
