"""core.schema: the one number rule every input reader applies, and its three wordings."""

import argparse
from pathlib import Path

from pulsejet_sim.core.model_io import ModelError
from pulsejet_sim.core.schema import Flag, mapping, Number, NumberRejected
import pytest


@pytest.mark.parametrize(
    'value, reason',
    [
        (True, 'not a number'),
        ('1.0', 'not a number'),
        (None, 'not a number'),
        (float('nan'), 'out of range'),
        (float('inf'), 'out of range'),
        (0.0, 'out of range'),  # low is open
        (2.5, 'out of range'),
        (10**400, 'out of range'),  # an int beyond the floats is refused, not an OverflowError
    ],
)
def test_the_rule_names_why(value, reason):
    with pytest.raises(NumberRejected) as err:
        Number(None, 0.0, 2.0, low_open=True).value(value)
    assert err.value.reason == reason


def test_accepted_values_and_text():
    rule = Number(None, 0.0, 2.0, low_open=True)
    assert rule.value(2) == 2.0 and isinstance(rule.value(2), float)
    assert rule.value(' 1.5 ', from_text=True) == 1.5
    with pytest.raises(NumberRejected):
        rule.value(True, from_text=True)  # a bool is never a number, not even as 1
    count = Number(None, 0.0, low_open=True, integer=True)
    assert count.value('3', from_text=True) == 3 and isinstance(count.value('3', True), int)
    with pytest.raises(NumberRejected):
        count.value('1.5', from_text=True)


def test_the_three_wordings():
    rule = Number(None, 0.0, 2.0, low_open=True, unit='m')
    with pytest.raises(ModelError, match=r"^geometry.a_m: 'x' is not a number; allowed: a finite "
                       r'number in \(0, 2\] m$'):
        rule.check('geometry.a_m', 'x')
    with pytest.raises(ModelError, match=r'^g.a_m: 3 is out of range; allowed: in \[0, 2\]$'):
        rule.check('g.a_m', 3, allowed='in [0, 2]')
    with pytest.raises(KeyError, match=r'f.yaml: duration_s: -1 rejected; allowed: > 0 s'):
        rule.accept(-1, 'f.yaml: duration_s', error=KeyError, allowed='> 0 s')
    with pytest.raises(ValueError, match=r"^rate='fast' rejected; allowed: a finite number in"):
        rule.accept('fast', 'rate', error=ValueError, sep='=', from_text=True)
    with pytest.raises(argparse.ArgumentTypeError, match=r"^'0' rejected; allowed: fps > 0$"):
        rule.accept('0', '', error=argparse.ArgumentTypeError, sep='', from_text=True,
                    allowed='fps > 0')


def test_flags_and_mappings():
    assert Flag(None).accept(' TRUE', 'loop', sep='=', from_text=True) is True
    with pytest.raises(ModelError, match=r"^loop='yes' rejected; allowed: true or false$"):
        Flag(None).accept('yes', 'loop', sep='=', from_text=True)
    with pytest.raises(ModelError, match=r"^loop: 'true' rejected"):
        Flag(None).accept('true', 'loop')  # text only where the reader allows it
    assert mapping(None, 'options', 'a, b') == {}
    with pytest.raises(ModelError, match=r'^options: 3 is not a mapping; allowed: a, b$'):
        mapping(3, 'options', 'a, b')


def test_exponents_without_a_dot_or_sign_are_numbers_quoted_text_stays_text(tmp_path):
    """YAML 1.1 read 1e-3 and 4.0e4 as text; the scene reader takes them as YAML 1.2 does."""
    from pulsejet_sim.core.schema import safe_load_yaml
    from pulsejet_sim.scene import load_scene

    data = safe_load_yaml(
        "a: 1e-3\nb: 4.0e4\nc: -2E+5\nd: .5e3\ne: 10\nf: '1e-3'\ng: 1e3x\nh: 1.5", 'test'
    )
    assert data == {
        'a': 0.001, 'b': 40000.0, 'c': -200000.0, 'd': 500.0, 'e': 10, 'f': '1e-3',
        'g': '1e3x', 'h': 1.5,
    }
    assert type(data['e']) is int
    # a lumped scene written with 1e-3 loads (its number rule refused the text '1e-3')
    text = Path(__file__).resolve().parents[1].joinpath('config', 'pump_cycle.yaml').read_text()
    assert 'viscosity_pa_s: 1.0e-3' in text
    scene = tmp_path / 'pump_cycle_exponent.yaml'
    scene.write_text(text.replace('viscosity_pa_s: 1.0e-3', 'viscosity_pa_s: 1e-3'))
    assert load_scene(str(scene)).data['fluid']['viscosity_pa_s'] == 0.001
    with pytest.raises(Exception, match="'1e-3' is not a number"):
        load_scene('pump_cycle', overrides={'fluid': {'viscosity_pa_s': '1e-3'}})
