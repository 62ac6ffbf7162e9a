"""The plant's mixing flaps (``softsensor/plant/controller.py``): the mixed air and its inverse."""

import pytest

from softsensor.plant.controller import fraction_for_temperature, mixed_air


def test_mixing_inverse():
    T, Y = mixed_air(0.4, 900.0, 0.06, 280.0, 0.004)
    assert 500 < T < 560 and Y == pytest.approx(0.4 * 0.06 + 0.6 * 0.004)
    assert fraction_for_temperature(T, 900.0, 0.06, 280.0, 0.004) == pytest.approx(0.4)
